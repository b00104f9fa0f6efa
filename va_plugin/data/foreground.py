"""Foreground masks for inputs without alpha, and a picture of them for the user to check.

Generators paint the object on a flat background (white, or gray for Zero123++).
:func:`color_key_mask` estimates that color from the view's border, keys it out, closes the edges,
drops specks and fills small enclosed holes (large ones, like a mug's handle, stay open).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from va_plugin.data.images import write_image
from va_plugin.errors import DataError


@dataclass
class ColorKey:
    """How background is told from object in an image without alpha."""

    threshold: float = 0.06
    """A pixel is foreground when a channel differs from the background color by more than this."""
    border: int = 3
    """Width in pixels of the frame of each view that the background color is estimated from."""
    min_border_share: float = 0.5
    """At least this share of the border must match the estimated color, or there is no flat background."""
    close_px: int = 3
    """Side of the square kernel of the morphological closing (0: none)."""
    min_blob: float = 0.02
    """Connected pieces smaller than this share of the largest piece are dropped as specks."""
    max_hole: float = 0.01
    """Enclosed background holes smaller than this share of the object's area are filled."""
    min_foreground: float = 0.001
    """A view whose mask covers less than this share of the image has no detectable foreground."""


def _frame(values: np.ndarray, border: int) -> np.ndarray:
    """The outer ``border`` pixels of ``values [H, W, ...]``, flattened to ``[n, ...]``."""
    parts = (values[:border], values[-border:], values[:, :border], values[:, -border:])
    return np.concatenate([p.reshape(-1, *values.shape[2:]) for p in parts])


def estimate_background(image: np.ndarray, border: int = 3) -> np.ndarray:
    """The median color ``[3]`` of the outer ``border`` pixels of an RGB image ``[H, W, 3]``."""
    return np.median(_frame(image, border), axis=0).astype(np.float32)


def _remove_specks(mask: np.ndarray, min_share: float) -> np.ndarray:
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if count <= 1:
        return mask
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.zeros(count, bool)
    keep[1:] = areas >= min_share * areas.max()
    return keep[labels]


def _fill_small_holes(mask: np.ndarray, max_share: float) -> np.ndarray:
    _count, labels, stats, _ = cv2.connectedComponentsWithStats((~mask).astype(np.uint8), connectivity=4)
    height, width = mask.shape
    x, y, w, h, area = (stats[:, i] for i in range(5))
    enclosed = (x > 0) & (y > 0) & (x + w < width) & (y + h < height)
    fill = enclosed & (area <= max_share * mask.sum())
    fill[0] = False  # label 0 is the mask itself
    return mask | fill[labels]


def color_key_mask(image: np.ndarray, key: ColorKey | None = None, where: str = "image") -> np.ndarray:
    """Foreground mask ``[H, W, 1]`` (0 or 1, float32) of an RGB image ``[H, W, 3]`` on a flat background;
    DataError when the border has no dominant color, or nothing stands out from it."""
    key = key or ColorKey()
    background = estimate_background(image, key.border)
    distance = np.abs(image - background).max(axis=-1)
    frame = _frame(distance, key.border)
    color = ", ".join(f"{round(255 * c)}" for c in background)
    if (frame <= key.threshold).mean() < key.min_border_share:
        raise DataError(f"{where}: no flat background color along the border, so the object cannot be keyed "
                        "out; pass a mask for every view with --masks")
    mask = distance > key.threshold
    if key.close_px > 1:
        kernel = np.ones((key.close_px, key.close_px), np.uint8)
        mask = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_CLOSE, kernel).astype(bool)
    mask = _remove_specks(mask, key.min_blob)
    mask = _fill_small_holes(mask, key.max_hole)
    if mask.mean() < key.min_foreground:
        raise DataError(f"{where}: no detectable foreground (every pixel is within {key.threshold:.2f} of the "
                        f"background color {color}); pass a mask with --masks, or check the input")
    return mask[:, :, None].astype(np.float32)


def mask_from_image(image: np.ndarray) -> np.ndarray:
    """A mask ``[H, W, 1]`` (0 or 1) from a user's mask image: its alpha when it has one, else its gray level."""
    values = image[:, :, 3] if image.shape[2] == 4 else image[:, :, :3].mean(axis=-1)
    return (values > 0.5).astype(np.float32)[:, :, None]


def composite(image: np.ndarray, mask: np.ndarray, background: Sequence[float]) -> np.ndarray:
    """RGB ``[H, W, 3]`` with the pixels outside ``mask [H, W, 1]`` replaced by ``background``."""
    return (image * mask + np.asarray(background, np.float32) * (1.0 - mask)).astype(np.float32)


def mask_picture(images: np.ndarray, masks: np.ndarray, columns: int = 8) -> np.ndarray:
    """A contact sheet: each view as the input (top) and its mask (bottom, background tinted magenta,
    outline red), ``images [n, H, W, 3]``, ``masks [n, H, W, 1]`` -> RGB ``[rows * 2H, columns * W, 3]``."""
    n, height, width = images.shape[:3]
    columns = max(1, min(columns, n))
    rows = (n + columns - 1) // columns
    sheet = np.ones((rows * 2 * height, columns * width, 3), np.float32)
    tint = np.array([1.0, 0.0, 1.0], np.float32)
    for i in range(n):
        r, c = divmod(i, columns)
        y, x = r * 2 * height, c * width
        m = masks[i]
        overlay = images[i] * m + (0.4 * images[i] + 0.6 * tint) * (1.0 - m)
        binary = (m[:, :, 0] > 0.5).astype(np.uint8)
        edge = cv2.morphologyEx(binary, cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
        overlay[edge] = (1.0, 0.0, 0.0)
        sheet[y:y + height, x:x + width] = images[i]
        sheet[y + height:y + 2 * height, x:x + width] = overlay
    return sheet


def write_mask_picture(path: Path, images: np.ndarray, masks: np.ndarray) -> Path:
    """Write :func:`mask_picture` of float arrays (or tensors) to ``path`` (PNG)."""
    write_image(Path(path), mask_picture(np.asarray(images), np.asarray(masks)))
    return Path(path)


def check_masks(masks: list[np.ndarray], names: Sequence[str], key: ColorKey) -> None:
    """Refuse masks (user-supplied or alpha) that leave a view with no foreground."""
    for mask, name in zip(masks, names):
        if mask.mean() < key.min_foreground:
            raise DataError(f"{name}: the mask is empty (no foreground pixels); every view needs the object")
