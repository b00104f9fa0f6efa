"""Per-view blur: a learned point-spread function for each training view.

A generator's views are softer than the object (SyncDreamer's at 256 px are blurred by a pixel or two),
and not equally: the conditioning view is the user's sharp photograph. A shared field fitted to the
soft views comes out soft, and a per-sample correction (the view-adaptive branches, a per-view colour
matrix) cannot undo a blur: a blur mixes neighbouring pixels. Here a training pixel of view i is
compared with a blurred render instead: its own ray with weight ``1 - w_i`` and four rays at ``radius``
pixels around it (a cross turned by a random angle per pixel) with ``w_i / 4`` each, so that view i's
render is the sharp field seen through a point-spread function of variance ``w_i radius^2 / 2`` per
axis. ``w_i = sigmoid(logit_i)`` is learned from the photometric loss (a linear mix, so its gradient
needs no derivative of the render with respect to the ray). The mask loss and every per-ray output
other than the colours keep the pixel's own ray; novel views and the mesh never see the blur.

It costs rays: a pixel takes five, so a batch of ``rays_per_batch`` rays supervises a fifth as many
pixels once the blur is on (from ``start`` of the budget; before, every ray is a pixel).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, Tuple, Type

import torch

from va_plugin.config import InstantiateConfig
from va_plugin.errors import ConfigError
from va_plugin.model_components.per_view import PerViewCorrection
from va_plugin.rays import RayBundle

RING = 4
"""Rays around each pixel's own (a cross)."""
PER_RAY_KEYS = ("accumulation", "depth", "normal", "colour_weight")
"""Per-ray outputs that keep the pixel's own ray (the colour is mixed); per-sample outputs stay whole."""


@dataclass
class ViewBlurConfig(InstantiateConfig):
    """Per-view learned blur of the training views' renders (off by default)."""

    _target: Type = field(default_factory=lambda: ViewBlur)
    enabled: bool = False
    """Give every training view a learned point-spread function."""
    radius: float = 2.5
    """Pixels from a pixel's centre to its four neighbouring rays; the largest blur it can represent is a
    Gaussian of ``radius / sqrt(2)`` pixels per axis (all weight on the ring)."""
    init_weight: float = 0.1
    """Every view's ring weight at the start (in (0, 1))."""
    start: float = 0.3
    """Share of the step budget before which every ray is a pixel of its own (no blur): the field first
    needs a shape, and until the fine levels open it is soft anyway."""
    penalty_weight: float = 0.0
    """Weight of the mean squared change of the ring weight's logit from its start, in the loss."""
    frozen_views: Tuple[int, ...] = ()
    """Views whose weight stays at ``init_weight``."""


class ViewBlur(PerViewCorrection):
    """Ring-weight logits ``[V, 1]`` (``correction`` is the change from the start)."""

    def __init__(self, config: ViewBlurConfig, num_views: int) -> None:
        if not (math.isfinite(config.radius) and 0.0 < config.radius <= 16.0):
            raise ConfigError(f"view_blur.radius must be in (0, 16] pixels, got {config.radius}")
        if not 0.0 < config.init_weight < 1.0:
            raise ConfigError(f"view_blur.init_weight must be in (0, 1), got {config.init_weight}")
        if not 0.0 <= config.start < 1.0:
            raise ConfigError(f"view_blur.start must be in [0, 1), got {config.start}")
        if config.penalty_weight < 0:
            raise ConfigError(f"view_blur.penalty_weight must be >= 0, got {config.penalty_weight}")
        super().__init__(num_views, 1, config.frozen_views, config.penalty_weight)
        self.config = config
        self.init_logit = math.log(config.init_weight / (1.0 - config.init_weight))
        self.active = config.start == 0.0
        """Whether training batches are blurred (from ``start`` of the budget on); set by ``set_step``."""

    def set_step(self, step: int, max_steps: int) -> None:
        self.active = step >= self.config.start * max_steps

    def weights(self) -> torch.Tensor:
        """Each view's ring weight ``[V]``."""
        return torch.sigmoid(self.init_logit + (self.correction * self.trained)[:, 0])

    def sub_pixels(self, rows: torch.Tensor, cols: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor]:
        """Rows and columns ``[(1 + RING) * n]`` of the rays that render pixels ``(rows, cols) [n]``: the
        pixels themselves first, then ring ray k of every pixel, k = 0..3 (a cross at a random angle)."""
        angle = torch.rand(rows.shape, device=rows.device) * (0.5 * math.pi)
        turns = angle[None, :] + torch.arange(RING, device=rows.device, dtype=angle.dtype)[:, None] * (0.5 * math.pi)
        ring_rows = rows.to(angle.dtype)[None, :] + self.config.radius * torch.sin(turns)
        ring_cols = cols.to(angle.dtype)[None, :] + self.config.radius * torch.cos(turns)
        return (torch.cat([rows.to(angle.dtype), ring_rows.reshape(-1)]),
                torch.cat([cols.to(angle.dtype), ring_cols.reshape(-1)]))

    def combine(self, outputs: Dict[str, torch.Tensor], views: torch.Tensor) -> Dict[str, torch.Tensor]:
        """Per-pixel outputs from the outputs of the rays of :meth:`sub_pixels` (``views [n]``, each pixel's
        view): the colour mixed by the view's weight, the other per-ray outputs the pixel's own ray's."""
        n = views.shape[0]
        out = dict(outputs)
        w = self.weights()[views][:, None]
        for key, rgb in outputs.items():  # the colour and the field's other colours (rgb_shared, ...)
            if key == "rgb" or key.startswith("rgb_"):
                ring = rgb[n:].reshape(RING, n, -1).mean(0)
                out[key] = (1.0 - w) * rgb[:n] + w * ring
        for key in PER_RAY_KEYS:
            if key in outputs:
                out[key] = outputs[key][:n]
        return out

    @torch.no_grad()
    def sigma_px(self) -> torch.Tensor:
        """Each view's blur as the standard deviation (pixels, per axis) of its point-spread function."""
        return self.config.radius * torch.sqrt(0.5 * self.weights())

    @torch.no_grad()
    def summary(self) -> Dict[str, object]:
        sigma = self.sigma_px()[: self.num_views].tolist()
        weights = self.weights()[: self.num_views].tolist()
        return {"radius_px": self.config.radius, "ring_weight": [round(w, 4) for w in weights],
                "sigma_px": [round(s, 4) for s in sigma], "largest_sigma_px": round(max(sigma, default=0.0), 4)}


def blurred_batch(blur: ViewBlur, cameras, ray_bundle: RayBundle, batch: Dict[str, torch.Tensor]
                  ) -> Tuple[RayBundle, Dict[str, torch.Tensor], torch.Tensor]:
    """The rays that render every ``(1 + RING)``-th pixel of ``batch`` through their views' point-spread
    functions, that share of ``batch``, and the pixels' views. A stride, not the first pixels: a batch is
    laid out by kind (foreground pixels first, then uniform ones), and the share keeps its mix."""
    pick = torch.arange(0, len(ray_bundle), 1 + RING, device=batch["pixel"].device)
    batch = {key: value[pick] for key, value in batch.items()}
    views, rows, cols = batch["pixel"].unbind(-1)
    sub_rows, sub_cols = blur.sub_pixels(rows, cols)
    all_views = views.repeat(1 + RING)
    origins, directions = cameras.generate_rays(all_views, sub_rows, sub_cols)
    return RayBundle(origins, directions, all_views), batch, views
