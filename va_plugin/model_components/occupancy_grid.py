"""An occupancy grid for skipping empty space, and the small marching helpers that use it.

A ``R^3`` lattice over ``[-bound, bound]^3``. Each update evaluates the density at one random point per
cell, turns it into the opacity across one cell, ``1 - exp(-density * cell_size)``, and keeps
``max(decay * old, new)``. A cell is occupied when its value exceeds ``min(threshold, mean value)`` (the
mean keeps a faint field from being pruned empty). During the warm-up every cell is occupied and
updates overwrite the values. :func:`scatter` moves packed samples (``dense[keep]``) back to the dense
``[n_rays, n_samples]`` layout.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import nn

from va_plugin.config import InstantiateConfig
from va_plugin.errors import ConfigError
from va_plugin.model_components.renderers import TRANSMITTANCE_EPS

UPDATE_CHUNK = 65536
"""Cells whose density is evaluated at once during an update."""


@dataclass
class OccupancyGridConfig(InstantiateConfig):
    """A max-decay occupancy grid over the scene bound, updated from the field's density."""

    _target: type = field(default_factory=lambda: OccupancyGrid)
    enabled: bool = True
    """Skip samples in empty cells (off: every sample inside the bounding sphere is evaluated)."""
    resolution: int = 64
    """Cells per axis."""
    update_every: int = 16
    """Training steps between grid updates."""
    warmup_steps: int = 64
    """Steps during which every cell counts as occupied (the field is still meaningless)."""
    decay: float = 0.95
    """Factor applied to a cell's value at each update before the max with the new value."""
    threshold: float = 0.01
    """Opacity across one cell (1 - exp(-density * cell size)) below which a cell is empty; the
    threshold used is min(this, the mean over cells), so a faint field keeps its denser half."""
    min_view_fraction: float = 1.0
    """After the warm-up, a cell can be occupied only if its centre projects inside at least this share
    of the training views (density seen by one view alone is a floater). 0 turns the test off."""


