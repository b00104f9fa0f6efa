"""Per-view image warp: a learned, smooth 2-D displacement of where each training view's targets are read.

A generated view draws the object a little out of place: parts sit a pixel or a few off where a
consistent object would put them (SyncDreamer's views disagree by such low-frequency warps and by small
orbit errors, which in a view look much the same). With one shared geometry every such view pulls the
surface its own way and the result is a blurred compromise. Here the ray through pixel ``p`` of view i
is compared with the input at ``p + s_i(p)`` instead of ``p``: ``s_i`` is a coarse grid of 2-D shifts over
the image (``grid`` control points per side, bilinear in between, so smooth by construction), zero at the
start and held near zero by a quadratic penalty. The shift is learned from the photometric and mask
losses through the input image's bilinear interpolation (the classic image-registration step), so it
costs one gather per ray and nothing in the field.

The geometry, the mesh and novel views are untouched by it; the conditioning view (view 0 by default)
stays unwarped and pins the frame, and the shift starts only after ``start`` of the budget, once the
shared field has a shape to register the views against.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Dict, Tuple, Type

import torch

from va_plugin.config import InstantiateConfig
from va_plugin.errors import ConfigError
from va_plugin.model_components.per_view import PerViewCorrection

MAX_SHIFT = 0.05
"""Largest shift, as a fraction of the image's larger side (13 px at 256 px): real generator warps are a
few pixels, and a diverging run cannot slide a view off the object."""


@dataclass
class ViewWarpConfig(InstantiateConfig):
    """Per-view smooth image warps of the training targets (off by default)."""

    _target: Type = field(default_factory=lambda: ViewWarp)
    enabled: bool = False
    """Give every training view (except ``frozen_views``) its own learned warp."""
    grid: int = 5
    """Control points per image side of each view's shift grid (at least 2; 2 is an affine-like warp)."""
    frozen_views: Tuple[int, ...] = (0,)
    """Views read where their pixels are (the generator's conditioning view)."""
    penalty_weight: float = 300.0
    """Weight of the mean squared shift (in fractions of the image side) in the loss. At 1 and 30 the
    warps took what the geometry should explain (CD +30% / +8% on GSO alarm at level 3); at 300 they stay
    within about a pixel and tie plain `neus` on GSO-10 (benchmarks/RESULTS.md, "Per-view image warps")."""
    start: float = 0.1
    """Share of the step budget before which the targets are read unwarped (the field first needs a shape)."""
    gradient_blur: float = 0.0
    """Standard deviation (pixels) of a Gaussian blur of the inputs from which the shift's slope is read,
    while the values stay the sharp inputs' (0: the sharp inputs' own slope). A bilinear reading's slope
    sees only the pixel cell around it, so the registration cannot see an error of a few pixels; the slope
    of a blurred copy reaches about as far as its blur, the classic coarse registration step."""


