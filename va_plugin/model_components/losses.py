"""Loss terms shared by the models."""

from __future__ import annotations

import math

import torch


def rgb_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Photometric loss: the mean squared error (the paper's eq. 13) between ``pred`` and ``target``, both
    ``[n_rays, 3]``; a scalar."""
    diff = pred - target
    return (diff * diff).mean()


GRADIENT_BOUND = 1e12
"""SDF gradient components are clamped to +-1e12 in the eikonal loss: a blown-up field gives a huge but
finite loss (rolled back by the trainer's guard), not NaN gradients."""


def eikonal_loss(gradients: torch.Tensor, valid: torch.Tensor | None = None) -> torch.Tensor:
    """``mean (|grad sdf| - 1)^2`` over ``gradients [..., 3]`` (optionally only where ``valid [...]``); the
    norm is sqrt(sum^2 + 1e-12) of the clamped components, finite in value and gradient."""
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


def normal_loss(rendered: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean ``1 - cos`` between rendered normals ``[n, 3]`` (a weighted sum, any length) and target unit
    normals ``[n, 3]``, over the rays whose target is a normal (length above one half; background pixels
    of a normal map are zero). 0 to 2; 0 when no ray has a target."""
    valid = (target.norm(dim=-1) > 0.5).to(rendered.dtype)
    direction = torch.nn.functional.normalize(rendered, dim=-1, eps=1e-6)
    error = 1.0 - (direction * target).sum(-1).clamp(-1.0, 1.0)
    return (error * valid).sum() / valid.sum().clamp_min(1.0)


MSE_FLOOR = 1e-10
"""PSNR's floor on the MSE: identical images score 100 dB (for images in [0, 1]), not infinity."""


def psnr_from_mse(mse: torch.Tensor, max_val: float = 1.0) -> torch.Tensor:
    """PSNR in dB, ``10 * log10(max_val**2 / MSE)``, of images in ``[0, max_val]``, in the MSE's dtype,
    with the MSE clamped at ``MSE_FLOOR``: the one PSNR of the package."""
    return -10.0 * torch.log10(mse.clamp_min(MSE_FLOOR)) + 20.0 * math.log10(max_val)
