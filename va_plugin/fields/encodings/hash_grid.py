"""Multiresolution hash encoding (Müller et al. 2022, "Instant Neural Graphics Primitives").

A point is looked up in ``L`` grids of growing resolution: coarse levels whose vertices fit in the
table are indexed directly, finer ones hash their vertices into ``T`` entries. Each level trilinearly
interpolates its cell's 8 corner features; the levels are concatenated.

All levels share one table with per-level offsets, so one gather and one ``index_add_`` serve every
level. The table is stored feature-major, ``[F, total_entries]``, so that gather and scatter run along
contiguous rows, and the gathered tensors are laid out ``[F, n_levels, 8, n_points]`` so broadcasts run
along the long, contiguous point axis. On CPU points go in chunks of :data:`CPU_CHUNK_POINTS` so the
allocator recycles the temporaries.

Gradients: a custom autograd function gives first-order gradients from an analytic backward that
recomputes the corners; a second-order gradient (``create_graph=True``) falls back to plain autograd.
Input gradients are zero outside ``[-bound, bound]`` (points are clamped).

On CPU, float32 lookups whose points need no gradient (training samples, probes, rendering) run on the
fused kernels of :mod:`hash_kernel` when they can be built; this module's PyTorch code is the path
everywhere else and the reference the kernels are tested against.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from va_plugin.errors import ConfigError
from va_plugin.fields.encodings import hash_kernel

# Per-axis multipliers of the spatial hash (Teschner et al. 2003, as used by InstantNGP).
HASH_PRIMES = (1, 2654435761, 805459861)

# Points per chunk on CPU: the largest temporary, [16 levels, 8, chunk] int64, stays below glibc's
# 32 MB mmap threshold, so it is recycled.
CPU_CHUNK_POINTS = 16384


def grid_resolutions(n_levels: int, base_resolution: int, max_resolution: int) -> list[int]:
    """Cells per axis of each level: ``N_l = floor(base * b**l)``, ``b = exp((ln max - ln base) / (L - 1))``."""
    if n_levels == 1:
        return [base_resolution]
    growth = math.exp((math.log(max_resolution) - math.log(base_resolution)) / (n_levels - 1))
    # The epsilon keeps float round-off from dropping an exact integer (2048 -> 2047) under floor.
    return [math.floor(base_resolution * growth**level + 1e-6) for level in range(n_levels)]


def is_dense_level(resolution: int, hashmap_size: int) -> bool:
    """Whether all ``(resolution + 1)**3`` vertices of a level fit in its table, so no hash is needed."""
    return (resolution + 1) ** 3 <= hashmap_size


def level_table_sizes(resolutions: Sequence[int], hashmap_size: int) -> list[int]:
    """Entries of each level's table: the dense vertex count when it fits, else ``hashmap_size``."""
    return [(r + 1) ** 3 if is_dense_level(r, hashmap_size) else hashmap_size for r in resolutions]


def level_offsets(sizes: Sequence[int]) -> list[int]:
    """Row of the shared table where each level starts."""
    return [sum(sizes[:level]) for level in range(len(sizes))]


def index_multipliers(resolutions: Sequence[int], hashmap_size: int) -> list[list[int]]:
    """Per-level, per-axis integer multipliers: row-major strides for dense levels, hash primes otherwise."""
    return [
        [1, r + 1, (r + 1) ** 2] if is_dense_level(r, hashmap_size) else list(HASH_PRIMES)
        for r in resolutions
    ]


class GridLevels(NamedTuple):
    """Per-level constants of a grid, as tensors on the table's device (levels ordered coarse to fine)."""

    resolutions: torch.Tensor  # [n_levels] int64 cells per axis
    multipliers: torch.Tensor  # [n_levels, 3] int64, see index_multipliers
    offsets: torch.Tensor  # [n_levels] int64 first table row of each level
    n_dense: int  # the first n_dense levels are dense, the rest hashed
    hashmap_size: int  # T, a power of two

    def first(self, n: int) -> GridLevels:
        """The ``n`` coarsest levels."""
        return GridLevels(
            self.resolutions[:n], self.multipliers[:n], self.offsets[:n], min(self.n_dense, n), self.hashmap_size
        )


def normalise_points(x: torch.Tensor, bound: float) -> torch.Tensor:
    """Map ``[-bound, bound]`` to ``[0, 1]``, clamping points outside to the domain edge. ``[..., 3]``."""
    return ((x + bound) / (2.0 * bound)).clamp(0.0, 1.0)


