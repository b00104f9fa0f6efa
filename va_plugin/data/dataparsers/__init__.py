"""Dataparsers by format name, with detection of the format from the input."""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Dict, Optional

from va_plugin.data.dataparsers.base import DataParserConfig
from va_plugin.data.dataparsers.transforms import TransformsDataParserConfig
from va_plugin.errors import DataError

# format name -> (config factory, detector)
FORMATS: Dict[str, tuple[Callable[[], DataParserConfig], Callable[[Path], bool]]] = {
    "transforms": (TransformsDataParserConfig,
                   lambda p: (p.is_dir() and any((p / n).is_file() for n in
                                                 ("transforms.json", "transforms_train.json")))
                   or (p.is_file() and p.suffix == ".json")),
}


def detect_format(path: Path) -> str:
    """The one format that recognises ``path``, or a clear error."""
    if not path.exists():
        raise DataError(f"data not found: {path}")
    matches = [name for name, (_, detect) in FORMATS.items() if detect(path)]
    if len(matches) == 1:
        return matches[0]
    if not matches:
        raise DataError(f"cannot tell the format of {path}; use --data-format with one of: {', '.join(FORMATS)}")
    raise DataError(f"{path} could be any of {', '.join(matches)}; choose one with --data-format")


def resolve_dataparser(path: Path, data_format: str = "auto", base: Optional[DataParserConfig] = None
                       ) -> DataParserConfig:
    """A dataparser config for ``path``, keeping the common options of ``base`` (background, radius...)."""
    name = detect_format(path) if data_format in ("auto", "", None) else data_format
    if name not in FORMATS:
        raise DataError(f"unknown data format {name!r}; known formats: {', '.join(FORMATS)}")
    if not path.exists():
        raise DataError(f"data not found: {path}")
    config = FORMATS[name][0]()
    if base is not None:
        for key in ("background", "scene_radius", "image_scale"):
            setattr(config, key, getattr(base, key))
    config.data = path
    return config
