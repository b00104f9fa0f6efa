"""Tests of the multiresolution hash encoding: indexing, hashing, agreement with the plain reference
implementation, gradients, edge cases and the coarse-to-fine level mask."""

import math

import pytest
import torch

from va_plugin.fields.encodings import hash_grid
from va_plugin.fields.encodings.hash_grid import (
    HashGridEncoding,
    corner_indices,
    grid_resolutions,
    level_table_sizes,
)
from va_plugin.fields.encodings.hash_grid_reference import hash_grid_reference

# Small enough to be quick, large enough to have 3 dense and 5 hashed levels.
SMALL = dict(n_levels=8, n_features_per_level=2, log2_hashmap_size=12, base_resolution=4, max_resolution=128)


def _edge_points(bound: float) -> torch.Tensor:
    """Corners and faces of the domain, points just outside it, far outside it and infinite."""
    values = [-bound, bound, 0.0, bound * (1 + 1e-7), -bound * 1.5, 1e6, -1e6, math.inf, -math.inf]
    grid = torch.tensor(values)
    return torch.cartesian_prod(grid, grid, grid)


def _points(n: int, bound: float, seed: int = 0) -> torch.Tensor:
    """Random points inside and somewhat outside the domain, plus the edge cases."""
    generator = torch.Generator().manual_seed(seed)
    inside = (torch.rand(n, 3, generator=generator) * 2.4 - 1.2) * bound
    return torch.cat([inside, _edge_points(bound)])


def _reference(encoding: HashGridEncoding, x: torch.Tensor) -> torch.Tensor:
    return hash_grid_reference(
        x, encoding.table.t(), encoding.offsets, encoding.resolutions, encoding.hashmap_size, encoding.bound
    )


def test_resolutions_follow_the_geometric_schedule():
    resolutions = grid_resolutions(16, 16, 2048)
    growth = math.exp((math.log(2048) - math.log(16)) / 15)
    assert resolutions[0] == 16 and resolutions[-1] == 2048
    assert resolutions == [math.floor(16 * growth**level + 1e-6) for level in range(16)]
    assert grid_resolutions(1, 16, 2048) == [16]


def test_one_table_holds_every_level():
    encoding = HashGridEncoding(**SMALL, init_scale=1e-3)
    sizes = level_table_sizes(encoding.resolutions, encoding.hashmap_size)
    assert encoding.table.shape == (2, sum(sizes)) and encoding.table.is_contiguous()  # feature-major
    assert encoding.offsets == [sum(sizes[:level]) for level in range(len(sizes))]
    assert max(sizes) == encoding.hashmap_size and encoding.n_dense_levels == 3
    assert encoding.table.abs().max() <= 1e-3
    assert list(encoding.state_dict()) == ["table"]


def test_indices_stay_in_each_levels_table_including_edges_and_outside():
    encoding = HashGridEncoding(**SMALL, bound=2.0)
    cell, _ = hash_grid.cell_corners(hash_grid.normalise_points(_points(2000, bound=2.0), 2.0), encoding._resolutions)
    indices = corner_indices(cell, encoding.levels()).permute(2, 0, 1)
    sizes = torch.tensor(level_table_sizes(encoding.resolutions, encoding.hashmap_size))
    assert indices.shape == (2000 + 9**3, 8, 8)
    assert indices.min() >= 0
    assert (indices < sizes[None, :, None]).all()


def _vertex_indices(encoding: HashGridEncoding, level: int, vertices: torch.Tensor) -> torch.Tensor:
    """Index of integer grid vertices ``[n, 3]`` on one level (corner 0 of the cell they start)."""
    levels = encoding.levels().first(level + 1)
    cell = vertices.t()[None].expand(level + 1, 3, -1)
    return corner_indices(cell, levels)[level, 0]


def test_dense_levels_are_collision_free():
    encoding = HashGridEncoding(**SMALL)
    for level in range(encoding.n_dense_levels):
        side = encoding.resolutions[level] + 1
        vertices = torch.cartesian_prod(*[torch.arange(side)] * 3)
        indices = _vertex_indices(encoding, level, vertices)
        assert torch.equal(indices.sort().values, torch.arange(side**3))


def test_hashed_levels_use_the_instant_ngp_hash():
    encoding = HashGridEncoding(**SMALL)
    level = encoding.n_dense_levels
    vertex = torch.tensor([[5, 70, 123]])
    expected = (5 ^ 70 * 2654435761 ^ 123 * 805459861) % encoding.hashmap_size
    assert _vertex_indices(encoding, level, vertex).item() == expected