def cell_corners(x01: torch.Tensor, resolutions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The cell holding each point ``x01 [n_points, 3]`` (in ``[0, 1]``) on each level (``resolutions
    [n_levels]`` int64): ``cell [n_levels, 3, n_points]`` int64 lower corner in ``[0, N_l - 1]`` (a point
    at 1 falls in the last cell with fraction 1) and ``frac [n_levels, 3, n_points]`` in ``[0, 1]``,
    differentiable w.r.t. ``x01``; both contiguous."""
    # Contiguous along the points: every index and weight tensor derived from these inherits the layout,
    # and elementwise kernels vectorize only along a contiguous innermost axis.
    pos = x01.t().contiguous()[None] * resolutions.to(x01.dtype)[:, None, None]
    upper = (resolutions - 1)[:, None, None]
    # Clamping the integers (not the floats) also keeps NaN inputs from producing stray indices.
    cell = torch.minimum(pos.detach().floor().long().clamp_min(0), upper)
    return cell, pos - cell.to(pos.dtype)


def corner_indices(cell: torch.Tensor, levels: GridLevels) -> torch.Tensor:
    """Index ``[n_levels, 8, n_points]`` int64 of the 8 corners of each cell (``cell [n_levels, 3,
    n_points]`` int64 lower corners) within its level's table; corner ``4 i + 2 j + k`` is the vertex
    ``cell + (i, j, k)``."""
    axis_steps = torch.arange(2, device=cell.device)[:, None]
    # [n_levels, 3, 2, n_points]: each axis' two vertex coordinates times that axis' multiplier.
    terms = (cell[:, :, None, :] + axis_steps) * levels.multipliers[:, :, None, None]
    tx = terms[:, 0, :, None, None]
    ty = terms[:, 1, None, :, None]
    tz = terms[:, 2, None, None, :]
    n = levels.n_dense
    # Both level groups are written into one buffer: no concatenation copy of the largest tensor.
    indices = cell.new_empty(cell.shape[0], 2, 2, 2, cell.shape[2])
    torch.add(tx[:n] + ty[:n], tz[:n], out=indices[:n])
    # int64 products keep the low 32 bits of InstantNGP's uint32 hash, and T <= 2**32 is a power
    # of two, so masking equals both "mod T" and InstantNGP's wrap-around.
    torch.bitwise_xor(tx[n:] ^ ty[n:], tz[n:], out=indices[n:]).bitwise_and_(levels.hashmap_size - 1)
    return indices.flatten(1, 3)


def axis_weights(frac: torch.Tensor) -> torch.Tensor:
    """Linear weights of the lower and upper vertex along each axis. ``[n_levels, 3, 2, n_points]``."""
    return torch.stack([1.0 - frac, frac], dim=2)


def corner_weights(frac: torch.Tensor) -> torch.Tensor:
    """Trilinear weights ``[n_levels, 8, n_points]`` of the corners of :func:`corner_indices`, from
    ``frac`` ``[n_levels, 3, n_points]``; they sum to 1 over the corners."""
    per_axis = axis_weights(frac)
    wx = per_axis[:, 0, :, None, None]
    wy = per_axis[:, 1, None, :, None]
    wz = per_axis[:, 2, None, None, :]
    return (wx * wy * wz).flatten(1, 3)


def _corners(x01: torch.Tensor, levels: GridLevels) -> tuple[torch.Tensor, torch.Tensor]:
    """Table rows ``[n_levels, 8, n_points]`` of every corner and the in-cell position ``frac``."""
    cell, frac = cell_corners(x01, levels.resolutions)
    indices = corner_indices(cell, levels).add_(levels.offsets[:, None, None])
    return indices, frac


class _TableRows(torch.autograd.Function):
    """``table.index_select(1, flat[0])`` for a feature-major ``table [F, entries]`` and indices ``flat [1,
    n]``, looked up with ``torch.gather`` (which splits the work across CPU threads, where ``index_select``
    along the second axis runs on one) and differentiated as ``index_select`` is: one ``index_add``, so the
    values and gradients are the same bits."""

    @staticmethod
    def forward(ctx, table: torch.Tensor, flat: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(flat)
        ctx.entries = table.shape[1]
        return torch.gather(table, 1, flat.expand(table.shape[0], -1))

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        (flat,) = ctx.saved_tensors
        # Out of place, so that a backward under create_graph=True stays differentiable.
        zeros = grad.new_zeros(grad.shape[0], ctx.entries)
        return zeros.index_add(1, flat[0], grad), None


def _gather(table: torch.Tensor, indices: torch.Tensor) -> torch.Tensor:
    """Corner features ``[F, n_levels, 8, n_points]`` of table entries ``[n_levels, 8, n_points]`` from the
    feature-major ``table [F, total_entries]``, in one gather."""
    flat = indices.reshape(1, -1)
    if table.device.type == "cpu" and torch.get_num_threads() > 1:
        rows = _TableRows.apply(table, flat)
    else:  # on one thread index_select is the faster; GPUs keep the lookup their timings were taken with
        rows = table.index_select(1, flat[0])
    return rows.view(table.shape[0], *indices.shape)


def encode_points(x01: torch.Tensor, table: torch.Tensor, levels: GridLevels) -> torch.Tensor:
    """Differentiable encoding of points ``[n_points, 3]`` in ``[0, 1]`` with the feature-major ``table [F,
    total_entries]``. ``[n_points, n_levels * F]``."""
    indices, frac = _corners(x01, levels)
    per_level = (_gather(table, indices) * corner_weights(frac)).sum(2)
    return per_level.permute(2, 1, 0).reshape(x01.shape[0], -1)


def _frac_gradient(corner_grad: torch.Tensor, frac: torch.Tensor) -> torch.Tensor:
    """Gradient w.r.t. ``frac`` ``[n_levels, 3, n_points]`` from the gradient w.r.t. the corner weights
    ``[n_levels, 8, n_points]`` (a weight's derivative along an axis: the other two axes' weights, signed)."""
    g = corner_grad.unflatten(1, (2, 2, 2))
    w = axis_weights(frac)
    wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
    # Contract the last remaining axis first so the second product runs on half as many elements.
    dx = (((g[:, 1] - g[:, 0]) * wz[:, None]).sum(2) * wy).sum(1)
    dy = (((g[:, :, 1] - g[:, :, 0]) * wz[:, None]).sum(2) * wx).sum(1)
    dz = (((g[:, :, :, 1] - g[:, :, :, 0]) * wy[:, None]).sum(2) * wx).sum(1)
    return torch.stack([dx, dy, dz], dim=1)


def _chunk_size(x01: torch.Tensor) -> int:
    """Points per chunk: cache-sized on CPU, the whole batch elsewhere."""
    return CPU_CHUNK_POINTS if x01.device.type == "cpu" else max(x01.shape[0], 1)


class _HashGridFunction(torch.autograd.Function):
    """``encode_points`` with a chunked forward and an analytic, recomputing first-order backward."""

    @staticmethod
    def forward(ctx, x01: torch.Tensor, table: torch.Tensor, levels: GridLevels) -> torch.Tensor:
        ctx.levels = levels
        ctx.save_for_backward(x01, table)
        n_points, chunk = x01.shape[0], _chunk_size(x01)
        out = x01.new_empty(n_points, levels.offsets.shape[0] * table.shape[0])
        for start in range(0, n_points, chunk):
            out[start : start + chunk] = encode_points(x01[start : start + chunk], table, levels)
        return out

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        x01, table = ctx.saved_tensors
        need_x, need_table = ctx.needs_input_grad[:2]
        if torch.is_grad_enabled():
            return _HashGridFunction._differentiable_backward(ctx, x01, table, grad_out)
        grad_table = torch.zeros_like(table) if need_table else None
        grad_x = torch.empty_like(x01) if need_x else None
        chunk = _chunk_size(x01)
        for start in range(0, x01.shape[0], chunk):
            part = slice(start, start + chunk)
            x_part = _backward_chunk(x01[part], table, ctx.levels, grad_out[part], grad_table, need_x)
            if need_x:
                grad_x[part] = x_part
        return grad_x, grad_table, None

    @staticmethod
    def _differentiable_backward(ctx, x01: torch.Tensor, table: torch.Tensor, grad_out: torch.Tensor):
        """Backward under ``create_graph=True``: plain autograd of :func:`encode_points`, so the
        returned gradients can themselves be differentiated (e.g. an eikonal loss)."""
        needed = [t for t, need in zip((x01, table), ctx.needs_input_grad) if need]
        grads = iter(torch.autograd.grad(encode_points(x01, table, ctx.levels), needed, grad_out, create_graph=True))
        return tuple(next(grads) if need else None for need in ctx.needs_input_grad[:2]) + (None,)


def _backward_chunk(
    x01: torch.Tensor,
    table: torch.Tensor,
    levels: GridLevels,
    grad_out: torch.Tensor,
    grad_table: torch.Tensor | None,
    need_x: bool,
) -> torch.Tensor | None:
    """Accumulate one chunk's table gradient into ``grad_table`` ``[F, total_entries]`` (if given) and
    return its point gradient ``[n_points, 3]`` (if ``need_x``); ``x01`` ``[n_points, 3]``, ``grad_out``
    ``[n_points, n_levels * F]``."""
    indices, frac = _corners(x01, levels)
    n_levels, n_features = indices.shape[0], table.shape[0]
    grad_levels = grad_out.reshape(-1, n_levels, n_features).permute(2, 1, 0).contiguous()
    if grad_table is not None:
        rows = grad_levels[:, :, None, :] * corner_weights(frac)
        # One scatter for all levels and features, along the table's contiguous rows like the gather.
        grad_table.index_add_(1, indices.reshape(-1), rows.view(n_features, -1))
    if not need_x:
        return None
    corner_grad = (_gather(table, indices) * grad_levels[:, :, None, :]).sum(0)
    # frac = x01 * N_l - cell, and the cell is piecewise constant.
    scale = levels.resolutions.to(x01.dtype)[:, None, None]
    return (_frac_gradient(corner_grad, frac) * scale).sum(0).t()


class HashGridEncoding(nn.Module):
    """Multiresolution hash encoding of 3D points.

    Args:
        n_levels: number of grids ``L``.
        n_features_per_level: features ``F`` stored per vertex.
        log2_hashmap_size: ``log2(T)``, the most entries a level's table may have.
        base_resolution: cells per axis of the coarsest level.
        max_resolution: cells per axis of the finest level.
        bound: points in ``[-bound, bound]^3`` are encoded; points outside are clamped to its edge.
        init_scale: tables start uniform in ``[-init_scale, init_scale]``.

    Attributes: ``output_dim`` (``L * F``), ``resolutions``, ``offsets`` (first table row of each
    level), ``hashmap_size`` (``T``), ``n_dense_levels`` (coarse levels indexed directly),
    ``n_active_levels`` (levels that contribute, see :meth:`set_active_levels`) and ``table``
    (``[F, total_entries]``, every level, feature-major; checkpoints holding the entry-major
    ``[total_entries, F]`` table load as well).
    """

    def __init__(
        self,
        n_levels: int = 16,
        n_features_per_level: int = 2,
        log2_hashmap_size: int = 19,
        base_resolution: int = 16,
        max_resolution: int = 2048,
        bound: float = 1.0,
        init_scale: float = 1e-4,
    ) -> None:
        super().__init__()
        if n_levels < 1 or n_features_per_level < 1:
            raise ConfigError(f"n_levels and features_per_level must be at least 1, got {n_levels} and "
                              f"{n_features_per_level}")
        if not 1 <= log2_hashmap_size <= 32:
            raise ConfigError(f"log2_hashmap_size must be in [1, 32], got {log2_hashmap_size}")
        if not 1 <= base_resolution <= max_resolution:
            raise ConfigError(f"the hash grid needs 1 <= base_resolution <= max_resolution, got {base_resolution} "
                              f"and {max_resolution}")
        if bound <= 0:
            raise ConfigError(f"bound must be positive, got {bound}")
        self.n_levels = n_levels
        self.n_features_per_level = n_features_per_level
        self.hashmap_size = 2**log2_hashmap_size
        self.bound = float(bound)
        self.output_dim = n_levels * n_features_per_level
        self.resolutions = grid_resolutions(n_levels, base_resolution, max_resolution)
        self.n_dense_levels = sum(is_dense_level(r, self.hashmap_size) for r in self.resolutions)
        self.n_active_levels = n_levels
        sizes = level_table_sizes(self.resolutions, self.hashmap_size)
        self.offsets = level_offsets(sizes)
        # Drawn entry by entry, then stored feature-major: the same values as an entry-major table.
        entries = torch.empty(sum(sizes), n_features_per_level)
        nn.init.uniform_(entries, -init_scale, init_scale)
        self.table = nn.Parameter(entries.t().contiguous())
        # Derived from the arguments, so kept out of the state dict; buffers follow .to(device).
        self.register_buffer("_resolutions", torch.tensor(self.resolutions), persistent=False)
        self.register_buffer("_offsets", torch.tensor(self.offsets), persistent=False)
        multipliers = torch.tensor(index_multipliers(self.resolutions, self.hashmap_size))
        self.register_buffer("_multipliers", multipliers, persistent=False)

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        # An entry-major [total_entries, F] table (the earlier layout) is transposed on load.
        key = prefix + "table"
        stored = state_dict.get(key)
        if stored is not None and stored.shape != self.table.shape and stored.shape == self.table.shape[::-1]:
            state_dict[key] = stored.t().contiguous()
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def levels(self) -> GridLevels:
        """The per-level constants, on the module's device."""
        return GridLevels(self._resolutions, self._multipliers, self._offsets, self.n_dense_levels, self.hashmap_size)

    def set_active_levels(self, n_active: int) -> None:
        """Let only the ``n_active`` coarsest levels contribute; the rest output zeros."""
        if not 0 <= n_active <= self.n_levels:
            raise ValueError(f"n_active must be in [0, {self.n_levels}], got {n_active}")
        self.n_active_levels = n_active

    def forward(self, x: torch.Tensor, n_active_levels: int | None = None) -> torch.Tensor:
        """Encode points ``x [..., 3]`` -> ``[..., output_dim]`` in the table's dtype, inactive levels'
        channels zero; ``n_active_levels`` overrides :attr:`n_active_levels` for this call."""
        n_active = self.n_active_levels if n_active_levels is None else n_active_levels
        points = normalise_points(x.reshape(-1, 3).to(self.table.dtype), self.bound)
        if n_active == 0:
            return points.new_zeros(*x.shape[:-1], self.output_dim)
        levels = self.levels().first(n_active)
        if hash_kernel.usable(points, self.table, self.hashmap_size):
            encoded = hash_kernel.encode(points, self.table, levels)
        else:
            encoded = _HashGridFunction.apply(points, self.table, levels)
        encoded = F.pad(encoded, (0, self.output_dim - encoded.shape[1]))
        return encoded.view(*x.shape[:-1], self.output_dim)

    def forward_with_pullback(self, x: torch.Tensor):
        """The encoding ``[n_points, output_dim]`` of points ``[n_points, 3]`` and a function mapping a
        derivative w.r.t. it to one w.r.t. the points in world units, ``[n_points, 3]`` (zero outside
        ``[-bound, bound]``); see :func:`encode_with_pullback`."""
        n_active = self.n_active_levels
        flat = x.reshape(-1, 3).to(self.table.dtype)
        points = normalise_points(flat, self.bound)
        width = n_active * self.n_features_per_level
        if n_active == 0 or points.shape[0] == 0:
            return points.new_zeros(points.shape[0], self.output_dim), lambda grad: points.new_zeros(points.shape)
        inside = ((flat > -self.bound) & (flat < self.bound)).to(flat.dtype) / (2.0 * self.bound)
        levels = self.levels().first(n_active)
        lookup = (hash_kernel.encode_with_pullback if hash_kernel.usable(points, self.table, self.hashmap_size)
                  else encode_with_pullback)
        encoded, pull = lookup(points, self.table, levels)

        def pullback(grad_encoded: torch.Tensor) -> torch.Tensor:
            return pull(grad_encoded[:, :width]) * inside

        return F.pad(encoded, (0, self.output_dim - width)), pullback


def encode_with_pullback(x01: torch.Tensor, table: torch.Tensor, levels: GridLevels):
    """The encoding ``[n_points, n_levels * F]`` and a function that pulls a derivative w.r.t. it back to
    the points (``[n_points, 3]``, d/d x01): a vector-Jacobian product through :func:`_frac_gradient`
    that never builds the Jacobian. Plain autograd, so the result is differentiable in ``table``
    (an eikonal loss trains the table in one ordinary backward)."""
    indices, frac = _corners(x01, levels)
    corners = _gather(table, indices)  # [F, L, 8, N]
    encoded = (corners * corner_weights(frac)).sum(2)  # [F, L, N]
    n, n_levels, n_features = x01.shape[0], indices.shape[0], table.shape[0]
    scale = levels.resolutions.to(frac.dtype)[:, None, None]

    def pullback(grad_encoded: torch.Tensor) -> torch.Tensor:
        per_level = grad_encoded.reshape(n, n_levels, n_features).permute(2, 1, 0)  # [F, L, N]
        corner_grad = (corners * per_level[:, :, None, :]).sum(0)  # [L, 8, N]
        return (_frac_gradient(corner_grad, frac) * scale).sum(0).t()

    return encoded.permute(2, 1, 0).reshape(n, -1), pullback
