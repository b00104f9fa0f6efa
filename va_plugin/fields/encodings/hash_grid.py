"""Multiresolution hash encoding (Müller et al. 2022, "Instant Neural Graphics Primitives"), pure PyTorch.

A point is looked up in ``L`` grids of growing resolution. Coarse levels whose dense vertex grid fits
in the table are indexed directly (no collisions); finer levels hash their vertices into ``T``
entries. Each level trilinearly interpolates the features at the 8 corners of the cell holding the
point, and the levels are concatenated.

All levels live in one ``[total_entries, F]`` table with per-level offsets, and the fast path works
on all levels at once: one gather in the forward pass and one ``index_add_`` in the backward pass.
Corner indices are laid out level-major (``[n_levels, n_points, 8]``) so that each level's part of
the gather and of the scatter touches one level's slice of the table at a time; on CPU this keeps the
working set in cache and is 2-3x faster than a point-major layout.

Gradients: the table always gets gradients. The input ``x`` gets first- and second-order gradients
through plain autograd (``create_graph=True`` works, as an eikonal loss needs); they are zero where
``x`` lies outside ``[-bound, bound]`` (the point is clamped) and, as in every hash grid, the
gradient is discontinuous across cell faces.
"""

from __future__ import annotations

import math
from typing import List, Optional, Sequence

import torch
import torch.nn.functional as F
from torch import nn

# Per-axis multipliers of the spatial hash (Teschner et al. 2003, as used by InstantNGP).
HASH_PRIMES = (1, 2654435761, 805459861)


def grid_resolutions(n_levels: int, base_resolution: int, max_resolution: int) -> List[int]:
    """Cells per axis of each level: ``N_l = floor(base * b**l)``, ``b = exp((ln max - ln base) / (L - 1))``."""
    if n_levels == 1:
        return [base_resolution]
    growth = math.exp((math.log(max_resolution) - math.log(base_resolution)) / (n_levels - 1))
    # The epsilon keeps float round-off from dropping an exact integer (2048 -> 2047) under floor.
    return [int(math.floor(base_resolution * growth**level + 1e-6)) for level in range(n_levels)]


def is_dense_level(resolution: int, hashmap_size: int) -> bool:
    """Whether all ``(resolution + 1)**3`` vertices of a level fit in its table, so no hash is needed."""
    return (resolution + 1) ** 3 <= hashmap_size


def level_table_sizes(resolutions: Sequence[int], hashmap_size: int) -> List[int]:
    """Entries of each level's table: the dense vertex count when it fits, else ``hashmap_size``."""
    return [(r + 1) ** 3 if is_dense_level(r, hashmap_size) else hashmap_size for r in resolutions]


def level_offsets(sizes: Sequence[int]) -> List[int]:
    """Row of the shared table where each level starts."""
    return [sum(sizes[:level]) for level in range(len(sizes))]


def index_multipliers(resolutions: Sequence[int], hashmap_size: int) -> List[List[int]]:
    """Per-level, per-axis integer multipliers: row-major strides for dense levels, hash primes otherwise."""
    return [
        [1, r + 1, (r + 1) ** 2] if is_dense_level(r, hashmap_size) else list(HASH_PRIMES)
        for r in resolutions
    ]


def normalise_points(x: torch.Tensor, bound: float) -> torch.Tensor:
    """Map ``[-bound, bound]`` to ``[0, 1]``, clamping points outside to the domain edge. ``[..., 3]``."""
    return ((x + bound) / (2.0 * bound)).clamp(0.0, 1.0)


