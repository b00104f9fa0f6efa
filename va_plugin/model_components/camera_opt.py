"""Per-view camera refinement: a small learned rigid correction of each training camera.

Generated views are seen from slightly wrong orbit positions (the generator's azimuth, elevation and
roll drift by a degree or so). With the nominal cameras every such view pulls the shared surface
towards its own shifted copy; a correction per view lets it line up instead.

The correction of view i is a world-frame rigid motion ``x -> R_i x + t_i`` applied to that view's
rays (origin and direction), with ``R_i = exp([w_i]_x)``. For an object-centred rig a rotation about
the world origin is exactly an orbit error, and the translation takes what is left. The conditioning
view (view 0 by default) stays fixed: it pins the frame, which would otherwise be free to turn as a
whole. A quadratic penalty keeps the corrections small; rays of novel views (camera index -1) are
never changed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Tuple, Type

import torch
from torch import nn

from va_plugin.config import InstantiateConfig
from va_plugin.errors import ConfigError
from va_plugin.model_components.per_view import PerViewCorrection
from va_plugin.rays import RayBundle

CAMERA_OPT_MODES = ("off", "SO3", "SE3")
MAX_ROTATION_RAD = 0.35
"""Largest correction angle (20 degrees): the rotation vector is clamped to it, so that a diverging
run cannot spin a camera around (real generator drift is a degree or two)."""
MAX_TRANSLATION = 0.5
"""Largest correction translation, scene units (the object fits a sphere of radius 1)."""


@dataclass
class CameraOptimizerConfig(InstantiateConfig):
    """Per-view camera refinement (off by default)."""

    _target: Type = field(default_factory=lambda: CameraOptimizer)
    mode: str = "off"
    """"off", "SO3" (a rotation about the world origin per view: the orbit errors of a generator's
    rig) or "SE3" (rotation and translation)."""
    frozen_views: Tuple[int, ...] = (0,)
    """Training views whose camera stays as given (the generator's conditioning view)."""
    penalty_weight: float = 1e-2
    """Weight of the mean squared correction (radians and scene units) in the loss."""
    train_until: float = 1.0
    """Share of the step budget after which the corrections stay as they are (1: trained to the end).
    While the hash grid's fine levels are still closed the field cannot bend its texture around a turned
    camera, so the photometric loss pins the pose; once they open, field and camera can drift together."""


class CameraOptimizer(PerViewCorrection):
    """The learned corrections ``[num_views, 6]`` (rotation vector, translation), zero at the start."""

    def __init__(self, config: CameraOptimizerConfig, num_views: int) -> None:
        if config.mode not in CAMERA_OPT_MODES:
            raise ConfigError(f"camera_opt.mode must be one of {', '.join(CAMERA_OPT_MODES)}, got {config.mode!r}")
        if config.penalty_weight < 0:
            raise ConfigError(f"camera_opt.penalty_weight must be >= 0, got {config.penalty_weight}")
        if not 0.0 <= config.train_until <= 1.0:
            raise ConfigError(f"camera_opt.train_until must be in [0, 1], got {config.train_until}")
        super().__init__(num_views, 6, config.frozen_views, config.penalty_weight)
        self.config = config
        self.enabled = config.mode != "off" and num_views > 0
        self.frozen = False
        """Set by the model once ``train_until`` of the budget has passed: the corrections are then applied
        without gradient and their penalty is 0, so the optimizer leaves them as they are."""
        if config.mode == "SO3":
            self.trained[:, 3:] = 0.0

    def set_step(self, step: int, max_steps: int) -> None:
        """Freeze the corrections from step ``train_until * max_steps`` on."""
        self.frozen = step >= self.config.train_until * max_steps

    def loss(self) -> torch.Tensor:
        return self.correction.new_zeros(()) if self.frozen else super().loss()

    def corrections(self) -> Tuple[torch.Tensor, torch.Tensor]:
        """Rotations ``[V, 3, 3]`` and translations ``[V, 3]`` of every training view."""
        rotvec, translation = self._vectors()
        return rotation_matrix(rotvec), translation

    def _vectors(self) -> Tuple[torch.Tensor, torch.Tensor]:
        """Rotation vectors and translations ``[V, 3]`` as applied (frozen entries zero, sizes clamped)."""
        correction = self.correction.detach() if self.frozen else self.correction
        delta = correction * self.trained
        return _clamp_norm(delta[:, :3], MAX_ROTATION_RAD), _clamp_norm(delta[:, 3:], MAX_TRANSLATION)

    def apply(self, rays: RayBundle) -> RayBundle:
        """The rays with their view's correction (unchanged when off or for camera index -1)."""
        if not self.enabled:
            return rays
        rotations, translations = self.corrections()
        known, safe = self.view_index(rays.camera_indices)
        rotation = rotations[safe]  # [n, 3, 3]
        origins = torch.einsum("nij,nj->ni", rotation, rays.origins) + translations[safe]
        directions = torch.einsum("nij,nj->ni", rotation, rays.directions)
        keep = known[:, None]
        return RayBundle(torch.where(keep, origins, rays.origins), torch.where(keep, directions, rays.directions),
                         rays.camera_indices, rays.nears, rays.fars)

    @torch.no_grad()
    def summary(self) -> Dict[str, object]:
        """Per view the correction's angle (degrees), rotation vector (world frame, radians), translation
        and its length, and the largest angle and length."""
        rotvec, translations = self._vectors()  # the angle is the rotation vector's length
        degrees = torch.rad2deg(rotvec.norm(dim=-1))[: self.num_views].tolist()
        shifts = translations.norm(dim=-1)[: self.num_views].tolist()
        return {"mode": self.config.mode, "rotation_deg": [round(d, 4) for d in degrees],
                "rotation_vector": [[round(v, 6) for v in row] for row in rotvec[: self.num_views].tolist()],
                "translation": [round(s, 5) for s in shifts],
                "translation_vector": [[round(v, 6) for v in row] for row in translations[: self.num_views].tolist()],
                "max_rotation_deg": round(max(degrees, default=0.0), 6),
                "max_translation": round(max(shifts, default=0.0), 5)}


def rotation_matrix(rotvec: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula for rotation vectors ``[..., 3]`` -> ``[..., 3, 3]``, with sin(a)/a and
    (1 - cos a)/a^2 taken from their Taylor series below 1e-3 rad, so the value and the gradient are
    finite at zero (where a plain formula divides 0 by 0)."""
    angle_sq = (rotvec * rotvec).sum(-1, keepdim=True)
    angle = torch.sqrt(angle_sq.clamp_min(1e-12))
    small = angle_sq < 1e-6
    safe_angle = torch.where(small, torch.ones_like(angle), angle)
    sin_over = torch.where(small, 1.0 - angle_sq / 6.0, torch.sin(safe_angle) / safe_angle)
    cos_term = torch.where(small, 0.5 - angle_sq / 24.0, (1.0 - torch.cos(safe_angle)) / (safe_angle * safe_angle))
    x, y, z = rotvec.unbind(-1)
    zero = torch.zeros_like(x)
    skew = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*rotvec.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device).expand_as(skew)
    return eye + sin_over[..., None] * skew + cos_term[..., None] * (skew @ skew)


def _clamp_norm(vectors: torch.Tensor, bound: float) -> torch.Tensor:
    norm = torch.sqrt((vectors * vectors).sum(-1, keepdim=True) + 1e-20)
    return vectors * (bound / norm.clamp_min(bound))
