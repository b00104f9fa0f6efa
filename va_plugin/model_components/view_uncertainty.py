"""Per-view uncertainty of the colour loss: views (or parts of views) that the shared field explains
worse count less.

A learned per-view uncertainty sigma_k with the loss ``e / (2 sigma_k^2) + log sigma_k`` (the
homoscedastic weighting of Kendall et al.; NeRF-W's transient uncertainty is its per-pixel relative) has
its optimum at ``sigma_k^2 = mean error of view k``. This module uses that optimum directly instead of
learning sigma: it keeps a running mean of each training view's colour error (optionally per cell of a
``grid x grid`` split of the image), and weights a ray by ``(reference / its cell's running error) **
power``, with the reference the mean over cells. Weights are clamped to [1 / MAX_RATIO, MAX_RATIO],
held constant (no gradient), and normalised to mean 1 over the weighted rays, so the colour loss keeps
its scale against the other losses. Only foreground rays (mask > 0.5) are weighted and counted when the
batch has masks: background pixels are explained near perfectly and would otherwise get the largest
weights.
"""

from __future__ import annotations

from typing import List, Optional

import torch
from torch import nn

MOMENTUM = 0.98
"""Running-mean momentum per step in which a cell has rays (about 50 steps of memory)."""
MAX_RATIO = 4.0
"""Largest weight, and 1 / the smallest, before the normalisation."""
ERROR_FLOOR = 1e-6
"""Smallest running error a weight divides by."""


class ViewUncertainty(nn.Module):
    """Running per-view (per-cell) colour errors and the ray weights they give."""

    def __init__(self, num_views: int, grid: int, power: float, width: int, height: int) -> None:
        super().__init__()
        self.grid, self.power, self.width, self.height = int(grid), float(power), int(width), int(height)
        self.register_buffer("error", torch.zeros(num_views, self.grid, self.grid))
        self.register_buffer("seen", torch.zeros(num_views, self.grid, self.grid))

    def cells(self, pixel: torch.Tensor) -> torch.Tensor:
        """Flat cell index ``[n]`` of rays with ``pixel [n, 3]`` (view, row, column)."""
        views, rows, cols = pixel.long().unbind(-1)
        r = (rows * self.grid // max(self.height, 1)).clamp(0, self.grid - 1)
        c = (cols * self.grid // max(self.width, 1)).clamp(0, self.grid - 1)
        return (views * self.grid + r) * self.grid + c

    @torch.no_grad()
    def update(self, pixel: torch.Tensor, error: torch.Tensor, keep: Optional[torch.Tensor] = None) -> None:
        """Fold the batch's per-ray errors ``[n]`` (of the rays where ``keep``) into the running means."""
        idx, error = self.cells(pixel), error.detach().to(self.error.dtype)
        if keep is not None:
            idx, error = idx[keep], error[keep]
        flat, seen = self.error.view(-1), self.seen.view(-1)
        total = torch.zeros_like(flat).index_add_(0, idx, error)
        count = torch.zeros_like(flat).index_add_(0, idx, torch.ones_like(error))
        has = count > 0
        mean = total / count.clamp_min(1.0)
        blended = torch.where(seen > 0, MOMENTUM * flat + (1.0 - MOMENTUM) * mean, mean)
        flat.copy_(torch.where(has, blended, flat))
        seen.copy_(torch.where(has, torch.ones_like(seen), seen))

    @torch.no_grad()
    def cell_weights(self) -> torch.Tensor:
        """Weight of each cell ``[views, grid, grid]`` before the batch normalisation (1 where unseen)."""
        seen = self.seen > 0
        if not seen.any():
            return torch.ones_like(self.error)
        reference = self.error[seen].mean().clamp_min(ERROR_FLOOR)
        ratio = reference / self.error.clamp_min(ERROR_FLOOR)
        weights = ratio.pow(self.power).clamp(1.0 / MAX_RATIO, MAX_RATIO)
        return torch.where(seen, weights, torch.ones_like(weights))

    def weights(self, pixel: torch.Tensor, keep: Optional[torch.Tensor] = None) -> torch.Tensor:
        """Constant per-ray weights ``[n]``: the cells' weights, 1 where not ``keep``, mean 1 over ``keep``."""
        w = self.cell_weights().view(-1)[self.cells(pixel)]
        if keep is None:
            return w / w.mean().clamp_min(1e-6)
        w = torch.where(keep, w, torch.ones_like(w))
        if keep.any():
            w = torch.where(keep, w / w[keep].mean().clamp_min(1e-6), w)
        return w

    def view_weights(self) -> List[float]:
        """Each view's mean cell weight (a diagnostic)."""
        return [round(float(v), 4) for v in self.cell_weights().mean((1, 2))]
