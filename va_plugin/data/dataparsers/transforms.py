"""The nerfstudio / Blender ``transforms.json`` layout.

A scene folder holds ``transforms_train.json`` and ``transforms_test.json`` (Blender splits) or a
single ``transforms.json`` (every frame is a training frame). Intrinsics come from ``camera_angle_x``
(Blender) or ``fl_x, fl_y, cx, cy, w, h`` (nerfstudio), at the top level or per frame. Each frame has
``file_path`` (relative to the json; ``.png`` is added when it has no extension) and a 4x4
``transform_matrix`` in OpenGL axes. Optional keys of ours: ``scene_radius`` (bounding sphere),
``camera_type`` (``perspective`` or ``orthographic``) and ``pixel_offset``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from va_plugin.cameras import PERSPECTIVE, Cameras, opengl_to_opencv
from va_plugin.data.dataparsers.base import DataParser, DataParserConfig, DataparserOutputs, rescale_views
from va_plugin.data.images import read_image, split_alpha
from va_plugin.errors import DataError

SPLIT_FILES = {"train": "transforms_train.json", "test": "transforms_test.json"}


def _load_json(path: Path) -> dict[str, Any]:
    try:
        with open(path, encoding="utf-8") as handle:
            meta = json.load(handle)
    except json.JSONDecodeError as exc:
        raise DataError(f"{path} is not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except UnicodeDecodeError:
        raise DataError(f"{path} is not a text file") from None
    if not isinstance(meta, dict):
        raise DataError(f"{path} must hold a JSON object with a 'frames' list")
    return meta


def find_split_file(root: Path, split: str) -> Path | None:
    """The json for a split, or None when the scene has no such split."""
    if root.is_file():
        return root if split == "train" else None
    if not root.is_dir():
        raise DataError(f"data folder not found: {root}")
    split_file = root / SPLIT_FILES.get(split, f"transforms_{split}.json")
    if split_file.is_file():
        return split_file
    single = root / "transforms.json"
    if single.is_file():
        return single if split == "train" else None
    if split == "train":
        raise DataError(f"{root} holds neither transforms_train.json nor transforms.json")
    return None


def referenced_files(folder: Path) -> Iterator[tuple[Path, str, str]]:
    """Every file named inside the scene files under ``folder``: (the json, where in it, the entry as
    written) for each frame's ``file_path`` of each ``transforms*.json`` and the ``mesh`` of each
    ``scene.json``. A json that cannot be read is skipped (the parser says what is wrong with it)."""
    for json_path in sorted(Path(folder).rglob("*.json")):
        if not (json_path.name.startswith("transforms") or json_path.name == "scene.json"):
            continue
        try:
            meta = json.loads(json_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if not isinstance(meta, dict):
            continue
        if json_path.name == "scene.json":
            if isinstance(meta.get("mesh"), str):
                yield json_path, "mesh", meta["mesh"]
            continue
        frames = meta.get("frames")
        for k, frame in enumerate(frames if isinstance(frames, list) else []):
            if isinstance(frame, dict) and "file_path" in frame:
                yield json_path, f"frame {k}", str(frame["file_path"])


def _resolve_image(json_dir: Path, file_path: str) -> Path:
    path = (json_dir / file_path).resolve()
    if path.suffix == "" and not path.exists():
        path = path.with_suffix(".png")
    return path


MAX_FIELD_OF_VIEW_DEG = 170.0
"""Widest field of view a perspective camera may have (a pinhole camera cannot see 180 degrees; near it, a
pixel spans a huge angle and the rays no longer meet the object)."""


def _number(value: Any, key: str, where: str) -> float:
    """A JSON number of the camera, finite; a clear error for text, booleans, null or NaN."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise DataError(f"{where}: {key} must be a finite number, got {value!r}")
    return float(value)


