"""Loss terms shared by the models."""

from __future__ import annotations

import torch


def rgb_loss(pred: torch.Tensor, target: torch.Tensor, kind: str = "l2") -> torch.Tensor:
    """Photometric loss: mean squared error (``l2``, the paper's eq. 13) or mean absolute error (``l1``)."""
    diff = pred - target
    return (diff * diff).mean() if kind == "l2" else diff.abs().mean()


GRADIENT_BOUND = 1e12
"""SDF gradient components are clamped to +-1e12 in the eikonal loss, so a blown-up field gives a huge
but finite loss (which the trainer's guard rolls back) instead of an overflow to inf and NaN gradients."""


def eikonal_loss(gradients: torch.Tensor, valid: torch.Tensor | None = None) -> torch.Tensor:
    """``mean (|grad sdf| - 1)^2`` over ``gradients [..., 3]`` (optionally only where ``valid [...]``).

    The norm is taken as sqrt(sum^2 + 1e-12) so its gradient is finite at a zero gradient, and of the
    components clamped to ``GRADIENT_BOUND`` so it cannot overflow.
    """
    gradients = gradients.clamp(-GRADIENT_BOUND, GRADIENT_BOUND)
    norm = torch.sqrt((gradients * gradients).sum(-1) + 1e-12)
    error = (norm - 1.0) ** 2
    if valid is None:
        return error.mean()
    weight = valid.to(error.dtype)
    return (error * weight).sum() / weight.sum().clamp_min(1.0)


def mask_loss(accumulation: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy between the accumulated opacity and the foreground mask, both ``[n, 1]``."""
    acc = accumulation.clamp(1e-3, 1.0 - 1e-3)
    return -(mask * torch.log(acc) + (1.0 - mask) * torch.log(1.0 - acc)).mean()


def psnr_from_mse(mse: torch.Tensor) -> torch.Tensor:
    """PSNR in dB for images in [0, 1], with the MSE clamped at 1e-10 (so at most 100 dB)."""
    return -10.0 * torch.log10(mse.clamp_min(1e-10))
