"""Dataparsers by format name, with detection of the format from the input.

Formats are ``transforms``, one per built-in rig file (:mod:`va_plugin.data.rigfile`; ``syncdreamer``,
``zero123pp`` and ``wonder3d`` with their own options), ``rig`` (a user's rig file, ``--rig FILE``), and those
other packages register under the ``va_plugin.formats`` entry-point group: a :class:`DataFormat`, a rig
file's content (a dict) or the path of a rig file::

    entry_points={"va_plugin.formats": ["my-gen = my_package.formats:my_gen_rig"]}

Detection scores each format on the input: 0 no, 1 its layout, 2 its layout at the generator's own size,
3 that and the generator's own file name. The best score wins; a tie is one line naming the candidates.
"""

from __future__ import annotations

import fnmatch
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

from va_plugin.data.dataparsers.base import DataParserConfig
from va_plugin.data.dataparsers.generators import IMAGE_SUFFIXES, image_files
from va_plugin.data.dataparsers.rigged import (
    RigDataParserConfig,
    SyncDreamerDataParserConfig,
    Wonder3DDataParserConfig,
    Zero123ppDataParserConfig,
)
from va_plugin.data.dataparsers.transforms import TransformsDataParserConfig
from va_plugin.data.images import VIDEO_SUFFIXES, decode_image, undecodable
from va_plugin.data.rigfile import RigSpec, builtin_rigs, find_file, read_rig_file, rig_from_dict
from va_plugin.errors import ConfigError, DataError

FORMAT_ENTRY_POINTS = "va_plugin.formats"


@dataclass(frozen=True)
class DataFormat:
    """A format the dataparsers read: its config, how to recognise it and what it looks like. ``detect``
    returns a score (or a bool): 0 no, 1 the layout, 2 the layout at the generator's size, 3 and its name."""

    make_config: Callable[[], DataParserConfig]
    detect: Callable[[Path], int | bool]
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


def _name_score(spec: RigSpec, path: Path) -> int:
    """1 when the file name is one the generator writes, 0 otherwise."""
    return int(any(fnmatch.fnmatch(path.name.lower(), pattern.lower()) for pattern in spec.names))


def _size_score(spec: RigSpec, tile: int) -> int:
    """2 when the views have the generator's own size, 1 when the rig fixes no size or detects any size,
    0 otherwise."""
    if not spec.tile_sizes:
        return 1
    return 2 if tile in spec.tile_sizes else int(spec.any_size)


def _image_tile(spec: RigSpec, shape: tuple) -> int | None:
    """The tile size of an image ``(height, width)`` in the rig's grid or strip layout, None if it is not."""
    height, width = shape
    rows, columns = (spec.rows, spec.columns) if spec.layout == "grid" else (1, spec.count)
    if height % rows or width % columns or height // rows != width // columns or height == 0:
        return None
    return height // rows


def rig_score(spec: RigSpec, path: Path) -> int:
    """How well ``path`` looks like the rig's layout (see the module docstring); 0 for rigs not detected."""
    if not spec.detect:
        return 0
    if spec.layout in ("grid", "strip") or (spec.layout == "video" and path.is_file()):
        if spec.layout == "video":
            if path.suffix.lower() not in VIDEO_SUFFIXES:
                return 0
            score = 1 + (path.suffix.lower() == ".mp4")
        else:
            shape = image_shape(path)
            tile = None if shape is None else _image_tile(spec, shape)
            if tile is None:
                return 0
            score = _size_score(spec, tile)
        named = _name_score(spec, path)
        if score == 0 or (spec.require_name and not named):
            return 0
        return score + named
    if not path.is_dir():
        return 0
    if spec.files:  # one view's file is enough: the parser names the missing ones
        return int(any(find_file(path, pattern, view) for pattern in spec.files for view in spec.view_names))
    return 1 if len(image_files(path)) == spec.count else 0


def _rig_format(spec: RigSpec, rig: str, make_config: Callable[[], DataParserConfig] | None = None) -> DataFormat:
    return DataFormat(make_config or (lambda: RigDataParserConfig(rig=rig)), lambda path: rig_score(spec, path),
                      spec.layout_text())


def _plugin_format(name: str, value) -> DataFormat:
    """A format an entry point gives: a DataFormat, a rig file's content or a rig file's path."""
    if isinstance(value, DataFormat):
        return value
    if isinstance(value, Mapping):
        spec = rig_from_dict(dict(value, name=value.get("name", name)), where=f"format {name!r}")
    elif isinstance(value, (str, Path)):
        spec = read_rig_file(value)
    else:
        raise ConfigError(f"entry point {name!r} of {FORMAT_ENTRY_POINTS} is a {type(value).__name__}, not a "
                          "DataFormat, rig dict or rig file path")
    return _rig_format(spec, spec if isinstance(value, Mapping) else str(value))


