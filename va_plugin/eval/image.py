"""Image metrics: PSNR and SSIM on float ``[H, W, C]`` images in [0, 1] (torch or numpy), as floats.

Callers composite RGBA images on white (``rgb * alpha + (1 - alpha)``), prediction and ground truth alike.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from va_plugin.model_components.losses import psnr_from_mse

ImageLike = torch.Tensor | np.ndarray

PSNR_CAP_DB = 100.0

# SSIM constants of Wang et al. 2004, with scikit-image's gaussian window (sigma 1.5, 11 taps).
SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03


def as_image_tensor(img: ImageLike, name: str = "image") -> torch.Tensor:
    """An ``[H, W, C]`` float32 tensor (on the tensor's device, or the CPU) from a tensor or numpy array;
    ``ValueError`` for a non-3-d or integer image."""
    t = img.detach() if isinstance(img, torch.Tensor) else torch.from_numpy(np.ascontiguousarray(img))
    if t.ndim != 3:
        raise ValueError(f"{name} must have shape [H, W, C], got {tuple(t.shape)}")
    if not t.is_floating_point():
        raise ValueError(f"{name} must be a float image in [0, 1], got dtype {t.dtype}; divide 8-bit images by 255")
    return t.to(torch.float32)


def _check_pair(pred: ImageLike, gt: ImageLike) -> tuple[torch.Tensor, torch.Tensor]:
    """Both images as float32 ``[H, W, C]`` tensors on the prediction's device, same shape."""
    p = as_image_tensor(pred, "pred")
    g = as_image_tensor(gt, "gt").to(p.device)
    if p.shape != g.shape:
        raise ValueError(f"pred and gt shapes differ: {tuple(p.shape)} vs {tuple(g.shape)}")
    return p, g


def psnr(pred: ImageLike, gt: ImageLike, max_val: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB, ``10 * log10(max_val**2 / MSE)``, of ``[H, W, C]`` images in
    ``[0, max_val]``. The MSE is clamped at ``1e-10``: identical images give 100 dB for ``max_val=1``."""
    p, g = _check_pair(pred, gt)
    return float(psnr_from_mse(torch.mean((p - g) ** 2).double(), max_val))


def gaussian_kernel_1d(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> torch.Tensor:
    """Normalised 1-d gaussian taps, shape ``[size]``, centred on ``size // 2``."""
    x = torch.arange(size, dtype=torch.float32) - (size - 1) / 2.0
    k = torch.exp(-(x**2) / (2.0 * sigma**2))
    return k / k.sum()


def _filter_valid(x: torch.Tensor, taps: torch.Tensor) -> torch.Tensor:
    """Separable gaussian filter of ``[C, 1, H, W]`` maps without padding: ``[C, 1, H - k + 1, W - k + 1]``,
    the region scikit-image averages over."""
    k = taps.numel()
    x = F.conv2d(x, taps.view(1, 1, k, 1))
    return F.conv2d(x, taps.view(1, 1, 1, k))


def ssim_map(pred: torch.Tensor, gt: torch.Tensor, data_range: float = 1.0) -> torch.Tensor:
    """Per-pixel SSIM ``[C, H - 10, W - 10]`` of float32 ``[H, W, C]`` tensors (``H, W >= 11``) with
    population covariances; ``data_range``: the images' value range."""
    x = pred.permute(2, 0, 1).unsqueeze(1)  # [C, 1, H, W]: channels as a batch
    y = gt.permute(2, 0, 1).unsqueeze(1)
    taps = gaussian_kernel_1d().to(x.device)
    mu_x, mu_y = _filter_valid(x, taps), _filter_valid(y, taps)
    var_x = _filter_valid(x * x, taps) - mu_x * mu_x
    var_y = _filter_valid(y * y, taps) - mu_y * mu_y
    cov_xy = _filter_valid(x * y, taps) - mu_x * mu_y
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    num = (2.0 * mu_x * mu_y + c1) * (2.0 * cov_xy + c2)
    den = (mu_x * mu_x + mu_y * mu_y + c1) * (var_x + var_y + c2)
    return (num / den).squeeze(1)


def ssim(pred: ImageLike, gt: ImageLike) -> float:
    """Structural similarity of two ``[H, W, C]`` images in [0, 1], at least 11x11, averaged over the
    valid region and the channels. Matches scikit-image's ``structural_similarity(gaussian_weights=True,
    sigma=1.5, use_sample_covariance=False, data_range=1, channel_axis=-1)``."""
    p, g = _check_pair(pred, gt)
    if min(p.shape[0], p.shape[1]) < SSIM_WINDOW:
        raise ValueError(f"SSIM needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels, got {tuple(p.shape)}")
    return ssim_map(p, g).mean().item()
