"""Writing rendered views as a multi-view generator writes them: its file names, sizes, background and
tile order, from its rig (:mod:`va_plugin.data.rigfile`), so each reader is tested and benchmarked on data
it did not write itself.

A grid or strip becomes one image (``path`` names it), a folder one file per view (and normal maps when the
rig names them), a video an MP4 (or, with ``frames_folder``, a folder of frame PNGs).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from va_plugin.data.images import write_image
from va_plugin.data.rigfile import UP_SIDES, RigSpec, shown_name
from va_plugin.errors import DataError


def on_background(rgba: np.ndarray, spec: RigSpec) -> np.ndarray:
    """Views ``[n, t, t, 4]`` as the generator paints them: on its background colour, or RGBA as they are."""
    if spec.background is None:
        return rgba
    return rgba[..., :3] * rgba[..., 3:] + np.asarray(spec.background, np.float32) * (1.0 - rgba[..., 3:])


def as_written(views: np.ndarray, spec: RigSpec) -> np.ndarray:
    """Upright views ``[n, t, t, C]`` turned so the object's top faces the rig's ``up`` side."""
    turns = UP_SIDES[spec.up]
    return np.stack([np.rot90(v, -turns) for v in views]) if turns else views


def assemble(views: np.ndarray, spec: RigSpec) -> np.ndarray:
    """Views in file order ``[n, t, t, C]`` as one grid or strip image."""
    if spec.layout == "strip":
        return np.concatenate(list(views), axis=1)
    if spec.layout == "grid":
        rows = [np.concatenate(list(views[r * spec.columns:(r + 1) * spec.columns]), axis=1)
                for r in range(spec.rows)]
        return np.concatenate(rows, axis=0)
    raise DataError(f"{spec.name} writes a {spec.layout}, not one image")


def write_video(path: Path, frames: np.ndarray, fps: int = 7) -> Path:
    """RGB frames ``[n, H, W, 3]`` in [0, 1] as an MP4 (mp4v, what OpenCV writes everywhere)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    height, width = frames.shape[1:3]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    try:
        for frame in frames:
            writer.write(np.ascontiguousarray((np.clip(frame, 0, 1) * 255 + 0.5).astype(np.uint8)[:, :, ::-1]))
    finally:
        writer.release()
    return path


def write_layout(path: Path, spec: RigSpec, rgba: np.ndarray, normals: np.ndarray | None = None,
                 frames_folder: bool = False) -> Path:
    """Write views rendered on ``spec``'s cameras (``rgba [n, t, t, 4]`` in file order; ``normals [n, t, t, 4]``
    encoded maps with alpha, for rigs that name them) in the generator's layout at ``path`` (the image or
    video file, or the folder). Returns ``path``."""
    path = Path(path)
    if len(rgba) != spec.count:
        raise DataError(f"{spec.name} has {spec.count} views; got {len(rgba)} renders")
    views = as_written(on_background(rgba, spec), spec)
    if spec.layout in ("grid", "strip"):
        write_image(path, assemble(views, spec))
    elif spec.layout == "video" and not frames_folder:
        write_video(path, views[..., :3])
    else:
        path.mkdir(parents=True, exist_ok=True)
        names = [shown_name(spec.files[-1], v) for v in spec.view_names] if spec.files else \
            [f"{k:03d}.png" for k in range(spec.count)]
        for name, view in zip(names, views):
            write_image(path / name, view)
        if spec.normals and normals is not None:
            for view_name, normal in zip(spec.view_names, as_written(normals, spec)):
                write_image(path / shown_name(spec.normals, view_name), normal)
    return path
