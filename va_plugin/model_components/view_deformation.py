"""Per-view geometric adaptation: a small, smooth deformation of space for each training view.

A generated view can draw the object's shape slightly wrong (a handle a little lower, a side a little
fatter). With one shared geometry every such view pulls the surface its own way. Here view i renders
the shared field at ``x + d_i(x)``: ``d_i`` is a coarse grid of displacements (``resolution`` cells per
axis over the scene's cube, trilinear in between, so smooth by construction), started at zero and held
near it by a quadratic penalty. View i can explain its own shape error through ``d_i`` while the mesh,
the novel views and the frozen conditioning view use the shared geometry as it is.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Tuple, Type

import torch
from torch import nn

from va_plugin.config import InstantiateConfig
from va_plugin.errors import ConfigError

MAX_DISPLACEMENT = 0.1
"""Largest displacement (scene units; the object fits the unit sphere): a diverging run cannot tear
space apart."""


@dataclass
class ViewDeformationConfig(InstantiateConfig):
    """Per-view deformation grids (off by default)."""

    _target: Type = field(default_factory=lambda: ViewDeformation)
    frozen_views: Tuple[int, ...] = (0,)
    """Views rendered without deformation (the generator's conditioning view)."""
    enabled: bool = False
    """Give every training view (except ``frozen_views``) its own deformation of space."""
    resolution: int = 6
    """Grid vertices per axis of each view's displacement grid (at least 2)."""
    bound: float = 1.0
    """The grid covers [-bound, bound]^3; points outside take the border's displacement."""
    penalty_weight: float = 1.0
    """Weight of the mean squared displacement (scene units) in the loss."""


class ViewDeformation(nn.Module):
    """Displacement grids ``[V, R, R, R, 3]``, zero at the start."""

    def __init__(self, config: ViewDeformationConfig, num_views: int) -> None:
        super().__init__()
        if config.resolution < 2:
            raise ConfigError(f"view_deformation.resolution must be at least 2, got {config.resolution}")
        if config.bound <= 0 or config.penalty_weight < 0:
            raise ConfigError("view_deformation.bound must be positive and penalty_weight >= 0, got "
                              f"{config.bound} and {config.penalty_weight}")
        self.config = config
        self.num_views = num_views
        r = config.resolution
        self.grid = nn.Parameter(torch.zeros(max(num_views, 1), r, r, r, 3))
        trained = torch.ones(max(num_views, 1))
        for view in config.frozen_views:
            if 0 <= view < num_views:
                trained[view] = 0.0
        self.register_buffer("trained", trained, persistent=False)

    def displacement(self, points: torch.Tensor, camera_indices: torch.Tensor) -> torch.Tensor:
        """``d_i(x)`` ``[n, 3]`` at ``points [n, 3]`` of views ``camera_indices [n]`` (0 for index -1)."""
        r = self.config.resolution
        known = (camera_indices >= 0) & (camera_indices < self.num_views)
        view = torch.where(known, camera_indices, torch.zeros_like(camera_indices))
        scale = (self.trained[view] * known.to(points.dtype))[:, None]
        u = ((points / self.config.bound + 1.0) * 0.5 * (r - 1)).clamp(0.0, r - 1.0)
        base = u.floor().long().clamp(max=r - 2)
        frac = u - base
        out = points.new_zeros(points.shape)
        for dx in (0, 1):
            wx = frac[:, 0] if dx else 1.0 - frac[:, 0]
            for dy in (0, 1):
                wy = frac[:, 1] if dy else 1.0 - frac[:, 1]
                for dz in (0, 1):
                    wz = frac[:, 2] if dz else 1.0 - frac[:, 2]
                    corner = self.grid[view, base[:, 0] + dx, base[:, 1] + dy, base[:, 2] + dz]
                    out = out + (wx * wy * wz)[:, None] * corner
        return (out * scale).clamp(-MAX_DISPLACEMENT, MAX_DISPLACEMENT)

    def apply(self, points: torch.Tensor, camera_indices: torch.Tensor) -> torch.Tensor:
        """``points [..., 3]`` moved by their view's displacement; ``camera_indices`` broadcasts to
        ``points.shape[:-1]``."""
        flat = points.reshape(-1, 3)
        index = camera_indices.expand(points.shape[:-1]).reshape(-1)
        return (flat + self.displacement(flat, index)).reshape(points.shape)

    def loss(self) -> torch.Tensor:
        """``penalty_weight`` times the mean squared displacement of the trained views' grid vertices."""
        per_view = (self.grid * self.grid).mean(dim=(1, 2, 3, 4))
        return self.config.penalty_weight * (per_view * self.trained).sum() / self.trained.sum().clamp_min(1.0)

    @torch.no_grad()
    def largest(self) -> float:
        """Largest displacement length at a grid vertex, any view (scene units)."""
        return float((self.grid * self.trained[:, None, None, None, None]).norm(dim=-1).max())
