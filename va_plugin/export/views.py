"""Per surface point, the color each input view shows there and how much to trust it.

A view sees a point in front of it, in its image, with no mesh in between (ray cast). Its weight: the
squared cosine to the normal, times a ramp from the silhouette edge, times (with inconsistency maps) a
fall-off where the view disagrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from va_plugin.cameras import Cameras
from va_plugin.raycast import o3d
from va_plugin.utils.progress import progress_bar

EDGE_PIXELS = 3.0
"""A view's weight rises from 0 at EDGE_MARGIN pixels inside its silhouette to 1 this many pixels further."""
EDGE_MARGIN = 1.5
"""Pixels this close to the silhouette edge blend the object with the background: they give no color."""
OPAQUE = 0.99
"""A pixel belongs to the object where its mask is at least this; partial pixels at the outline mix in the
background's color, so they count as background."""
MIN_COS = 0.1
"""Views seeing the surface more grazing than this (cos of the angle to the normal) are ignored."""
INCONSISTENCY_SCALE = 0.05
"""With inconsistency maps: a view keeps exp(-map / this) of its weight (0.05 = a clear disagreement)."""


@dataclass
class Views:
    """Input views to bake from."""

    cameras: Cameras
    images: np.ndarray  # [n, H, W, 3] float32, composited on the background
    masks: np.ndarray | None = None  # [n, H, W] bool (None: the mesh's own silhouettes)
    inconsistency: np.ndarray | None = None  # [n, h, w] float32 per-view disagreement maps, any size

    def __len__(self) -> int:
        return len(self.images)


def bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``image [H, W, C]`` (or ``[H, W]``) at continuous pixel coordinates ``x, y [m]`` (pixel centres at
    integers, clamped to the border): ``[m, C]`` (or ``[m]``)."""
    h, w = image.shape[:2]
    x = np.clip(x, 0.0, w - 1.0)
    y = np.clip(y, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), max(w - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.int64), max(h - 2, 0))
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = x - x0, y - y0
    if image.ndim == 3:
        fx, fy = fx[:, None], fy[:, None]
    flat = image.reshape(h * w, *image.shape[2:])  # a gather by flat index: far quicker than image[y, x]
    row0, row1 = y0 * w, y1 * w
    left = 1 - fx
    top = np.take(flat, row0 + x0, axis=0) * left + np.take(flat, row0 + x1, axis=0) * fx
    bottom = np.take(flat, row1 + x0, axis=0) * left + np.take(flat, row1 + x1, axis=0) * fx
    return (top * (1 - fy) + bottom * fy).astype(np.float32)


def rays_through(cameras: Cameras, index: int, points: np.ndarray):
    """Rays of view ``index`` through world points ``[m, 3]``: ``origins, directions [m, 3]``, the points'
    distance along them ``[m]`` and their pixel coordinates ``[m, 2]`` (column, row)."""
    pts = torch.as_tensor(points, dtype=torch.float32)
    uv, _ = cameras.project(pts, index)
    origins, directions = cameras.generate_rays(index, uv[:, 1], uv[:, 0])
    distance = ((pts - origins) * directions).sum(-1)
    return origins.numpy(), directions.numpy(), distance.numpy(), uv.numpy()


def silhouette_distance(scene, cameras: Cameras, index: int, mask: np.ndarray | None) -> np.ndarray:
    """Distance in pixels ``[H, W]`` to the nearest pixel outside the object in view ``index`` (0 outside);
    the object is where the mesh is hit and, when given, ``mask`` is set."""
    _, rows, cols = cameras.pixel_grid(index)
    origins, directions = cameras.generate_rays(index, rows, cols)
    rays = np.concatenate([origins.numpy(), directions.numpy()], -1).astype(np.float32)
    inside = np.isfinite(scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()).reshape(cameras.height,
                                                                                           cameras.width)
    if mask is not None:
        inside &= mask
    padded = np.pad(inside.astype(np.uint8), 1)  # the image border counts as an edge
    return cv2.distanceTransform(padded, cv2.DIST_L2, 5)[1:-1, 1:-1]


def view_samples(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, normals: np.ndarray, views: Views,
                 edge_pixels: float = EDGE_PIXELS, progress: bool = False):
    """Color and weight of every view at every surface point ``points, normals [m, 3]`` (unit outward
    normals) of the mesh ``vertices, faces`` (which occludes): colors ``[m, n, 3]``, weights ``[m, n]``
    (0: unseen) and ``in_view [n]`` bool (any pixel of view k shows the mesh inside its mask)."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
    edges = np.linalg.norm(vertices[faces[:, 1]] - vertices[faces[:, 0]], axis=-1)
    tolerance = 0.5 * float(np.median(edges)) if len(edges) else 1e-3  # depth slack of the visibility test
    m, n = len(points), len(views)
    colors = np.zeros((m, n, 3), np.float32)
    weights = np.zeros((m, n), np.float32)
    in_view = np.zeros(n, bool)
    cameras = views.cameras
    for k in progress_bar(range(n), desc="projecting views", disable=not progress):
        edge = silhouette_distance(scene, cameras, k, None if views.masks is None else views.masks[k])
        in_view[k] = bool(edge.max() > 0)
        origins, directions, distance, pix = rays_through(cameras, k, points)
        cos = -(normals * directions).sum(-1)
        candidate = (cos > MIN_COS) & (distance > 0)
        candidate &= (pix[:, 0] > -0.5) & (pix[:, 0] < cameras.width - 0.5)
        candidate &= (pix[:, 1] > -0.5) & (pix[:, 1] < cameras.height - 0.5)
        idx = np.nonzero(candidate)[0]
        if len(idx) == 0:
            continue
        rays = np.concatenate([origins[idx], directions[idx]], -1).astype(np.float32, copy=False)
        t_hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        idx = idx[t_hit >= distance[idx] - tolerance]  # nothing in front of the point
        x, y = pix[idx, 0], pix[idx, 1]
        w = cos[idx] ** 2 * np.clip((bilinear(edge, x, y) - EDGE_MARGIN) / max(edge_pixels, 1e-6), 0.0, 1.0)
        if views.inconsistency is not None:
            imap = views.inconsistency[k]
            sx, sy = imap.shape[1] / cameras.width, imap.shape[0] / cameras.height
            spread = bilinear(imap, (x + 0.5) * sx - 0.5, (y + 0.5) * sy - 0.5)
            w = w * np.exp(-np.maximum(spread, 0.0) / INCONSISTENCY_SCALE)
        keep = w > 0
        colors[idx[keep], k] = bilinear(views.images[k], x[keep], y[keep])
        weights[idx[keep], k] = w[keep]
    return colors, weights, in_view
