"""A plain, loop-per-level and loop-per-corner hash grid encoding, to check the fast path against.

It follows the InstantNGP paper directly and shares no code with the fast path except the hash
primes. It is slow; use :class:`~va_plugin.fields.encodings.hash_grid.HashGridEncoding` for work.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import torch

from va_plugin.fields.encodings.hash_grid import HASH_PRIMES


def _vertex_index(vertex: torch.Tensor, resolution: int, hashmap_size: int) -> torch.Tensor:
    """Index of grid vertices ``[n_points, 3]`` (int64) within their level's table. ``[n_points]``."""
    x, y, z = vertex.unbind(-1)
    side = resolution + 1
    if side**3 <= hashmap_size:
        return x + side * y + side * side * z
    hashed = (x * HASH_PRIMES[0]) ^ (y * HASH_PRIMES[1]) ^ (z * HASH_PRIMES[2])
    return hashed % hashmap_size


def hash_grid_reference(
    x: torch.Tensor,
    table: torch.Tensor,
    offsets: Sequence[int],
    resolutions: Sequence[int],
    hashmap_size: int,
    bound: float = 1.0,
) -> torch.Tensor:
    """Encode points ``[..., 3]`` into ``[..., n_levels * F]`` with ``table [total_entries, F]``; level ``l``
    has ``resolutions[l]`` cells per axis and starts at ``table[offsets[l]]``."""
    points = ((x.reshape(-1, 3).to(table.dtype) + bound) / (2 * bound)).clamp(0.0, 1.0)
    levels = []
    for offset, resolution in zip(offsets, resolutions):
        pos = points * resolution
        cell = pos.detach().floor().long().clamp(0, resolution - 1)
        frac = pos - cell.to(pos.dtype)
        level = torch.zeros(points.shape[0], table.shape[1], dtype=table.dtype, device=table.device)
        for corner in itertools.product((0, 1), repeat=3):
            step = torch.tensor(corner, device=x.device)
            weight = torch.where(step.bool(), frac, 1.0 - frac).prod(-1)
            index = offset + _vertex_index(cell + step, resolution, hashmap_size)
            level = level + weight[:, None] * table[index]
        levels.append(level)
    return torch.cat(levels, -1).view(*x.shape[:-1], -1)
