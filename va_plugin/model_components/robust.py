"""Robust photometric and mask losses: drop the batch's worst-explained rays.

A generated view can be wrong in patches (a hallucinated blob, a misplaced handle). Those pixels are
the ones the shared field explains worst, so a loss that averages over all but the largest
``fraction`` of per-ray errors stops them from pulling the shared surface and colour towards the
error (the reconstruction stages of Wonder3D and Era3D use such outlier-dropping losses). Which rays
are dropped is decided on detached errors; the kept rays' gradients are those of a plain mean over
them.
"""

from __future__ import annotations

import torch


def trimmed_mean(per_ray: torch.Tensor, fraction: float) -> torch.Tensor:
    """Mean of ``per_ray [n]`` without its ``floor(fraction * n)`` largest entries (at least one kept)."""
    n = per_ray.shape[0]
    drop = min(int(fraction * n), max(n - 1, 0))
    if fraction <= 0 or drop == 0:
        return per_ray.mean()
    keep = torch.topk(per_ray.detach(), n - drop, largest=False).indices
    return per_ray[keep].mean()


def per_ray_rgb_error(pred: torch.Tensor, target: torch.Tensor, kind: str = "l2") -> torch.Tensor:
    """Per-ray photometric error ``[n]``: the mean over channels of the squared (l2) or absolute (l1)
    difference, so that its mean over rays is the plain loss of ``losses.rgb_loss``."""
    diff = pred - target
    return (diff * diff).mean(-1) if kind == "l2" else diff.abs().mean(-1)


def per_ray_mask_error(accumulation: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Per-ray binary cross-entropy ``[n]`` of the opacity ``[n, 1]`` against the mask ``[n, 1]``, with
    the opacity clamped to [1e-3, 1 - 1e-3] (as ``losses.mask_loss``)."""
    acc = accumulation.clamp(1e-3, 1.0 - 1e-3)
    return -(mask * torch.log(acc) + (1.0 - mask) * torch.log(1.0 - acc))[..., 0]