def plugin_formats() -> dict[str, DataFormat]:
    """The formats other packages register; one that fails to load is skipped with a warning."""
    found = {}
    for entry_point in metadata.entry_points(group=FORMAT_ENTRY_POINTS):
        try:
            found[entry_point.name] = _plugin_format(entry_point.name, entry_point.load())
        except Exception as exc:  # a broken plugin must not stop the built-in formats
            warnings.warn(f"format {entry_point.name!r} of {FORMAT_ENTRY_POINTS} not loaded: {exc}", stacklevel=2)
    return found


COMMON_OPTIONS = ("background", "scene_radius", "image_scale")  # carried over from a method's dataparser
RIG_FILE_FORMAT = "rig"
OWN_CONFIGS: dict[str, Callable[[], DataParserConfig]] = {
    "syncdreamer": SyncDreamerDataParserConfig, "zero123pp": Zero123ppDataParserConfig,
    "wonder3d": Wonder3DDataParserConfig}
"""Built-in rigs read with their own options (``--views``, ``--elevation``; ``--rig`` v1.1 or v1.2; ...)."""
FORMATS: dict[str, DataFormat] = {
    "transforms": DataFormat(TransformsDataParserConfig, _is_transforms,
                             "a folder with transforms.json (or transforms_train.json), or that json file"),
    **{name: _rig_format(builtin_rigs()[name], name, make) for name, make in OWN_CONFIGS.items()},
    **{name: _rig_format(spec, name) for name, spec in builtin_rigs().items() if name not in OWN_CONFIGS},
    RIG_FILE_FORMAT: DataFormat(RigDataParserConfig, lambda path: False, "any layout, as a rig file (--rig FILE) says"),
}
FORMATS.update({name: fmt for name, fmt in plugin_formats().items() if name not in FORMATS})


def counted_folder(spec: RigSpec) -> bool:
    """Whether the rig recognises a folder only by how many images it holds (a 4-view folder, SV3D frames)."""
    return spec.layout in ("folder", "video") and not spec.files


def is_input_folder(path: Path) -> bool:
    """Whether a folder is one input as a whole (a scene folder, a Wonder3D or Era3D output), not a folder of
    inputs: folders a rig recognises only by their image count do not count (four SyncDreamer strips are
    four inputs)."""
    counted = {name for name, spec in builtin_rigs().items() if counted_folder(spec)}
    return path.is_dir() and any(fmt.detect(path) for name, fmt in FORMATS.items() if name not in counted)


def format_list() -> str:
    return "; ".join(f"{name}: {fmt.layout}" for name, fmt in FORMATS.items() if name != RIG_FILE_FORMAT)


def detect_format(path: Path) -> str:
    """The one format that recognises ``path`` best, or a clear error."""
    if not path.exists():
        raise DataError(f"data not found: {path}")
    scores = {name: int(fmt.detect(path)) for name, fmt in FORMATS.items()}
    best = max(scores.values())
    matches = [name for name, score in scores.items() if score == best and best > 0]
    if len(matches) == 1:
        return matches[0]
    if not matches:
        if path.is_file() and path.suffix.lower() in IMAGE_SUFFIXES and image_shape(path) is None:
            raise undecodable(path)
        shape = image_shape(path)
        what = f" (a {shape[1]}x{shape[0]} image)" if shape else ""
        raise DataError(f"cannot tell the format of {path}{what}; name one with --data-format (or describe it "
                        f"with --rig FILE): {format_list()}")
    raise DataError(f"{path} could be any of {', '.join(matches)}; choose one with --data-format")


def resolve_dataparser(path: Path, data_format: str = "auto", base: DataParserConfig | None = None,
                       rig_file: str | Path | None = None) -> DataParserConfig:
    """A dataparser config for ``path``, keeping the common options of ``base`` (background, radius...)
    where the method changed them from their defaults. ``rig_file``: read the input as that rig file
    says (format ``rig`` unless ``data_format`` names another rig format)."""
    if rig_file is not None and data_format in ("auto", "", None):
        data_format = RIG_FILE_FORMAT
    name = detect_format(path) if data_format in ("auto", "", None) else data_format
    if name not in FORMATS:
        raise DataError(f"unknown data format {name!r}; known formats: auto, {', '.join(FORMATS)}")
    if not path.exists():
        raise DataError(f"data not found: {path}")
    config = FORMATS[name].make_config()
    if rig_file is not None:
        if not isinstance(config, RigDataParserConfig):
            raise DataError(f"--rig FILE describes the input's layout itself; it does not go with --data-format "
                            f"{name}")
        config.rig = str(rig_file)
    if base is not None:
        defaults = DataParserConfig()
        for key in COMMON_OPTIONS:
            if getattr(base, key) != getattr(defaults, key):
                setattr(config, key, getattr(base, key))
    config.data = path
    return config