class ViewWarp(PerViewCorrection):
    """Shift grids ``[V, 2 * grid * grid]`` (x then y, row-major), fractions of the image side, zero at the
    start."""

    def __init__(self, config: ViewWarpConfig, num_views: int) -> None:
        if config.grid < 2:
            raise ConfigError(f"view_warp.grid must be at least 2, got {config.grid}")
        if config.penalty_weight < 0:
            raise ConfigError(f"view_warp.penalty_weight must be >= 0, got {config.penalty_weight}")
        if not 0.0 <= config.start < 1.0:
            raise ConfigError(f"view_warp.start must be in [0, 1), got {config.start}")
        if not 0.0 <= config.gradient_blur <= 32.0:
            raise ConfigError(f"view_warp.gradient_blur must be in [0, 32] pixels, got {config.gradient_blur}")
        super().__init__(num_views, 2 * config.grid * config.grid, config.frozen_views, config.penalty_weight)
        self.config = config
        self.active = config.start == 0.0
        """Whether the warp is applied (from ``start`` of the budget on); set by ``set_step``."""
        self.image_side = 0
        """The larger side of the images warped last (pixels), for the summary."""

    def set_step(self, step: int, max_steps: int) -> None:
        self.active = step >= self.config.start * max_steps

    def _grids(self) -> torch.Tensor:
        """Shift grids ``[V, G, G, 2]`` as applied (frozen views zero, each component clamped)."""
        g = self.config.grid
        delta = (self.correction * self.trained).clamp(-MAX_SHIFT, MAX_SHIFT)
        return delta.reshape(-1, 2, g, g).permute(0, 2, 3, 1)

    def shifts(self, views: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor, height: int, width: int
               ) -> torch.Tensor:
        """Shifts ``[n, 2]`` (columns, rows; pixels) of pixels ``(rows, cols)`` of training views ``views``
        (zero for views outside the training set), bilinear between the grid's control points, which span
        the image from the first pixel's centre to the last's."""
        g = self.config.grid
        self.image_side = max(height, width)
        known = (views >= 0) & (views < self.num_views)
        safe = torch.where(known, views, torch.zeros_like(views))
        gx = cols.to(torch.float32) * ((g - 1) / max(width - 1, 1))
        gy = rows.to(torch.float32) * ((g - 1) / max(height - 1, 1))
        shift = sample_bilinear(self._grids(), safe, gy, gx)  # the grid is a G x G image of 2-D shifts
        return shift * known[:, None].to(shift.dtype) * float(max(height, width))

    @torch.no_grad()
    def largest(self) -> float:
        """The largest shift of any control point, pixels of the last images warped (fractions before any)."""
        return float(self._grids().abs().max()) * max(self.image_side, 1)

    @torch.no_grad()
    def summary(self) -> Dict[str, object]:
        """Per view the RMS and the largest shift of the control points, in pixels of the training images."""
        side = max(self.image_side, 1)
        grids = self._grids()[: self.num_views] * side
        lengths = grids.norm(dim=-1).reshape(grids.shape[0], -1)
        rms = lengths.pow(2).mean(-1).sqrt().tolist()
        largest = lengths.max(-1).values.tolist()
        return {"grid": self.config.grid, "image_side_px": self.image_side,
                "rms_shift_px": [round(r, 4) for r in rms], "max_shift_px": [round(m, 4) for m in largest],
                "largest_px": round(max(largest, default=0.0), 4)}


def gaussian_blurred(images: torch.Tensor, sigma: float) -> torch.Tensor:
    """``images [V, H, W, C]`` blurred by a separable Gaussian of ``sigma`` pixels (kernel radius 3 sigma,
    the border replicated), as the same dtype and device."""
    from va_plugin.eval.image import gaussian_kernel_1d  # SSIM's taps; made once per sigma, off the hot path

    radius = max(1, int(math.ceil(3.0 * sigma)))
    kernel = gaussian_kernel_1d(2 * radius + 1, sigma).to(device=images.device, dtype=images.dtype)
    channels = images.shape[-1]
    x = images.permute(0, 3, 1, 2)  # V, C, H, W
    x = torch.nn.functional.pad(x, (radius, radius, radius, radius), mode="replicate")
    x = torch.nn.functional.conv2d(x, kernel.view(1, 1, 1, -1).expand(channels, 1, 1, -1), groups=channels)
    x = torch.nn.functional.conv2d(x, kernel.view(1, 1, -1, 1).expand(channels, 1, -1, 1), groups=channels)
    return x.permute(0, 2, 3, 1).contiguous()


def sample_bilinear_blur_slope(images: torch.Tensor, blurred: torch.Tensor, views: torch.Tensor,
                               rows: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
    """The values of ``images`` at ``(rows, cols)`` (as :func:`sample_bilinear`) with the slope in the
    positions of ``blurred`` (straight through: ``sharp + blurred - blurred.detach()``)."""
    soft = sample_bilinear(blurred, views, rows, cols)
    return sample_bilinear(images, views, rows.detach(), cols.detach()) + soft - soft.detach()


def sample_bilinear(images: torch.Tensor, views: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor
                    ) -> torch.Tensor:
    """Values ``[n, C]`` of ``images [V, H, W, C]`` at fractional pixel positions ``(rows, cols)`` (pixel
    centres at whole numbers) of ``views``, bilinear, clamped to the border; differentiable in the
    positions (the slope inside each pixel cell) and in the images."""
    height, width = images.shape[1:3]
    rows = rows.clamp(0.0, height - 1.0)
    cols = cols.clamp(0.0, width - 1.0)
    r0 = rows.detach().floor().long().clamp(0, max(height - 2, 0))
    c0 = cols.detach().floor().long().clamp(0, max(width - 2, 0))
    r1 = (r0 + 1).clamp(max=height - 1)
    c1 = (c0 + 1).clamp(max=width - 1)
    fr, fc = (rows - r0)[:, None], (cols - c0)[:, None]
    return ((1 - fr) * (1 - fc) * images[views, r0, c0] + (1 - fr) * fc * images[views, r0, c1]
            + fr * (1 - fc) * images[views, r1, c0] + fr * fc * images[views, r1, c1])