def cell_corners(x01: torch.Tensor, resolutions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The cell holding each point on each level and the point's position inside it.

    Args:
        x01: ``[n_points, 3]`` points in ``[0, 1]``.
        resolutions: ``[n_levels]`` int64 cells per axis.

    Returns:
        ``cell`` ``[n_levels, n_points, 3]`` int64 lower corner, in ``[0, N_l - 1]`` (a point at 1
        falls in the last cell with fraction 1), and ``frac`` ``[n_levels, n_points, 3]`` in ``[0, 1]``,
        differentiable w.r.t. ``x01``.
    """
    scale = resolutions.to(x01.dtype)[:, None, None]
    pos = x01[None] * scale
    upper = (resolutions - 1)[:, None, None]
    # Clamping the integers (not the floats) also keeps NaN inputs from producing stray indices.
    cell = torch.minimum(pos.detach().floor().long().clamp_min(0), upper)
    return cell, pos - cell.to(pos.dtype)


def corner_indices(
    cell: torch.Tensor, multipliers: torch.Tensor, n_dense: int, hashmap_size: int
) -> torch.Tensor:
    """Per-level table index of the 8 corners of each cell, in ``[0, level size)``.

    Corner ``c = 4 i + 2 j + k`` is the vertex ``cell + (i, j, k)``.

    Args:
        cell: ``[n_levels, n_points, 3]`` int64 lower cell corners.
        multipliers: ``[n_levels, 3]`` int64, see :func:`index_multipliers`.
        n_dense: how many leading levels are dense (levels are ordered coarse to fine).
        hashmap_size: ``T``, a power of two.

    Returns:
        ``[n_levels, n_points, 8]`` int64.
    """
    axis_offsets = torch.arange(2, device=cell.device)
    # [n_levels, n_points, 3, 2]: each axis' two vertex coordinates times that axis' multiplier.
    terms = (cell[..., None] + axis_offsets) * multipliers[:, None, :, None]
    tx = terms[..., 0, :, None, None]
    ty = terms[..., 1, None, :, None]
    tz = terms[..., 2, None, None, :]
    dense = tx[:n_dense] + ty[:n_dense] + tz[:n_dense]
    # int64 products keep the low 32 bits of InstantNGP's uint32 hash, and T <= 2**32 is a power
    # of two, so masking equals both "mod T" and the reference implementation's wrap-around.
    hashed = (tx[n_dense:] ^ ty[n_dense:] ^ tz[n_dense:]) & (hashmap_size - 1)
    return torch.cat([dense, hashed]).flatten(-3)


def corner_weights(frac: torch.Tensor) -> torch.Tensor:
    """Trilinear weights of the 8 corners, ordered as in :func:`corner_indices`.

    Args:
        frac: ``[n_levels, n_points, 3]`` position inside the cell.

    Returns:
        ``[n_levels, n_points, 8]``, summing to 1 over the corners.
    """
    per_axis = torch.stack([1.0 - frac, frac], dim=-1)
    wx = per_axis[..., 0, :, None, None]
    wy = per_axis[..., 1, None, :, None]
    wz = per_axis[..., 2, None, None, :]
    return (wx * wy * wz).flatten(-3)


def interpolate(table: torch.Tensor, indices: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Weighted sum of the corner features of every level.

    Args:
        table: ``[total_entries, F]``.
        indices: ``[n_levels, n_points, 8]`` int64 global rows of ``table``.
        weights: ``[n_levels, n_points, 8]``.

    Returns:
        ``[n_levels, n_points, F]``.
    """
    features = table.index_select(0, indices.reshape(-1)).view(*indices.shape, table.shape[1])
    return torch.einsum("lncf,lnc->lnf", features, weights)


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

    Attributes:
        output_dim: ``L * F``.
        resolutions: cells per axis of each level.
        n_dense_levels: how many coarse levels are indexed directly (collision-free).
        n_active_levels: levels that contribute; the finer ones output zeros (coarse-to-fine schedules).
        table: ``[total_entries, F]`` parameter holding every level, level ``l`` starting at row
            ``offsets[l]``.
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
            raise ValueError("n_levels and n_features_per_level must be at least 1")
        if not 1 <= log2_hashmap_size <= 32:
            raise ValueError(f"log2_hashmap_size must be in [1, 32], got {log2_hashmap_size}")
        if not 1 <= base_resolution <= max_resolution:
            raise ValueError("need 1 <= base_resolution <= max_resolution")
        if bound <= 0:
            raise ValueError(f"bound must be positive, got {bound}")
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
        self.table = nn.Parameter(torch.empty(sum(sizes), n_features_per_level))
        nn.init.uniform_(self.table, -init_scale, init_scale)
        # Derived from the arguments, so kept out of the state dict; buffers follow .to(device).
        self.register_buffer("_resolutions", torch.tensor(self.resolutions), persistent=False)
        self.register_buffer("_offsets", torch.tensor(self.offsets), persistent=False)
        multipliers = torch.tensor(index_multipliers(self.resolutions, self.hashmap_size))
        self.register_buffer("_multipliers", multipliers, persistent=False)

    def set_active_levels(self, n_active: int) -> None:
        """Let only the ``n_active`` coarsest levels contribute; the rest output zeros."""
        if not 0 <= n_active <= self.n_levels:
            raise ValueError(f"n_active must be in [0, {self.n_levels}], got {n_active}")
        self.n_active_levels = n_active

    def level_mask(self, n_active: int) -> torch.Tensor:
        """``[output_dim]`` bool, True for the output channels of the ``n_active`` coarsest levels."""
        mask = torch.zeros(self.n_levels, self.n_features_per_level, dtype=torch.bool)
        mask[:n_active] = True
        return mask.flatten()

    def corner_indices(self, x: torch.Tensor) -> torch.Tensor:
        """Per-level table index (before adding the level offset) of each point's 8 corners.

        Args:
            x: ``[n_points, 3]``.

        Returns:
            ``[n_points, n_levels, 8]`` int64, each level's in ``[0, its table size)``.
        """
        cell, _ = cell_corners(normalise_points(x, self.bound), self._resolutions)
        indices = corner_indices(cell, self._multipliers, self.n_dense_levels, self.hashmap_size)
        return indices.transpose(0, 1)

    def forward(self, x: torch.Tensor, n_active_levels: Optional[int] = None) -> torch.Tensor:
        """Encode points.

        Args:
            x: ``[..., 3]`` points.
            n_active_levels: overrides :attr:`n_active_levels` for this call.

        Returns:
            ``[..., output_dim]`` in the table's dtype (float32 by default); the channels of inactive
            levels are zero.
        """
        n_active = self.n_active_levels if n_active_levels is None else n_active_levels
        points = normalise_points(x.reshape(-1, 3).to(self.table.dtype), self.bound)
        cell, frac = cell_corners(points, self._resolutions[:n_active])
        local = corner_indices(
            cell, self._multipliers[:n_active], min(self.n_dense_levels, n_active), self.hashmap_size
        )
        indices = local + self._offsets[:n_active, None, None]
        features = interpolate(self.table, indices, corner_weights(frac))
        # [n_active, n_points, F] -> [n_points, n_active * F], then zeros for the inactive levels.
        encoded = features.permute(1, 0, 2).reshape(points.shape[0], -1)
        encoded = F.pad(encoded, (0, self.output_dim - encoded.shape[1]))
        return encoded.view(*x.shape[:-1], self.output_dim)
