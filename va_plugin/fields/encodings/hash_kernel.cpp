// Fused CPU kernels of the multiresolution hash encoding (see hash_grid.py for the definitions).
//
// Every kernel recomputes a point's cell, corner rows and trilinear weights per level instead of
// storing them, so a lookup reads the table and the point once and allocates nothing per corner.
// The loops over points hold scalars only, so the compiler vectorizes them across points; they run
// in parallel over blocks of points. Scatters into the table run in parallel over levels, whose rows
// are disjoint, so no two threads write one entry and the sums do not depend on the thread count.
//
// Conventions (the same as the PyTorch path): x01 [n, 3] float32 in [0, 1]; the table is
// feature-major [F, entries]; the encoding is point-major [n, L * F] with channel l * F + f; corner
// 4 i + 2 j + k is the vertex cell + (i, j, k) and its weight is (wx_i * wy_j) * wz_k. The encoding
// is the same bits as the PyTorch path's (same products, same order of the sums; the build turns
// off fused multiply-adds); gradients agree to float rounding.

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/library.h>

#include <algorithm>
#include <cstdint>
#include <vector>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define VA_HAS_MXCSR 1
#endif

namespace {

constexpr int64_t kPointGrain = 512;  // points per parallel task

// One level's constants.
struct Level {
  float scale;       // cells per axis N_l
  int32_t upper;     // the last cell, N_l - 1
  uint32_t mult[3];  // per-axis multipliers (low 32 bits: a product's low bits do not depend on the rest)
  uint32_t mask;     // hashmap_size - 1
  int64_t offset;    // first table row of the level
  bool dense;        // vertices indexed row-major (they fit the table) rather than hashed
};

struct Grid {
  std::vector<Level> levels;
  int64_t width(int64_t F) const { return static_cast<int64_t>(levels.size()) * F; }
};

// A point's 8 corners on one level: rows relative to the level's first row, trilinear weights, and
// the per-axis fractions (f) and their complements (g = 1 - f).
struct Corners {
  uint32_t row[8];
  float w[8];
  float fx, fy, fz, gx, gy, gz;
};

// Inlined into loops over points, it keeps to scalars and fixed-size arrays (registers once
// inlined). A point exactly at 1 falls in the last cell with fraction 1; a NaN lands in cell 0 with
// a NaN fraction, as on the PyTorch path. Truncation is floor here: the position is non-negative.
template <bool kDense>
inline __attribute__((always_inline)) void corners_of(const float* x, const Level& v, Corners& c) {
  const float px = x[0] * v.scale, py = x[1] * v.scale, pz = x[2] * v.scale;
  int32_t cx = px >= 0.0f ? static_cast<int32_t>(px) : 0;
  int32_t cy = py >= 0.0f ? static_cast<int32_t>(py) : 0;
  int32_t cz = pz >= 0.0f ? static_cast<int32_t>(pz) : 0;
  cx = cx > v.upper ? v.upper : cx;
  cy = cy > v.upper ? v.upper : cy;
  cz = cz > v.upper ? v.upper : cz;
  c.fx = px - static_cast<float>(cx);
  c.fy = py - static_cast<float>(cy);
  c.fz = pz - static_cast<float>(cz);
  c.gx = 1.0f - c.fx;
  c.gy = 1.0f - c.fy;
  c.gz = 1.0f - c.fz;
  const uint32_t x0 = static_cast<uint32_t>(cx) * v.mult[0], x1 = static_cast<uint32_t>(cx + 1) * v.mult[0];
  const uint32_t y0 = static_cast<uint32_t>(cy) * v.mult[1], y1 = static_cast<uint32_t>(cy + 1) * v.mult[1];
  const uint32_t z0 = static_cast<uint32_t>(cz) * v.mult[2], z1 = static_cast<uint32_t>(cz + 1) * v.mult[2];
  if (kDense) {
    c.row[0] = x0 + y0 + z0; c.row[1] = x0 + y0 + z1; c.row[2] = x0 + y1 + z0; c.row[3] = x0 + y1 + z1;
    c.row[4] = x1 + y0 + z0; c.row[5] = x1 + y0 + z1; c.row[6] = x1 + y1 + z0; c.row[7] = x1 + y1 + z1;
  } else {
    const uint32_t m = v.mask;
    c.row[0] = (x0 ^ y0 ^ z0) & m; c.row[1] = (x0 ^ y0 ^ z1) & m; c.row[2] = (x0 ^ y1 ^ z0) & m;
    c.row[3] = (x0 ^ y1 ^ z1) & m; c.row[4] = (x1 ^ y0 ^ z0) & m; c.row[5] = (x1 ^ y0 ^ z1) & m;
    c.row[6] = (x1 ^ y1 ^ z0) & m; c.row[7] = (x1 ^ y1 ^ z1) & m;
  }
  const float gg = c.gx * c.gy, gf = c.gx * c.fy, fg = c.fx * c.gy, ff = c.fx * c.fy;
  c.w[0] = gg * c.gz; c.w[1] = gg * c.fz; c.w[2] = gf * c.gz; c.w[3] = gf * c.fz;
  c.w[4] = fg * c.gz; c.w[5] = fg * c.fz; c.w[6] = ff * c.gz; c.w[7] = ff * c.fz;
}

// h[corner] = sum_a gd[a] * N_l * d w[corner] / d frac[a]: how the pulled-back derivative of a point
// depends on each corner's value (d w / d fx is the other two axes' weights, signed by the side).
inline __attribute__((always_inline)) void pullback_weights(const Corners& c, const float* gd, float scale,
                                                            float h[8]) {
  const float ax = gd[0] * scale, ay = gd[1] * scale, az = gd[2] * scale;
  const float yz[4] = {c.gy * c.gz, c.gy * c.fz, c.fy * c.gz, c.fy * c.fz};
  const float xz[4] = {c.gx * c.gz, c.gx * c.fz, c.fx * c.gz, c.fx * c.fz};
  const float xy[4] = {c.gx * c.gy, c.gx * c.fy, c.fx * c.gy, c.fx * c.fy};
  for (int i = 0; i < 2; ++i) {
    for (int j = 0; j < 2; ++j) {
      for (int k = 0; k < 2; ++k) {
        const float sx = i ? 1.0f : -1.0f, sy = j ? 1.0f : -1.0f, sz = k ? 1.0f : -1.0f;
        h[4 * i + 2 * j + k] = ax * sx * yz[2 * j + k] + ay * sy * xz[2 * i + k] + az * sz * xy[2 * i + j];
      }
    }
  }
}

// Calls body(std::true_type or std::false_type) for a dense or a hashed level.
template <typename Body>
inline void dispatch_kind(const Level& v, Body&& body) {
  if (v.dense) {
    body(std::true_type());
  } else {
    body(std::false_type());
  }
}

// Runs body(dense, l, level, begin, end) for every level on blocks [begin, end) of the n points, the
// blocks in parallel; ``dense`` is std::true_type or std::false_type.
template <typename Body>
inline void for_levels_over_points(const Grid& grid, int64_t n, Body&& body) {
  at::parallel_for(0, n, kPointGrain, [&](int64_t begin, int64_t end) {
    for (size_t l = 0; l < grid.levels.size(); ++l) {
      const Level& v = grid.levels[l];
      dispatch_kind(v, [&](auto dense) { body(dense, static_cast<int64_t>(l), v, begin, end); });
    }
  });
}

Grid make_grid(const at::Tensor& resolutions, const at::Tensor& multipliers, const at::Tensor& offsets,
               int64_t n_dense, int64_t hashmap_size) {
  TORCH_CHECK(resolutions.dtype() == at::kLong && multipliers.dtype() == at::kLong && offsets.dtype() == at::kLong,
              "the grid's level constants must be int64");
  TORCH_CHECK(hashmap_size >= 2 && hashmap_size <= (int64_t{1} << 31) && (hashmap_size & (hashmap_size - 1)) == 0,
              "the fused hash kernels take a power-of-two table size up to 2^31, got ", hashmap_size);
  const at::Tensor r = resolutions.contiguous(), m = multipliers.contiguous(), o = offsets.contiguous();
  Grid grid;
  for (int64_t l = 0; l < r.size(0); ++l) {
    const int64_t resolution = r.data_ptr<int64_t>()[l];
    TORCH_CHECK(resolution >= 1 && resolution < (int64_t{1} << 30), "bad grid resolution ", resolution);
    Level v;
    v.scale = static_cast<float>(resolution);
    v.upper = static_cast<int32_t>(resolution - 1);
    for (int a = 0; a < 3; ++a) v.mult[a] = static_cast<uint32_t>(m.data_ptr<int64_t>()[3 * l + a]);
    v.mask = static_cast<uint32_t>(hashmap_size - 1);
    v.offset = o.data_ptr<int64_t>()[l];
    v.dense = l < n_dense;
    grid.levels.push_back(v);
  }
  return grid;
}

void check_points(const at::Tensor& x01, const at::Tensor& table) {
  TORCH_CHECK(x01.device().is_cpu() && table.device().is_cpu(), "the fused hash kernels run on CPU");
  TORCH_CHECK(x01.dtype() == at::kFloat && table.dtype() == at::kFloat, "the fused hash kernels take float32");
  TORCH_CHECK(x01.dim() == 2 && x01.size(1) == 3 && x01.is_contiguous(), "points must be contiguous [n, 3]");
  TORCH_CHECK(table.dim() == 2 && table.is_contiguous(), "the table must be contiguous [F, entries]");
}

void check_per_point(const at::Tensor& t, int64_t n, int64_t width, const char* what) {
  TORCH_CHECK(t.dtype() == at::kFloat && t.dim() == 2 && t.size(0) == n && t.size(1) == width && t.is_contiguous(),
              what, " must be a contiguous float32 [", n, ", ", width, "]");
}

// What every kernel starts from: the checked points and table, the grid, and the sizes.
struct Lookup {
  Grid grid;
  int64_t n, F, E, width;  // points, features per level, table entries, channels of the encoding
  const float* x;
  const float* t;
};

Lookup make_lookup(const at::Tensor& x01, const at::Tensor& table, const at::Tensor& resolutions,
                   const at::Tensor& multipliers, const at::Tensor& offsets, int64_t n_dense, int64_t hashmap_size) {
  check_points(x01, table);
  Lookup q{make_grid(resolutions, multipliers, offsets, n_dense, hashmap_size), x01.size(0), table.size(0),
           table.size(1), 0, x01.data_ptr<float>(), table.data_ptr<float>()};
  q.width = q.grid.width(q.F);
  return q;
}

// The encoding [n, L * F].
at::Tensor encode(const at::Tensor& x01, const at::Tensor& table, const at::Tensor& resolutions,
                  const at::Tensor& multipliers, const at::Tensor& offsets, int64_t n_dense, int64_t hashmap_size) {
  const Lookup q = make_lookup(x01, table, resolutions, multipliers, offsets, n_dense, hashmap_size);
  const int64_t n = q.n, F = q.F, E = q.E, width = q.width;
  at::Tensor out = at::empty({n, width}, x01.options());
  const float *x = q.x, *t = q.t;
  float* o = out.data_ptr<float>();
  for_levels_over_points(q.grid, n, [&](auto dense, int64_t l, const Level& v, int64_t begin, int64_t end) {
    for (int64_t f = 0; f < F; ++f) {
      const float* row = t + f * E + v.offset;
      float* out_f = o + l * F + f;
#pragma omp simd
      for (int64_t p = begin; p < end; ++p) {
        Corners c;
        corners_of<decltype(dense)::value>(x + 3 * p, v, c);
        float acc = 0.0f;
        for (int k = 0; k < 8; ++k) acc += row[c.row[k]] * c.w[k];
        out_f[p * width] = acc;
      }
    }
  });
  return out;
}

// The pull-back of a derivative w.r.t. the encoding, g [n, L * F], to the points: d/d x01, [n, 3].
at::Tensor pullback(const at::Tensor& x01, const at::Tensor& table, const at::Tensor& g, const at::Tensor& resolutions,
                    const at::Tensor& multipliers, const at::Tensor& offsets, int64_t n_dense, int64_t hashmap_size) {
  const Lookup q = make_lookup(x01, table, resolutions, multipliers, offsets, n_dense, hashmap_size);
  const int64_t n = q.n, F = q.F, E = q.E, width = q.width;
  check_per_point(g, n, width, "the derivative w.r.t. the encoding");
  at::Tensor out = at::zeros({n, 3}, x01.options());
  const float *x = q.x, *t = q.t;
  const float* gp = g.data_ptr<float>();
  float* o = out.data_ptr<float>();
  for_levels_over_points(q.grid, n, [&](auto dense, int64_t l, const Level& v, int64_t begin, int64_t end) {
#pragma omp simd
    for (int64_t p = begin; p < end; ++p) {
      Corners c;
      corners_of<decltype(dense)::value>(x + 3 * p, v, c);
      // the derivative w.r.t. each corner's value, summed over the features
      float s[8] = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
      for (int64_t f = 0; f < F; ++f) {
        const float* row = t + f * E + v.offset;
        const float gf = gp[p * width + l * F + f];
        for (int k = 0; k < 8; ++k) s[k] += row[c.row[k]] * gf;
      }
      // d/d fx = sum over the (j, k) pairs of (s[1jk] - s[0jk]) * wy_j * wz_k, and so on
      const float dx = (s[4] - s[0]) * c.gy * c.gz + (s[5] - s[1]) * c.gy * c.fz + (s[6] - s[2]) * c.fy * c.gz +
                       (s[7] - s[3]) * c.fy * c.fz;
      const float dy = (s[2] - s[0]) * c.gx * c.gz + (s[3] - s[1]) * c.gx * c.fz + (s[6] - s[4]) * c.fx * c.gz +
                       (s[7] - s[5]) * c.fx * c.fz;
      const float dz = (s[1] - s[0]) * c.gx * c.gy + (s[3] - s[2]) * c.gx * c.fy + (s[5] - s[4]) * c.fx * c.gy +
                       (s[7] - s[6]) * c.fx * c.fy;
      o[3 * p] += dx * v.scale;
      o[3 * p + 1] += dy * v.scale;
      o[3 * p + 2] += dz * v.scale;
    }
  });
  return out;
}

// The derivative of sum(pullback(g) * gd) w.r.t. g, [n, L * F] (the pull-back is linear in g).
at::Tensor pullback_grad_g(const at::Tensor& x01, const at::Tensor& table, const at::Tensor& gd,
                           const at::Tensor& resolutions, const at::Tensor& multipliers, const at::Tensor& offsets,
                           int64_t n_dense, int64_t hashmap_size) {
  const Lookup q = make_lookup(x01, table, resolutions, multipliers, offsets, n_dense, hashmap_size);
  const int64_t n = q.n, F = q.F, E = q.E, width = q.width;
  check_per_point(gd, n, 3, "the derivative w.r.t. the pulled-back gradient");
  at::Tensor out = at::empty({n, width}, x01.options());
  const float *x = q.x, *t = q.t;
  const float* gdp = gd.data_ptr<float>();
  float* o = out.data_ptr<float>();
  for_levels_over_points(q.grid, n, [&](auto dense, int64_t l, const Level& v, int64_t begin, int64_t end) {
#pragma omp simd
    for (int64_t p = begin; p < end; ++p) {
      Corners c;
      corners_of<decltype(dense)::value>(x + 3 * p, v, c);
      float h[8];
      pullback_weights(c, gdp + 3 * p, v.scale, h);
      for (int64_t f = 0; f < F; ++f) {
        const float* row = t + f * E + v.offset;
        float acc = 0.0f;
        for (int k = 0; k < 8; ++k) acc += row[c.row[k]] * h[k];
        o[p * width + l * F + f] = acc;
      }
    }
  });
  return out;
}

// Adds to one level's table rows (``rows``: the level's first row of feature 0) what points [0, n)
// send them: e * w[k] from the encoding's derivative e and q * h[k] from a pull-back's.
template <bool kDense, bool kEncoded, bool kPull>
void scatter_level(const float* x, const Level& v, int64_t l, const float* ge, const float* gp, const float* gdp,
                   int64_t n, int64_t F, int64_t E, int64_t width, float* rows) {
  Corners c;
  float h[8];
  for (int64_t p = 0; p < n; ++p) {
    corners_of<kDense>(x + 3 * p, v, c);
    if (kPull) pullback_weights(c, gdp + 3 * p, v.scale, h);
    for (int64_t f = 0; f < F; ++f) {
      float* row = rows + f * E;
      const int64_t channel = p * width + l * F + f;
      const float e = kEncoded ? ge[channel] : 0.0f;
      const float q = kPull ? gp[channel] : 0.0f;
      for (int k = 0; k < 8; ++k) {
        if (kEncoded && kPull) {
          row[c.row[k]] += e * c.w[k] + q * h[k];
        } else if (kPull) {
          row[c.row[k]] += q * h[k];
        } else {
          row[c.row[k]] += e * c.w[k];
        }
      }
    }
  }
}

// The table's gradient [F, entries] from a derivative w.r.t. the encoding (grad_encoded [n, L * F])
// and, optionally, from a pull-back: g [n, L * F] the derivative it pulled back and gd [n, 3] the
// derivative w.r.t. its result. Either part may be absent.
at::Tensor table_grad(const at::Tensor& x01, const at::Tensor& table, const c10::optional<at::Tensor>& grad_encoded,
                      const c10::optional<at::Tensor>& g, const c10::optional<at::Tensor>& gd,
                      const at::Tensor& resolutions, const at::Tensor& multipliers, const at::Tensor& offsets,
                      int64_t n_dense, int64_t hashmap_size) {
  const Lookup q = make_lookup(x01, table, resolutions, multipliers, offsets, n_dense, hashmap_size);
  const int64_t n = q.n, F = q.F, E = q.E, width = q.width;
  const bool has_encoded = grad_encoded.has_value() && grad_encoded->defined();
  const bool has_pull = g.has_value() && g->defined();
  TORCH_CHECK(has_pull == (gd.has_value() && gd->defined()), "a pull-back's gradient needs both g and gd");
  if (has_encoded) check_per_point(*grad_encoded, n, width, "the derivative w.r.t. the encoding");
  if (has_pull) {
    check_per_point(*g, n, width, "the pulled-back derivative");
    check_per_point(*gd, n, 3, "the derivative w.r.t. the pulled-back gradient");
  }
  // Each level's rows are zeroed by the task that scatters into them, just before: the rows are then in
  // cache for the scatter, instead of one pass over the whole table beforehand evicting them.
  at::Tensor out = at::empty({F, E}, table.options());
  const float* x = q.x;
  const float* ge = has_encoded ? grad_encoded->data_ptr<float>() : nullptr;
  const float* gp = has_pull ? g->data_ptr<float>() : nullptr;
  const float* gdp = has_pull ? gd->data_ptr<float>() : nullptr;
  float* o = out.data_ptr<float>();
  const int64_t L = static_cast<int64_t>(q.grid.levels.size());
  auto zero_rows = [&](int64_t first, int64_t last) {
    for (int64_t f = 0; f < F; ++f) std::fill(o + f * E + first, o + f * E + last, 0.0f);
  };
  if (L == 0) {
    zero_rows(0, E);
    return out;
  }
  zero_rows(0, q.grid.levels[0].offset);  // rows before the first level (none in the encoding's layout)
  // Levels write disjoint rows. Threads take contiguous runs of tasks, and task i is level 0, L-1, 1,
  // L-2, ...: each run mixes cheap coarse levels (small, cached tables) with costly fine ones.
  at::parallel_for(0, L, 1, [&](int64_t begin, int64_t end) {
    for (int64_t task = begin; task < end; ++task) {
      const int64_t l = task % 2 == 0 ? task / 2 : L - 1 - task / 2;
      const Level& v = q.grid.levels[l];
      // the last open level's task also zeroes the rows of the levels not yet open
      zero_rows(v.offset, l + 1 < L ? q.grid.levels[l + 1].offset : E);
      float* rows = o + v.offset;
      dispatch_kind(v, [&](auto dense) {
        constexpr bool kDense = decltype(dense)::value;
        if (has_encoded && has_pull) {
          scatter_level<kDense, true, true>(x, v, l, ge, gp, gdp, n, F, E, width, rows);
        } else if (has_pull) {
          scatter_level<kDense, false, true>(x, v, l, ge, gp, gdp, n, F, E, width, rows);
        } else if (has_encoded) {
          scatter_level<kDense, true, false>(x, v, l, ge, gp, gdp, n, F, E, width, rows);
        }
      });
    }
  });
  return out;
}

// Flush-to-zero and denormals-are-zero (MXCSR bits 15 and 6) on or off in the calling thread and in
// every thread of torch's pool: a thread's floating-point mode is its own, so the caller's alone would
// leave the pool's threads on the slow path for denormal values. False where the CPU has no MXCSR.
bool flush_denormals(bool on) {
#ifdef VA_HAS_MXCSR
  constexpr unsigned kBits = 0x8040;
  auto apply = [on]() {
    const unsigned csr = _mm_getcsr();
    _mm_setcsr(on ? (csr | kBits) : (csr & ~kBits));
  };
  apply();
  at::parallel_for(0, at::get_num_threads(), 1, [&](int64_t, int64_t) { apply(); });
  return true;
#else
  return false;
#endif
}

}  // namespace

TORCH_LIBRARY(va_hash_grid, m) {
  m.def("flush_denormals(bool on) -> bool", &flush_denormals);
  m.def("encode(Tensor x01, Tensor table, Tensor resolutions, Tensor multipliers, Tensor offsets, int n_dense, "
        "int hashmap_size) -> Tensor");
  m.def("pullback(Tensor x01, Tensor table, Tensor g, Tensor resolutions, Tensor multipliers, Tensor offsets, "
        "int n_dense, int hashmap_size) -> Tensor");
  m.def("pullback_grad_g(Tensor x01, Tensor table, Tensor gd, Tensor resolutions, Tensor multipliers, "
        "Tensor offsets, int n_dense, int hashmap_size) -> Tensor");
  m.def("table_grad(Tensor x01, Tensor table, Tensor? grad_encoded, Tensor? g, Tensor? gd, Tensor resolutions, "
        "Tensor multipliers, Tensor offsets, int n_dense, int hashmap_size) -> Tensor");
}

TORCH_LIBRARY_IMPL(va_hash_grid, CPU, m) {
  m.impl("encode", &encode);
  m.impl("pullback", &pullback);
  m.impl("pullback_grad_g", &pullback_grad_g);
  m.impl("table_grad", &table_grad);
}