def _image_size(meta: dict[str, Any], frame: dict[str, Any], image: np.ndarray, where: str) -> tuple[int, int]:
    """``w, h`` of a frame from its own keys, the file's top-level keys or the image itself."""
    size = []
    for key, axis in (("w", 1), ("h", 0)):
        value = frame.get(key, meta.get(key, image.shape[axis]))
        number = _number(value, key, where)
        if number < 1 or number != int(number):
            raise DataError(f"{where}: {key} must be a positive whole number of pixels, got {value!r}")
        size.append(int(number))
    return size[0], size[1]


def _intrinsics(meta: dict[str, Any], frame: dict[str, Any], width: int, height: int, where: str,
                perspective: bool = True):
    """fx, fy, cx, cy of a frame from its own keys or the file's top-level keys, each checked: numbers, positive
    focal lengths, a principal point inside the image and (perspective) a field of view below
    :data:`MAX_FIELD_OF_VIEW_DEG`."""
    def pick(key):
        return frame.get(key, meta.get(key))

    angle_x = pick("camera_angle_x")
    fl_x, fl_y = pick("fl_x"), pick("fl_y")
    if fl_x is None and angle_x is None:
        raise DataError(f"{where}: no intrinsics (need camera_angle_x or fl_x/fl_y/cx/cy)")
    if fl_x is None:
        angle = _number(angle_x, "camera_angle_x", where)
        if not 0.0 < angle < math.pi:
            raise DataError(f"{where}: camera_angle_x is the horizontal field of view in radians, between 0 and "
                            f"pi; got {angle_x!r}")
        fl_x = 0.5 * width / math.tan(0.5 * angle)
    fl_x = _number(fl_x, "fl_x", where)
    fl_y = fl_x if fl_y is None else _number(fl_y, "fl_y", where)
    if fl_x <= 0 or fl_y <= 0:
        raise DataError(f"{where}: intrinsics must have positive focal lengths, got fl_x {fl_x:g}, fl_y {fl_y:g}")
    cx, cy = pick("cx"), pick("cy")
    cx = width / 2.0 if cx is None else _number(cx, "cx", where)
    cy = height / 2.0 if cy is None else _number(cy, "cy", where)
    if not (0.0 < cx < width and 0.0 < cy < height):
        raise DataError(f"{where}: the principal point (cx {cx:g}, cy {cy:g}) must lie inside the "
                        f"{width}x{height} image")
    if perspective:
        fov = max(2.0 * math.degrees(math.atan(0.5 * width / fl_x)), 2.0 * math.degrees(math.atan(0.5 * height / fl_y)))
        if fov >= MAX_FIELD_OF_VIEW_DEG:
            raise DataError(f"{where}: a field of view of {fov:.1f} degrees (focal length {min(fl_x, fl_y):g} px for "
                            f"a {width}x{height} image) is beyond the {MAX_FIELD_OF_VIEW_DEG:g} a perspective camera "
                            "can have; check camera_angle_x (radians) or fl_x/fl_y (pixels)")
    return [fl_x, fl_y, cx, cy]


@dataclass
class TransformsDataParserConfig(DataParserConfig):
    """Reads a scene in the ``transforms.json`` layout."""

    _target: type = field(default_factory=lambda: TransformsDataParser)


