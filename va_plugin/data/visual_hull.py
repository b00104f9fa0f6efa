"""The visual hull of a set of masked views: where the object can be, and how well the rig explains it.

Used by the generator dataparsers to (a) scale and centre a rig whose object size is not fixed by the
generator (Zero123++'s radius is "up to you"), and (b) check a rig against its images: with the right
cameras the hull's projection covers each mask (IoU near 1, less the generator's own inconsistency);
with wrong ones (mirrored azimuths, wrong elevation) the silhouettes carve each other away.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from va_plugin.cameras import PERSPECTIVE, Cameras
from va_plugin.utils.threads import single_thread


@dataclass
class Hull:
    """Occupied voxel centres of a visual hull and the per-view agreement of its silhouette."""

    points: torch.Tensor  # [m, 3]
    voxel: float
    silhouette_iou: list[float]

    @property
    def bounds(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Lower and upper corners ``[3]`` of the occupied voxels' box (voxel extent included)."""
        half = self.voxel / 2.0
        return self.points.min(0).values - half, self.points.max(0).values + half

    def moved(self, centre: torch.Tensor, scale: float) -> Hull:
        """The same hull in a world moved by ``-centre`` and scaled by ``scale`` (silhouettes unchanged)."""
        return Hull((self.points - centre) * scale, self.voxel * scale, list(self.silhouette_iou))


def _inside_all(cameras: Cameras, masks: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """``[m]`` True where a point projects into the foreground of every view. A projection beyond the
    frame takes the mask value at the nearest edge pixel, so an object cut by the frame is not cut off."""
    keep = torch.ones(points.shape[0], dtype=torch.bool)
    for k in range(len(cameras)):
        uv, depth = cameras.project(points[keep], k)
        col = uv[:, 0].round().clamp(0, cameras.width - 1).long()
        row = uv[:, 1].round().clamp(0, cameras.height - 1).long()
        keep[keep.clone()] = masks[k, row, col] & (depth > 0)
    return keep


def _grid(lower: torch.Tensor, upper: torch.Tensor, resolution: int) -> tuple[torch.Tensor, float]:
    voxel = float((upper - lower).max()) / resolution
    axes = [torch.arange(lower[i] + voxel / 2, upper[i], voxel) for i in range(3)]
    points = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return points, voxel


def search_bound(cameras: Cameras) -> float:
    """Half-side of a cube at the origin that holds everything the views can see of the object."""
    extents = []
    for k in range(len(cameras)):
        half_image = 0.5 * max(cameras.width / cameras.fx[k], cameras.height / cameras.fy[k])
        if cameras.camera_type == PERSPECTIVE:
            distance = float(cameras.centers[k].norm())
            extents.append(min(0.95 * distance, distance * float(half_image)))
        else:
            extents.append(float(half_image))
    return max(extents)


def visual_hull(cameras: Cameras, masks: torch.Tensor, resolution: int = 64) -> Hull:
    """The hull of ``masks [n, H, W]`` (bool) seen by ``cameras``: a coarse pass over the whole search
    cube, then a finer one over the coarse hull's box. Empty ``points`` when the silhouettes exclude
    each other."""
    with single_thread():
        return _visual_hull(cameras.to(torch.device("cpu")), masks.bool().cpu(), resolution)


def _visual_hull(cameras: Cameras, masks: torch.Tensor, resolution: int) -> Hull:
    bound = search_bound(cameras)
    lower, upper = torch.full((3,), -bound), torch.full((3,), bound)
    points, voxel = _grid(lower, upper, resolution // 2)
    occupied = points[_inside_all(cameras, masks, points)]
    if occupied.numel():
        lower, upper = occupied.min(0).values - voxel, occupied.max(0).values + voxel
        points, voxel = _grid(lower, upper, resolution)
        occupied = points[_inside_all(cameras, masks, points)]
    return Hull(occupied, voxel, silhouette_agreement(cameras, masks, occupied, voxel))


def silhouette_agreement(cameras: Cameras, masks: torch.Tensor, points: torch.Tensor, voxel: float) -> list[float]:
    """IoU per view between each mask and the projection of the hull's voxels (voxel centres dilated by
    the typical footprint of one voxel in that view)."""
    scores = []
    for k in range(len(cameras)):
        if points.numel() == 0:
            scores.append(0.0)
            continue
        uv, depth = cameras.project(points, k)
        scale = float(cameras.fx[k]) / (float(depth.median()) if cameras.camera_type == PERSPECTIVE else 1.0)
        footprint = max(1, int(np.ceil(voxel * scale)))
        col, row = uv[:, 0].round().long().numpy(), uv[:, 1].round().long().numpy()
        ok = (col >= 0) & (col < cameras.width) & (row >= 0) & (row < cameras.height)
        projected = np.zeros((cameras.height, cameras.width), np.uint8)
        projected[row[ok], col[ok]] = 1
        projected = cv2.dilate(projected, np.ones((footprint, footprint), np.uint8)).astype(bool)
        mask = masks[k].numpy()
        scores.append(float((projected & mask).sum()) / max(int((projected | mask).sum()), 1))
    return scores


def unit_box_transform(lower: torch.Tensor, upper: torch.Tensor, side: float = 1.0) -> tuple[torch.Tensor, float]:
    """Centre and scale that take the box ``[lower, upper]`` to a box at the origin whose longest side is
    ``side`` (the unit box the models are tuned for): ``x' = (x - centre) * scale``."""
    return (lower + upper) / 2.0, side / float((upper - lower).max())


def normalise_cameras(cameras: Cameras, centre: torch.Tensor, scale: float) -> Cameras:
    """The same views of a world moved by ``-centre`` and scaled by ``scale``."""
    c2w = cameras.c2w.clone()
    c2w[:, :, 3] = (c2w[:, :, 3] - centre) * scale
    # perspective intrinsics are scale-free; orthographic ones count pixels per world unit
    focal = 1.0 if cameras.camera_type == PERSPECTIVE else 1.0 / scale
    return Cameras(c2w, cameras.fx * focal, cameras.fy * focal, cameras.cx, cameras.cy, cameras.width,
                   cameras.height, cameras.camera_type, cameras.pixel_offset)
