"""A figure of a scene's inputs: the clean views on top, the inconsistent inputs below (on white)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from va_plugin.data.images import read_image, write_image
from va_plugin.errors import DataError

LABEL_COLOR = (30, 30, 30)


def _tile(path: Path, size: int) -> np.ndarray:
    """An RGBA image composited on white and resized to ``size x size``, 8-bit RGB ``[size, size, 3]``."""
    image = read_image(path)
    if image.shape[2] == 4:
        image = image[:, :, :3] * image[:, :, 3:] + (1.0 - image[:, :, 3:])
    if image.shape[0] != size:
        image = cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA)
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _label(tile: np.ndarray, text: str) -> np.ndarray:
    """Write ``text`` in the top-left corner of an 8-bit tile."""
    out = np.ascontiguousarray(tile.copy())
    scale = max(out.shape[0] / 640.0, 0.3)
    cv2.putText(out, text, (4, int(16 * scale / 0.4)), cv2.FONT_HERSHEY_SIMPLEX, scale, LABEL_COLOR, 1,
                cv2.LINE_AA)
    return out


def _per_view(info: dict) -> dict[int, dict]:
    return {v["view"]: v for v in info.get("inconsistency", {}).get("per_view", [])}


def inputs_figure(scene_dir: Path, path: Path, tile_size: int | None = None) -> Path:
    """Write a PNG: top row the clean input views, bottom row the scene's inputs with their PSNR / LPIPS."""
    scene_dir = Path(scene_dir)
    info_path = scene_dir / "scene.json"
    if not info_path.is_file():
        raise DataError(f"not a benchmark scene (no scene.json): {scene_dir}")
    info = json.loads(info_path.read_text())
    views: list[int] = info["train_views"]
    size = tile_size or int(info["resolution"])
    level = info["inconsistency"]["level"]
    errors = _per_view(info)
    top, bottom = [], []
    for i in views:
        top.append(_label(_tile(scene_dir / f"images/clean_{i:03d}.png", size), f"view {i} clean"))
        e = errors.get(i, {})
        text = f"L{level} {e['psnr']:.1f}dB" if e.get("perturbed") else (f"L{level} kept clean" if level else "L0")
        if e.get("perturbed") and e.get("lpips") is not None:
            text += f" {e['lpips']:.3f}"
        bottom.append(_label(_tile(scene_dir / f"images/train_{i:03d}.png", size), text))
    grid = np.concatenate([np.concatenate(top, 1), np.concatenate(bottom, 1)], 0)
    write_image(Path(path), grid)
    return Path(path)
