"""Rendering held-out views and turntables of a trained model."""

from __future__ import annotations

import numbers
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import torch

from va_plugin.cameras import Cameras
from va_plugin.data.images import write_image
from va_plugin.data.rigs import orbit_cameras
from va_plugin.errors import ConfigError
from va_plugin.fields.encodings.hash_kernel import denormals_flushed
from va_plugin.raycast import MeshRenderer
from va_plugin.rays import RayBundle
from va_plugin.utils.arguments import check_kind, check_kinds
from va_plugin.utils.memory import check_image_side
from va_plugin.utils.progress import progress_bar

if TYPE_CHECKING:
    import trimesh


def check_render_options(scale: float, max_views: int | None, frames: int, turntable_resolution: int,
                         progress: bool) -> None:
    """Refuse render options that cannot work, before the run is loaded (one line each)."""
    check_kinds(scale=(scale, numbers.Real), frames=(frames, numbers.Integral),
                turntable_resolution=(turntable_resolution, numbers.Integral), progress=(progress, bool))
    check_kind("max_views", max_views, numbers.Integral, optional=True)
    if scale <= 0 or frames < 1 or turntable_resolution < 2:
        raise ConfigError("--scale must be positive, --frames at least 1 and --turntable-resolution at least 2")
    check_image_side(turntable_resolution, "--turntable-resolution")


def render_view(model, cameras: Cameras, index: int, as_view: int = -1, keys=None):
    """RGB ``[H, W, 3]`` float of one camera, rendered with the canonical (novel-view) path, or with
    training view ``as_view``'s own path (its branch, for view-adaptive models) when ``as_view >= 0``.
    With ``keys`` (outputs of the model, e.g. ``("rgb", "rgb_canonical")`` or ``("accumulation",)``), a list
    of those images ``[H, W, C]`` from the same render pass."""
    device = next(model.parameters()).device
    cameras = cameras.to(device)
    views, rows, cols = cameras.pixel_grid(index)
    origins, directions = cameras.generate_rays(index, rows, cols)
    rays = RayBundle(origins, directions, torch.full_like(views, as_view))
    wanted = ("rgb",) if keys is None else tuple(keys)
    with denormals_flushed(device.type == "cpu"):  # far from the surface the field underflows: same images
        outputs = model.render_rays(rays, keys=wanted)
    images = [outputs[k].reshape(cameras.height, cameras.width, -1).cpu().numpy() for k in wanted]
    return images[0] if keys is None else images


def turntable_cameras(n_frames: int, resolution: int, elevation_deg: float = 30.0) -> Cameras:
    """Cameras circling the object on the SyncDreamer rig's orbit."""

    return orbit_cameras([360.0 * k / n_frames for k in range(n_frames)], elevation_deg, resolution=resolution)


def write_video(frames: list[np.ndarray], path: Path, fps: int = 12) -> Path:
    """Write frames (float RGB) as an MP4 (mp4v) video."""
    path = Path(path)
    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    for frame in frames:
        writer.write((np.clip(frame, 0, 1)[:, :, ::-1] * 255 + 0.5).astype(np.uint8))
    writer.release()
    return path


def render_turntable(model, out_dir: Path, n_frames: int = 24, resolution: int = 128, progress: bool = True
                     ) -> list[Path]:
    """PNG frames and ``turntable.mp4`` in ``out_dir``."""
    out_dir = Path(out_dir)
    cameras = turntable_cameras(n_frames, resolution)
    frames, paths = [], []
    for k in progress_bar(range(n_frames), desc="turntable", disable=not progress):
        frame = render_view(model, cameras, k)
        frames.append(frame)
        path = out_dir / f"frame_{k:03d}.png"
        write_image(path, frame)
        paths.append(path)
    paths.append(write_video(frames, out_dir / "turntable.mp4"))
    return paths


def held_out_views(pipeline, scale: float = 1.0, max_views: int | None = None, progress: bool = True,
                   desc: str = "test views", render_fn=None) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """``(index, render, target)`` of the first ``max_views`` held-out views (all when None), rendered on
    the canonical path at ``scale`` of the scene's size, the target resized to match (area filter).
    ``render_fn(cameras, index) -> [H, W, 3]`` renders something else at those cameras (a textured mesh)."""
    test = pipeline.datamanager.test
    if test is None:
        return
    cameras = test.cameras.scaled(scale) if scale != 1.0 else test.cameras
    count = len(test) if max_views is None else min(max_views, len(test))
    for i in progress_bar(range(count), desc=desc, disable=not progress):
        render = render_view(pipeline.model, cameras, i) if render_fn is None else render_fn(cameras, i)
        target = test.images[i].numpy()
        if scale != 1.0:
            target = cv2.resize(target, (cameras.width, cameras.height), interpolation=cv2.INTER_AREA)
        yield i, render, target


def write_pair(out_dir: Path, index: int, render: np.ndarray, target: np.ndarray) -> Path:
    """``view_XXX.png``: the render next to its ground truth."""
    path = Path(out_dir) / f"view_{index:03d}.png"
    write_image(path, np.concatenate([render, target], axis=1))
    return path


def render_test_views(pipeline, out_dir: Path, scale: float = 1.0, max_views: int | None = None,
                      progress: bool = True) -> list[Path]:
    """Each held-out view rendered next to its ground truth: ``view_XXX.png`` (render | target)."""
    return [write_pair(out_dir, i, render, target)
            for i, render, target in held_out_views(pipeline, scale, max_views, progress)]


def mesh_views(meshes: list[trimesh.Trimesh], n_views: int = 4, resolution: int = 128,
               elevation_deg: float = 30.0, background: float = 1.0) -> np.ndarray:
    """One row per mesh of ``n_views`` grey shaded renders on the SyncDreamer orbit: the meshes' geometry
    side by side (vertex colors are ignored)."""

    cameras = turntable_cameras(n_views, resolution, elevation_deg)
    grey = lambda hits: np.full((hits.points.shape[0], 3), 0.8, np.float32)
    rows = []
    for mesh in meshes:
        renderer = MeshRenderer(mesh, grey)
        tiles = []
        for k in range(n_views):
            rgba = renderer.render(cameras, k)
            tiles.append(rgba[..., :3] * rgba[..., 3:] + background * (1.0 - rgba[..., 3:]))
        rows.append(np.concatenate(tiles, axis=1))
    return np.concatenate(rows, axis=0)