class TransformsDataParser(DataParser):
    config: TransformsDataParserConfig

    def get_outputs(self, split: str = "train") -> DataparserOutputs | None:
        root = Path(self.config.data)
        json_path = find_split_file(root, split)
        if json_path is None:
            return None
        meta = _load_json(json_path)
        frames = meta.get("frames")
        if not isinstance(frames, list) or not frames:
            raise DataError(f"{json_path} has no frames")
        camera_type = str(meta.get("camera_type", PERSPECTIVE))
        images, masks, poses, intrinsics, paths = [], [], [], [], []
        size = None
        for k, frame in enumerate(frames):
            where = f"{json_path.name} frame {k}"
            if not isinstance(frame, dict) or "file_path" not in frame or "transform_matrix" not in frame:
                raise DataError(f"{where}: needs file_path and transform_matrix")
            path = _resolve_image(json_path.parent, str(frame["file_path"]))
            image = read_image(path)
            width, height = _image_size(meta, frame, image, where)
            if (image.shape[1], image.shape[0]) != (width, height):
                raise DataError(f"{path}: image is {image.shape[1]}x{image.shape[0]} "
                                f"but the json says {width}x{height}")
            if size is None:
                size = (width, height)
            elif size != (width, height):
                raise DataError(f"images differ in size: {paths[0]} is {size[0]}x{size[1]}, {path} is {width}x{height}")
            try:
                matrix = np.asarray(frame["transform_matrix"], dtype=np.float64)
            except (TypeError, ValueError):
                raise DataError(f"{where}: transform_matrix must be a 4x4 list of numbers") from None
            if matrix.shape not in ((4, 4), (3, 4)):
                raise DataError(f"{where}: transform_matrix must be 4x4, got shape {list(matrix.shape)}")
            if matrix.shape == (4, 4) and not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
                raise DataError(f"{where}: transform_matrix is not a rigid transform (its last row is "
                                f"{matrix[3].tolist()}, not [0, 0, 0, 1])")
            rgb, mask = split_alpha(image, self.config.background)
            images.append(rgb)
            masks.append(mask)
            poses.append(matrix[:3, :4])
            intrinsics.append(_intrinsics(meta, frame, width, height, where, camera_type == PERSPECTIVE))
            paths.append(path)
        has_masks = all(m is not None for m in masks)
        c2w = opengl_to_opencv(torch.tensor(np.stack(poses), dtype=torch.float32))
        fx, fy, cx, cy = torch.tensor(intrinsics, dtype=torch.float32).unbind(-1)
        cameras = Cameras(c2w, fx, fy, cx, cy, size[0], size[1],
                          camera_type=camera_type,
                          pixel_offset=_number(meta.get("pixel_offset", 0.5), "pixel_offset", json_path.name))
        cameras, images_np, masks_np = rescale_views(cameras, np.stack(images), np.stack(masks) if has_masks else None,
                                                     self.config.image_scale)
        radius = _number(meta.get("scene_radius", self.config.scene_radius), "scene_radius", json_path.name)
        chosen = float(self.config.scene_radius)
        if "scene_radius" in meta and chosen not in (radius, DataParserConfig.scene_radius):
            raise DataError(f"contradictory scene radius: {json_path.name} says {radius:g}, the options say "
                            f"{chosen:g}; change scene_radius in the json, or drop the option")
        metadata = {"json": str(json_path)}
        scene_file = json_path.parent / "scene.json"
        if scene_file.is_file():
            metadata["scene"] = _load_json(scene_file)
        return DataparserOutputs(
            images=torch.from_numpy(images_np).float(),
            masks=torch.from_numpy(masks_np).float() if masks_np is not None else None,
            cameras=cameras, scene_radius=radius, background=tuple(self.config.background),
            image_paths=paths, metadata=metadata)


def frames_to_json(cameras: Cameras, file_paths: list[str], extra: dict[str, Any] | None = None
                   ) -> dict[str, Any]:
    """The inverse of the parser: a ``transforms.json`` dict for ``cameras`` (used by scene writers)."""
    gl = opengl_to_opencv(cameras.c2w)  # the flip is its own inverse
    frames = []
    for i, file_path in enumerate(file_paths):
        matrix = torch.eye(4)
        matrix[:3, :4] = gl[i]
        frames.append({"file_path": file_path, "transform_matrix": matrix.tolist(),
                       "fl_x": float(cameras.fx[i]), "fl_y": float(cameras.fy[i]),
                       "cx": float(cameras.cx[i]), "cy": float(cameras.cy[i])})
    meta = {"w": cameras.width, "h": cameras.height, "camera_type": cameras.camera_type,
            "pixel_offset": cameras.pixel_offset, "frames": frames}
    meta.update(extra or {})
    return meta
