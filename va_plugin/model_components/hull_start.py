"""A start from the masks: the SDF of the views' visual hull, and a short fit of a field to it.

A NeuS field starts as a sphere; its first few hundred steps mostly carve that sphere to the silhouettes.
The masks already say where the silhouettes are: the visual hull (every point that projects into the
foreground of every view) is a shape the object lies inside of, up to the generator's inconsistency. Its
signed distance, on a voxel grid, is a target a field fits in a fraction of a training step's cost per
point, so training starts from the hull instead of the sphere.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from scipy import ndimage

from va_plugin.cameras import Cameras
from va_plugin.data.visual_hull import foreground_votes
from va_plugin.utils.threads import single_thread


def hull_sdf_volume(cameras: Cameras, masks: torch.Tensor, radius: float, resolution: int,
                    agreement: float = 1.0) -> torch.Tensor | None:
    """The signed distance ``[R, R, R]`` (indexed x, y, z; negative inside) to the visual hull of ``masks
    [n, H, W]`` (foreground above one half) seen by ``cameras``, at the centres of ``resolution`` voxels a
    side over the cube ``[-radius, radius]^3``; the hull's boundary lies halfway between an inside and an
    outside centre.
    None when no voxel centre is inside every silhouette, or every one is."""
    voxel = 2.0 * radius / resolution
    axis = -radius + voxel * (torch.arange(resolution, dtype=torch.float32) + 0.5)
    points = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    masks = masks.cpu().float().reshape(len(cameras), cameras.height, cameras.width) > 0.5  # [n, H, W(, 1)]
    with single_thread():
        votes = foreground_votes(cameras.to(torch.device("cpu")), masks, points)
    inside = votes >= max(1, math.ceil(agreement * len(cameras) - 1e-6))
    inside = inside.reshape(resolution, resolution, resolution).numpy()
    if not inside.any() or inside.all():
        return None
    outside_distance = ndimage.distance_transform_edt(~inside)  # to the nearest inside centre, in voxels
    inside_distance = ndimage.distance_transform_edt(inside)  # to the nearest outside centre
    sdf = np.where(inside, 0.5 - inside_distance, outside_distance - 0.5) * voxel
    return torch.from_numpy(sdf.astype(np.float32))


def sample_volume(volume: torch.Tensor, radius: float, points: torch.Tensor) -> torch.Tensor:
    """Trilinear values ``[n]`` of ``volume [R, R, R]`` (voxel centres over ``[-radius, radius]^3``, indexed
    x, y, z) at ``points [n, 3]``; beyond the outer centres the border value holds."""
    grid = (points / radius).reshape(1, -1, 1, 1, 3)  # grid_sample's (x, y, z) index (W, H, D)
    values = F.grid_sample(volume.permute(2, 1, 0)[None, None], grid, mode="bilinear", padding_mode="border",
                           align_corners=False)
    return values.reshape(-1)


def fit_field_to_volume(field, volume: torch.Tensor, radius: float, steps: int, points_per_step: int = 4096,
                        lr: float = 1e-2, seed: int = 0) -> float:
    """Fit ``field``'s SDF to ``volume`` (see :func:`hull_sdf_volume`) by ``steps`` Adam steps of the mean
    absolute error on ``points_per_step`` points, half uniform in the cube and half within two voxels of
    the hull's boundary. Only the parameters the SDF depends on move; the optimizer's moments are dropped
    afterwards. Returns the last step's mean absolute error (world units)."""
    device = next(field.parameters()).device
    volume = volume.to(device)
    resolution = volume.shape[0]
    voxel = 2.0 * radius / resolution
    axis = -radius + voxel * (torch.arange(resolution, device=device, dtype=torch.float32) + 0.5)
    near = (volume.abs() < 1.5 * voxel).nonzero()
    near_points = torch.stack([axis[near[:, 0]], axis[near[:, 1]], axis[near[:, 2]]], -1)
    generator = torch.Generator(device="cpu").manual_seed(seed)
    params = [p for p in field.parameters() if p.requires_grad]
    optimizer = torch.optim.Adam(params, lr=lr)
    half = points_per_step // 2
    error = float("nan")
    for _ in range(steps):
        uniform = (torch.rand(points_per_step - half, 3, generator=generator) * 2.0 - 1.0).to(device) * radius
        pick = torch.randint(0, near_points.shape[0], (half,), generator=generator).to(device)
        jitter = (torch.rand(half, 3, generator=generator) * 2.0 - 1.0).to(device) * voxel
        points = torch.cat([uniform, near_points[pick] + jitter])
        target = sample_volume(volume, radius, points)
        optimizer.zero_grad(set_to_none=True)
        loss = (field.geometry(points)[0][..., 0] - target).abs().mean()
        loss.backward()
        optimizer.step()
        error = float(loss.detach())
    optimizer.zero_grad(set_to_none=True)
    return error