class OccupancyGrid(nn.Module):
    """Occupancy of ``resolution^3`` cells over ``[-bound, bound]^3``.

    Buffers (checkpointed): ``values`` ``[R, R, R]`` float (running cell opacity), ``binary``
    ``[R, R, R]`` bool (the occupancy :meth:`occupied` reads; all True until the first update after
    the warm-up) and ``seen`` ``[R, R, R]`` bool (cells that may be occupied, see :meth:`restrict_to_views`).
    """

    def __init__(self, config: OccupancyGridConfig, bound: float) -> None:
        super().__init__()
        if config.resolution < 1 or config.update_every < 1 or config.warmup_steps < 0:
            raise ConfigError("occupancy_grid needs resolution >= 1, update_every >= 1 and warmup_steps >= 0")
        if not 0.0 < config.decay <= 1.0:
            raise ConfigError(f"occupancy_grid.decay must be in (0, 1], got {config.decay}")
        if not 0.0 <= config.threshold < 1.0:
            raise ConfigError(f"occupancy_grid.threshold is an opacity in [0, 1), got {config.threshold}")
        if not 0.0 <= config.min_view_fraction <= 1.0:
            raise ConfigError(f"occupancy_grid.min_view_fraction must be in [0, 1], got {config.min_view_fraction}")
        if bound <= 0:
            raise ConfigError(f"the occupancy grid's bound must be positive, got {bound}")
        self.config = config
        self.bound = float(bound)
        self.resolution = config.resolution
        self.cell_size = 2.0 * self.bound / self.resolution
        r = self.resolution
        self.register_buffer("values", torch.zeros(r, r, r))
        self.register_buffer("binary", torch.ones(r, r, r, dtype=torch.bool))
        self.register_buffer("seen", torch.ones(r, r, r, dtype=torch.bool))
        # Cells that meet the bounding sphere (centre closer than radius + half a cell diagonal):
        # the only ones rays sample, so the only ones evaluated and counted in the mean.
        index = torch.arange(r ** 3)
        centres = self._cell_points(index, torch.full((r ** 3, 3), 0.5))
        inside = centres.norm(dim=-1) < self.bound + 0.5 * math.sqrt(3.0) * self.cell_size
        self.register_buffer("cells", index[inside], persistent=False)

    def _cell_points(self, flat_index: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
        """World points ``[n, 3]`` at ``offset`` (``[n, 3]`` in [0, 1)) inside the cells ``flat_index [n]``."""
        r = self.resolution
        ijk = torch.stack([flat_index // (r * r), (flat_index // r) % r, flat_index % r], dim=-1)
        return (ijk.to(offset.dtype) + offset) * self.cell_size - self.bound

    @torch.no_grad()
    def restrict_to_views(self, cameras, min_views: int) -> None:
        """Let only cells whose centre projects inside at least ``min_views`` of ``cameras`` (a
        :class:`va_plugin.cameras.Cameras`, in front of the camera and within the image) be occupied."""
        r = self.resolution
        index = torch.arange(r ** 3, device=self.values.device)
        centres = self._cell_points(index, torch.full((r ** 3, 3), 0.5, device=index.device))
        count = torch.zeros(r ** 3, dtype=torch.long, device=index.device)
        for view in range(len(cameras)):
            uv, depth = cameras.project(centres, view)
            inside = (depth > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= cameras.width - 0.5) \
                & (uv[:, 1] >= -0.5) & (uv[:, 1] <= cameras.height - 0.5)
            count += inside.long()
        self.seen.copy_((count >= min_views).view_as(self.seen))

    @torch.no_grad()
    def update(self, step: int, density_fn: Callable[[torch.Tensor], torch.Tensor]) -> None:
        """Re-evaluate every cell that meets the sphere (and may be occupied) at a random point and
        refresh ``binary``.

        Args:
            step: the training step (the warm-up is measured in steps).
            density_fn: points ``[n, 3]`` -> density ``[n]`` (>= 0).
        """
        cells = self.cells[self.seen.view(-1)[self.cells]]
        points = self._cell_points(cells, torch.rand(cells.shape[0], 3, device=cells.device))
        density = torch.cat([density_fn(chunk).reshape(-1) for chunk in torch.split(points, UPDATE_CHUNK)])
        density = torch.nan_to_num(density.float(), nan=0.0, posinf=1e6).clamp_min(0.0)
        opacity = 1.0 - torch.exp(-(density * self.cell_size).clamp_max(80.0))
        flat = self.values.view(-1)
        if step < self.config.warmup_steps:
            # No memory of the untrained field's uniform density.
            flat[cells] = opacity
            self.binary.fill_(True)
            return
        flat[cells] = torch.maximum(flat[cells] * self.config.decay, opacity)
        if cells.numel() == 0:
            self.binary.fill_(False)
            return
        threshold = min(self.config.threshold, float(flat[cells].mean()))
        binary = torch.zeros_like(flat, dtype=torch.bool)
        binary[cells] = flat[cells] > threshold
        self.binary.copy_(binary.view_as(self.binary))

    def occupied(self, points: torch.Tensor) -> torch.Tensor:
        """Whether each point ``[..., 3]`` lies in an occupied cell, ``[...]`` bool (False outside the grid)."""
        r = self.resolution
        scaled = (points + self.bound) / self.cell_size
        inside = ((scaled >= 0) & (scaled < r)).all(-1)
        ijk = scaled.floor().long().clamp(0, r - 1)
        flat = (ijk[..., 0] * r + ijk[..., 1]) * r + ijk[..., 2]
        return self.binary.view(-1)[flat] & inside

    def occupied_fraction(self) -> float:
        """Share of the cells meeting the bounding sphere that are occupied."""
        return float(self.binary.view(-1)[self.cells].float().mean())


def transmittance_before(alpha: torch.Tensor) -> torch.Tensor:
    """Transmittance in front of each sample, ``prod_{j<i} (1 - alpha_j)``, ``[n_rays, n_samples]``."""
    shifted = torch.cat([torch.ones_like(alpha[:, :1]), 1.0 - alpha[:, :-1] + TRANSMITTANCE_EPS], dim=-1)
    return torch.cumprod(shifted, dim=-1)


def scatter(packed: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """Inverse of ``dense[keep]``: ``[n_kept, ...]`` -> ``[n_rays, n_samples, ...]``, zeros where not kept;
    differentiable w.r.t. ``packed`` (even an empty one)."""
    dense = packed.new_zeros(keep.shape + packed.shape[1:])
    return dense.index_put((keep,), packed)
