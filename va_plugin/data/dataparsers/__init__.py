"""Dataparsers by format name, with detection of the format from the input."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from va_plugin.data.dataparsers.base import DataParserConfig
from va_plugin.data.dataparsers.generators import (
    IMAGE_SUFFIXES,
    SYNCDREAMER_LAYOUT,
    WONDER3D_LAYOUT,
    ZERO123PP_LAYOUT,
    SyncDreamerDataParserConfig,
    Wonder3DDataParserConfig,
    Zero123ppDataParserConfig,
    wonder3d_file,
)
from va_plugin.data.dataparsers.transforms import TransformsDataParserConfig
from va_plugin.data.images import decode_image, undecodable
from va_plugin.data.rigs import RIG_VIEWS, WONDER3D_VIEWS
from va_plugin.errors import DataError


@dataclass(frozen=True)
class DataFormat:
    """A format the dataparsers read: its config, how to recognise it and what it looks like."""

    make_config: Callable[[], DataParserConfig]
    detect: Callable[[Path], bool]
    layout: str


def image_shape(path: Path) -> tuple | None:
    """``(height, width)`` of an image file, or None when ``path`` is not a readable image."""
    if not (path.is_file() and path.suffix.lower() in IMAGE_SUFFIXES):
        return None
    image = decode_image(np.fromfile(str(path), dtype=np.uint8))
    return None if image is None else image.shape[:2]


def _is_transforms(path: Path) -> bool:
    if path.is_dir():
        return any((path / n).is_file() for n in ("transforms.json", "transforms_train.json"))
    return path.is_file() and path.suffix == ".json"


def _is_strip(path: Path) -> bool:
    shape = image_shape(path)
    return shape is not None and shape[1] == RIG_VIEWS * shape[0]


def _is_grid(path: Path) -> bool:
    shape = image_shape(path)
    return shape is not None and shape[0] * 2 == shape[1] * 3 and shape[1] % 2 == 0


def _is_wonder3d(path: Path) -> bool:
    """A folder with Wonder3D's ``rgb_000_<view>`` files (any of them: the parser names the missing views)."""
    if not path.is_dir():
        return False
    views = [v for v, _ in WONDER3D_VIEWS]
    return any(any(wonder3d_file(folder, "rgb", v) for v in views) for folder in (path, path / "masked_colors"))


COMMON_OPTIONS = ("background", "scene_radius", "image_scale")  # carried over from a method's dataparser
FORMATS: dict[str, DataFormat] = {
    "transforms": DataFormat(TransformsDataParserConfig, _is_transforms,
                             "a folder with transforms.json (or transforms_train.json), or that json file"),
    "syncdreamer": DataFormat(SyncDreamerDataParserConfig, _is_strip, SYNCDREAMER_LAYOUT),
    "zero123pp": DataFormat(Zero123ppDataParserConfig, _is_grid, ZERO123PP_LAYOUT),
    "wonder3d": DataFormat(Wonder3DDataParserConfig, _is_wonder3d, WONDER3D_LAYOUT),
}


def format_list() -> str:
    return "; ".join(f"{name}: {fmt.layout}" for name, fmt in FORMATS.items())


def detect_format(path: Path) -> str:
    """The one format that recognises ``path``, or a clear error."""
    if not path.exists():
        raise DataError(f"data not found: {path}")
    matches = [name for name, fmt in FORMATS.items() if fmt.detect(path)]
    if len(matches) == 1:
        return matches[0]
    if not matches:
        if path.is_file() and path.suffix.lower() in IMAGE_SUFFIXES and image_shape(path) is None:
            raise undecodable(path)
        shape = image_shape(path)
        what = f" (a {shape[1]}x{shape[0]} image)" if shape else ""
        raise DataError(f"cannot tell the format of {path}{what}; expected one of these, or name one with "
                        f"--data-format: {format_list()}")
    raise DataError(f"{path} could be any of {', '.join(matches)}; choose one with --data-format")


def resolve_dataparser(path: Path, data_format: str = "auto", base: DataParserConfig | None = None
                       ) -> DataParserConfig:
    """A dataparser config for ``path``, keeping the common options of ``base`` (background, radius...)
    where the method changed them from their defaults."""
    name = detect_format(path) if data_format in ("auto", "", None) else data_format
    if name not in FORMATS:
        raise DataError(f"unknown data format {name!r}; known formats: auto, {', '.join(FORMATS)}")
    if not path.exists():
        raise DataError(f"data not found: {path}")
    config = FORMATS[name].make_config()
    if base is not None:
        defaults = DataParserConfig()
        for key in COMMON_OPTIONS:
            if getattr(base, key) != getattr(defaults, key):
                setattr(config, key, getattr(base, key))
    config.data = path
    return config
