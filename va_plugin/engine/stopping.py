"""Ending a run once its surface has settled: the stopping rule.

Every ``check_every`` steps from ``start`` of the schedule on, the model's mesh field is sampled on a coarse
grid over the scene's sphere and each point's side of the surface (inside: negative) is compared with the
previous check. The change is the share of the inside points that crossed the surface since then; the run
ends after ``patience`` checks in a row with a change below ``tolerance``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Optional

import torch

from va_plugin.errors import ConfigError

CHUNK = 65536
"""Grid points per mesh-field call."""


@dataclass
class StopConfig:
    """The stopping rule: end the run when the surface stops changing between checks."""

    enabled: bool = False
    """End the run early when the surface has settled."""
    record_only: bool = False
    """Check and log as when enabled, keep a checkpoint at each check under ``settling/``, but train on to
    ``max_steps`` (to measure what the rule would save and cost)."""
    start: float = 0.5
    """Share of the schedule before the first check."""
    check_every: int = 100
    """Steps between checks."""
    grid: int = 48
    """Points per axis of the checked grid (over the scene's bounding cube, inside its sphere)."""
    tolerance: float = 0.01
    """Largest share of the inside points that may cross the surface between two checks of a settled run."""
    patience: int = 2
    """Settled checks in a row that end the run."""

    def validate(self) -> None:
        if not 0.0 <= self.start <= 1.0 or self.check_every < 1 or not 8 <= self.grid <= 256 or \
                not 0.0 <= self.tolerance <= 1.0 or self.patience < 1:
            raise ConfigError(f"stop: start must be in [0, 1], check_every >= 1, grid in [8, 256], tolerance in "
                              f"[0, 1] and patience >= 1; got {self.start}, {self.check_every}, {self.grid}, "
                              f"{self.tolerance} and {self.patience}")

    @property
    def active(self) -> bool:
        return self.enabled or self.record_only


class SurfaceSettling:
    """The rule's state: the last check's inside points and the settled checks in a row."""

    def __init__(self, config: StopConfig, horizon: int) -> None:
        config.validate()
        self.config = config
        self.first = max(config.check_every, int(round(config.start * horizon)))
        self.previous: Optional[torch.Tensor] = None
        self.settled = 0

    def due(self, step: int) -> bool:
        """Whether a check follows ``step`` (the steps done)."""
        return self.config.active and step >= self.first and (step - self.first) % self.config.check_every == 0

    @torch.no_grad()
    def inside(self, model) -> torch.Tensor:
        """Which grid points lie inside the surface, ``[grid^3]`` bool (points outside the sphere: False)."""
        radius = float(model.scene.scene_radius)
        device = next(model.parameters()).device
        axis = torch.linspace(-radius, radius, self.config.grid, device=device)
        points = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), dim=-1).reshape(-1, 3)
        in_sphere = points.norm(dim=-1) < radius
        values = torch.cat([model.mesh_field(points[i:i + CHUNK]) for i in range(0, points.shape[0], CHUNK)])
        return (values < 0) & in_sphere

    def check(self, model) -> Dict[str, float]:
        """Compare the surface with the last check's: ``{"change", "settled"}`` (change is NaN at the first)."""
        now = self.inside(model)
        change = float("nan")
        if self.previous is not None:
            crossed = int((now ^ self.previous).sum())
            change = crossed / max(int(now.sum()), 1)
            self.settled = self.settled + 1 if change < self.config.tolerance else 0
        self.previous = now
        return {"change": change, "settled": self.settled}

    @property
    def stop(self) -> bool:
        return self.settled >= self.config.patience
