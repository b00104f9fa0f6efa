"""Volume rendering: alphas to weights, weights to colors."""

from __future__ import annotations

import torch

TRANSMITTANCE_EPS = 1e-7


def weights_from_alpha(alpha: torch.Tensor) -> torch.Tensor:
    """Rendering weights ``w_i = alpha_i * prod_{j<i} (1 - alpha_j)``, ``[n_rays, n_samples]`` from alpha
    of that shape; rows sum to at most 1. Each factor ``1 - alpha`` is floored at ``1e-7`` (not offset,
    which would bias long rays' sums above 1) to keep gradients finite at alpha 1."""
    ones = torch.ones_like(alpha[:, :1])
    transmittance = torch.cumprod(torch.cat([ones, (1.0 - alpha).clamp_min(TRANSMITTANCE_EPS)], dim=-1), dim=-1)
    return alpha * transmittance[:, :-1]


def alpha_from_density(density: torch.Tensor, deltas: torch.Tensor) -> torch.Tensor:
    """``alpha = 1 - exp(-sigma * delta)`` ``[n_rays, n_samples]`` from ``density`` and ``deltas`` (section
    lengths), both ``[n_rays, n_samples]``, with the exponent clamped so it never overflows."""
    return 1.0 - torch.exp(-(density * deltas).clamp(0.0, 80.0))


def render_rgb(weights: torch.Tensor, rgb: torch.Tensor, background: torch.Tensor) -> torch.Tensor:
    """``sum_i w_i c_i + (1 - sum_i w_i) * background``; weights ``[n, s]``, rgb ``[n, s, 3]``."""
    accumulation = weights.sum(-1, keepdim=True)
    return (weights[..., None] * rgb).sum(-2) + (1.0 - accumulation).clamp_min(0.0) * background


def render_depth(weights: torch.Tensor, t_mid: torch.Tensor) -> torch.Tensor:
    """Expected depth ``[n, 1]`` normalised by the accumulated weight (0 where nothing was hit)."""
    accumulation = weights.sum(-1, keepdim=True)
    return (weights * t_mid).sum(-1, keepdim=True) / accumulation.clamp_min(1e-6)
