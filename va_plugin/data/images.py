"""Reading images with clear errors, and compositing them on a background."""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

from va_plugin.errors import DataError


@contextmanager
def native_stderr_silenced() -> Iterator[None]:
    """Silence file descriptor 2 for a moment: OpenCV and libpng print their own lines about a broken
    file straight to it ("libpng error: ..."), where we raise one clear :class:`DataError` instead."""
    try:
        saved = os.dup(2)
    except OSError:  # no stderr at all
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


EXIF_ORIENTED = cv2.IMREAD_ANYCOLOR | cv2.IMREAD_ANYDEPTH
"""OpenCV's flags that keep gray, color and 16 bits as in the file and turn the image as its EXIF
orientation says (``IMREAD_UNCHANGED`` keeps alpha but ignores the orientation)."""


def has_exif(raw: np.ndarray) -> bool:
    """Whether the bytes of a file are a JPEG with an EXIF block (where a camera or a phone records that
    the picture is to be shown turned; JPEG has no alpha to lose)."""
    return raw[:2].tobytes() == b"\xff\xd8" and b"Exif\x00\x00" in raw[:65536].tobytes()


def decode_image(raw: np.ndarray, flags: int | None = None) -> np.ndarray | None:
    """``cv2.imdecode`` of the bytes of a file, None for a corrupt, truncated or non-image file, quietly.
    By default every channel is kept (``IMREAD_UNCHANGED``), and a JPEG with EXIF is turned upright as
    its orientation tag says."""
    if raw.size == 0:
        return None
    if flags is None:
        flags = EXIF_ORIENTED if has_exif(raw) else cv2.IMREAD_UNCHANGED
    with native_stderr_silenced():
        return cv2.imdecode(raw, flags)


def undecodable(path: Path) -> DataError:
    """The error for an image file that cannot be decoded (empty, corrupt, truncated or not an image)."""
    empty = "empty, " if Path(path).is_file() and Path(path).stat().st_size == 0 else ""
    return DataError(f"cannot decode image ({empty}corrupt, truncated or not an image): {path}")


def read_image(path: Path) -> np.ndarray:
    """An 8- or 16-bit image file as float32 ``[H, W, C]`` in [0, 1], C = 3 (RGB) or 4 (RGBA), turned as
    its EXIF orientation says; :class:`DataError` for a missing, truncated or non-image file."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"image not found: {path}")
    raw = np.fromfile(str(path), dtype=np.uint8)
    image = decode_image(raw)
    if image is None:
        raise undecodable(path)
    if image.dtype == np.uint16:
        image = image.astype(np.float32) / 65535.0
    elif image.dtype == np.uint8:
        image = image.astype(np.float32) / 255.0
    else:
        image = image.astype(np.float32)
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    if image.shape[2] == 3:
        image = image[:, :, ::-1]
    elif image.shape[2] == 4:
        image = image[:, :, [2, 1, 0, 3]]
    else:
        raise DataError(f"image has {image.shape[2]} channels, expected gray, RGB or RGBA: {path}")
    if not np.isfinite(image).all():
        raise DataError(f"image contains NaN or infinite values: {path}")
    return np.ascontiguousarray(np.clip(image, 0.0, 1.0))


def write_image(path: Path, image: np.ndarray) -> None:
    """Write float ``[H, W, 3|4]`` in [0, 1] (or uint8) as an 8-bit image; format by extension."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if image.dtype != np.uint8:
        image = (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    if image.ndim == 3 and image.shape[2] == 3:
        image = image[:, :, ::-1]
    elif image.ndim == 3 and image.shape[2] == 4:
        image = image[:, :, [2, 1, 0, 3]]
    if not cv2.imwrite(str(path), np.ascontiguousarray(image)):
        raise DataError(f"cannot write image: {path}")


def split_alpha(image: np.ndarray, background: Sequence[float]) -> tuple[np.ndarray, np.ndarray | None]:
    """Composite an RGBA image on ``background``: RGB ``[H, W, 3]`` and mask ``[H, W, 1]`` (an RGB image
    comes back as it is, with no mask)."""
    if image.shape[2] == 3:
        return image, None
    alpha = image[:, :, 3:4]
    rgb = image[:, :, :3] * alpha + np.asarray(background, dtype=np.float32) * (1.0 - alpha)
    return rgb.astype(np.float32), alpha.astype(np.float32)


def resize(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Area-resample an image to ``width x height`` (keeps float and channel count)."""
    if image.shape[1] == width and image.shape[0] == height:
        return image
    out = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
    return out[:, :, None] if out.ndim == 2 else out


VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".webm", ".mkv")


def read_video(path: Path) -> list[np.ndarray]:
    """Every frame of a video file as float32 RGB ``[H, W, 3]`` in [0, 1]; :class:`DataError` for a missing
    file or one OpenCV cannot decode."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"video not found: {path}")
    with native_stderr_silenced():
        capture = cv2.VideoCapture(str(path))
        frames = []
        try:
            while capture.isOpened():
                ok, frame = capture.read()
                if not ok:
                    break
                frames.append(np.ascontiguousarray(frame[:, :, ::-1]).astype(np.float32) / 255.0)
        finally:
            capture.release()
    if not frames:
        raise DataError(f"cannot decode video (empty, corrupt or not a video): {path}")
    return frames
