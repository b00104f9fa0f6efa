"""The frame of the meshes written for 3D tools: upright (+Y up, standing on y = 0) or the training frame.

The training frame is the one the cameras and the field live in: +Z up, the generator's input view on +x.
glTF (and Blender's OBJ import, three.js, model viewers) take +Y as up and +Z as the front of an asset, so
an upright file is the training frame turned by the proper rotation ``(x, y, z) -> (y, z, x)`` (up goes to
+Y, the input view's side to +Z, handedness and face winding kept), then shifted so the bounding box is
centred on the vertical axis (x and z) and its lowest vertex sits at y = 0. The scale is unchanged.
PLY files stay in the training frame (what ``va-eval`` and the benchmarks read).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from va_plugin.errors import VAError
from va_plugin.utils.files import write_atomic

FRAMES = ("upright", "training")
"""``upright``: +Y up, on the ground, centred (GLB and OBJ default); ``training``: as trained, +Z up."""
UPRIGHT_FORMATS = (".glb", ".obj")
"""Formats written in the chosen frame; every other format (PLY) stays in the training frame."""
UPRIGHT_ROTATION = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
"""Training axes -> upright axes: x' = y, y' = z (up), z' = x (the input view's side, glTF's front)."""
FRAME_SUFFIX = "_frame.json"


def check_frame(frame: str) -> str:
    """``frame`` when it is one of :data:`FRAMES`; VAError otherwise."""
    if frame not in FRAMES:
        raise VAError(f"--frame must be one of {', '.join(FRAMES)}, got {frame!r}")
    return frame


def frame_applies(path: Path) -> bool:
    """Whether a mesh file at ``path`` is written in the chosen frame (GLB, OBJ) or kept in the training frame."""
    return Path(path).suffix.lower() in UPRIGHT_FORMATS


def frame_transform(vertices: np.ndarray, frame: str = "upright") -> np.ndarray:
    """The 4 x 4 matrix that takes training-frame points to ``frame`` (float64; identity for ``training``):
    for ``upright``, :data:`UPRIGHT_ROTATION` then the shift that puts the x and z centre of the bounding
    box of ``vertices [v, 3]`` on the axis and their lowest point at y = 0."""
    check_frame(frame)
    transform = np.eye(4)
    if frame == "training" or len(vertices) == 0:
        return transform
    turned = np.asarray(vertices, np.float64) @ UPRIGHT_ROTATION.T
    low, high = turned.min(0), turned.max(0)
    transform[:3, :3] = UPRIGHT_ROTATION
    transform[:3, 3] = -np.array([(low[0] + high[0]) / 2, low[1], (low[2] + high[2]) / 2])
    return transform


def apply_transform(vertices: np.ndarray, transform: np.ndarray) -> np.ndarray:
    """``vertices [v, 3]`` moved by the 4 x 4 ``transform``, in their own dtype."""
    vertices = np.asarray(vertices)
    moved = np.asarray(vertices, np.float64) @ transform[:3, :3].T + transform[:3, 3]
    return moved.astype(vertices.dtype if vertices.dtype.kind == "f" else np.float64)


def frame_record(frame: str, transform: np.ndarray) -> dict[str, object]:
    """What a file's frame is, as JSON: the frame, its up axis, and the 4 x 4 matrices between it and the
    training frame (row-major, acting on column vectors ``[x, y, z, 1]``)."""
    inverse = np.eye(4)
    inverse[:3, :3] = transform[:3, :3].T  # a rotation's inverse is its transpose
    inverse[:3, 3] = -transform[:3, :3].T @ transform[:3, 3]
    return {"frame": frame, "up": "+y" if frame == "upright" else "+z",
            "training_to_file": (transform + 0.0).tolist(), "file_to_training": (inverse + 0.0).tolist()}


def frame_record_path(mesh_path: Path) -> Path:
    """``<stem>_frame.json`` beside a mesh file."""
    mesh_path = Path(mesh_path)
    return mesh_path.with_name(mesh_path.stem + FRAME_SUFFIX)


def write_frame_record(mesh_path: Path, frame: str, transform: np.ndarray) -> Path:
    """:func:`frame_record` as ``<stem>_frame.json`` beside ``mesh_path`` (whole or not at all)."""
    return write_atomic(frame_record_path(mesh_path), json.dumps(frame_record(frame, transform), indent=2))