def test_hashed_levels_collide_at_the_rate_of_a_uniform_hash():
    """Distinct vertices hashed into T slots fill ``T (1 - exp(-V / T))`` of them in expectation; a
    hash that ignores an axis or its high bits fills far fewer."""
    encoding = HashGridEncoding(n_levels=2, log2_hashmap_size=14, base_resolution=8, max_resolution=1024)
    table_size = encoding.hashmap_size
    generator = torch.Generator().manual_seed(1)
    for n_vertices in (table_size // 4, 4 * table_size):
        candidates = torch.randint(0, 1025, (2 * n_vertices, 3), generator=generator).unique(dim=0)
        vertices = candidates[torch.randperm(candidates.shape[0], generator=generator)[:n_vertices]]
        occupied = _vertex_indices(encoding, 1, vertices).unique().numel()
        expected = table_size * (1 - math.exp(-n_vertices / table_size))
        assert abs(occupied - expected) < 0.01 * expected, (n_vertices, occupied, expected)


def test_forward_matches_reference():
    """Fast path and reference agree to atol 1e-6 (float32), inside, on the edges and outside."""
    encoding = HashGridEncoding(**SMALL, init_scale=1.0)
    x = _points(1500, bound=1.0)
    torch.testing.assert_close(encoding(x), _reference(encoding, x), atol=1e-6, rtol=0)


def test_gradients_match_reference():
    """Gradients w.r.t. the table and the points agree to atol 1e-5 (float32)."""
    encoding = HashGridEncoding(**SMALL, init_scale=0.05)
    points = _points(1500, bound=1.0)
    weights = torch.randn(points.shape[0], encoding.output_dim, generator=torch.Generator().manual_seed(2))
    grads = []
    for encode in (encoding, lambda p: _reference(encoding, p)):
        x = points.clone().requires_grad_()
        grads.append(torch.autograd.grad((encode(x) * weights).sum(), (encoding.table, x)))
    (table_fast, x_fast), (table_ref, x_ref) = grads
    torch.testing.assert_close(table_fast, table_ref, atol=1e-5, rtol=0)
    torch.testing.assert_close(x_fast, x_ref, atol=1e-5, rtol=0)


def test_chunking_does_not_change_results(monkeypatch):
    encoding = HashGridEncoding(**SMALL, init_scale=1.0)
    x = _points(500, bound=1.0).requires_grad_()
    results = []
    for chunk in (hash_grid.CPU_CHUNK_POINTS, 7):
        monkeypatch.setattr(hash_grid, "CPU_CHUNK_POINTS", chunk)
        out = encoding(x)
        results.append((out, *torch.autograd.grad(out.square().sum(), (encoding.table, x))))
    for fast, chunked in zip(*results):
        torch.testing.assert_close(fast, chunked, atol=1e-5, rtol=1e-5)


def _tiny_double_encoding() -> HashGridEncoding:
    """Two levels (one dense, one hashed into 64 entries) in float64, for gradcheck."""
    encoding = HashGridEncoding(n_levels=2, log2_hashmap_size=6, base_resolution=2, max_resolution=4, init_scale=1.0)
    assert encoding.n_dense_levels == 1
    return encoding.double()


def test_first_order_gradients_pass_gradcheck():
    encoding = _tiny_double_encoding()
    x = (torch.rand(6, 3, dtype=torch.float64) * 1.8 - 0.9).requires_grad_()
    assert torch.autograd.gradcheck(lambda points, table: encoding(points), (x, encoding.table))


def test_second_order_gradients_pass_gradgradcheck():
    """``create_graph=True`` (an eikonal loss) takes the differentiable fallback backward."""
    encoding = _tiny_double_encoding()
    x = (torch.rand(4, 3, dtype=torch.float64) * 1.8 - 0.9).requires_grad_()
    assert torch.autograd.gradgradcheck(lambda points, table: encoding(points), (x, encoding.table))


def test_eikonal_style_double_backward_matches_reference():
    """Checked in float64: second-order terms scale with resolution squared."""
    encoding = HashGridEncoding(**SMALL, init_scale=0.05).double()
    points = _points(500, bound=1.0).double()
    grads = []
    for encode in (encoding, lambda p: _reference(encoding, p)):
        x = points.clone().requires_grad_()
        (normal,) = torch.autograd.grad(encode(x)[:, ::3].sum(), x, create_graph=True)
        grads.append(torch.autograd.grad((normal.norm(dim=-1) - 1).square().sum(), encoding.table))
    torch.testing.assert_close(grads[0][0], grads[1][0], atol=1e-9, rtol=1e-9)


def test_edges_outside_and_huge_inputs_give_finite_values_and_gradients():
    encoding = HashGridEncoding(**SMALL, bound=1.0, init_scale=1.0)
    x = _edge_points(1.0).requires_grad_()
    out = encoding(x)
    table_grad, x_grad = torch.autograd.grad(out.square().sum(), (encoding.table, x))
    assert torch.isfinite(out).all() and torch.isfinite(table_grad).all() and torch.isfinite(x_grad).all()
    # Clamped coordinates get no gradient (1 + 1e-7 rounds onto the edge, which still has one).
    assert (x_grad[x.detach().abs() > 1.001] == 0).all()
    torch.testing.assert_close(out, encoding(x.detach().clamp(-1.0, 1.0)))


def test_output_shape_and_dtype():
    encoding = HashGridEncoding(**SMALL)
    assert encoding.output_dim == 16
    out = encoding(torch.rand(4, 5, 3, dtype=torch.float64))
    assert out.shape == (4, 5, 16) and out.dtype == torch.float32
    assert encoding(torch.zeros(0, 3)).shape == (0, 16)


def test_active_level_mask_zeroes_the_finest_levels():
    encoding = HashGridEncoding(**SMALL, init_scale=1.0)
    x = _points(200, bound=1.0)
    full = encoding(x)
    encoding.set_active_levels(3)
    partial = encoding(x)
    mask = torch.arange(encoding.output_dim) < 3 * encoding.n_features_per_level
    assert mask.tolist() == [True] * 6 + [False] * 10
    assert (partial[:, ~mask] == 0).all()
    torch.testing.assert_close(partial[:, mask], full[:, mask])
    (table_grad,) = torch.autograd.grad(partial.sum(), encoding.table)
    assert (table_grad[:, encoding.offsets[3] :] == 0).all() and table_grad[:, : encoding.offsets[3]].abs().sum() > 0
    assert (encoding(x, n_active_levels=0) == 0).all()
    torch.testing.assert_close(encoding(x, n_active_levels=8), full)
    with pytest.raises(ValueError):
        encoding.set_active_levels(9)


def test_the_table_is_drawn_entry_by_entry_and_stored_feature_major():
    torch.manual_seed(3)
    encoding = HashGridEncoding(**SMALL, init_scale=0.5)
    torch.manual_seed(3)
    entries = torch.empty(encoding.table.shape[1], encoding.table.shape[0]).uniform_(-0.5, 0.5)
    assert torch.equal(encoding.table.detach(), entries.t())


def test_an_entry_major_checkpoint_loads_transposed():
    """A table saved as ``[total_entries, F]`` (the earlier layout) loads into the feature-major one and
    encodes exactly as before."""
    saved = HashGridEncoding(**SMALL, init_scale=1.0)
    x = _points(300, bound=1.0)
    loaded = HashGridEncoding(**SMALL)
    loaded.load_state_dict({"table": saved.table.detach().t().contiguous()})
    assert torch.equal(loaded(x), saved(x))
    with pytest.raises(RuntimeError):
        loaded.load_state_dict({"table": torch.zeros(3, 5)})


def test_cells_and_fractions_are_contiguous_along_the_points():
    """The index and weight tensors inherit this layout; a strided one (from ``x01.t()``) made every
    elementwise kernel of the encoding run unvectorized."""
    encoding = HashGridEncoding(**SMALL)
    cell, frac = hash_grid.cell_corners(torch.rand(50, 3), encoding._resolutions)
    assert cell.is_contiguous() and frac.is_contiguous()
    indices, _ = hash_grid._corners(torch.rand(50, 3), encoding.levels())
    assert indices.is_contiguous()


@pytest.fixture
def two_threads():
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(before)


def test_the_threaded_lookup_gives_the_same_bits_as_index_select(two_threads):
    """With several CPU threads the corners are looked up with ``torch.gather``: the same values and table
    gradients as ``index_select``, bit for bit."""
    table = torch.randn(2, 5000, requires_grad=True)
    indices = torch.randint(0, 5000, (3, 8, 700))
    weights = torch.randn(2, 3, 8, 700)
    threaded = hash_grid._gather(table, indices)
    plain = table.index_select(1, indices.reshape(-1)).view(2, *indices.shape)
    assert torch.equal(threaded, plain)
    grads = [torch.autograd.grad((rows * weights).sum(), table)[0] for rows in (threaded, plain)]
    assert torch.equal(grads[0], grads[1])


def test_the_threaded_lookup_passes_gradcheck_and_gradgradcheck(two_threads):
    encoding = _tiny_double_encoding()
    x = (torch.rand(4, 3, dtype=torch.float64) * 1.8 - 0.9).requires_grad_()
    assert torch.autograd.gradcheck(lambda points, table: encoding(points), (x, encoding.table))
    assert torch.autograd.gradgradcheck(lambda points, table: encoding(points), (x, encoding.table))
