"""The dataparser of every rig-file format: a generator's output read as its rig file says
(:mod:`va_plugin.data.rigfile`), with the masks, silhouette check and normalisation shared by all
generator parsers (:mod:`va_plugin.data.dataparsers.generators`).

The built-in generators (Hunyuan3D-1, MV-Adapter, SV3D, Era3D, CRM, Wonder3D++, 4-view grids and folders)
are rig files shipped in ``va_plugin/data/rig_files``; a user's rig file takes the same path.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from va_plugin.cameras import Cameras
from va_plugin.data.dataparsers.generators import (
    GeneratorDataParser,
    GeneratorDataParserConfig,
    image_files,
    read_normal_maps,
    split_grid,
    split_strip,
)
from va_plugin.data.images import VIDEO_SUFFIXES, read_image, read_video
from va_plugin.data.rigfile import UP_SIDES, RigSpec, resolve_rig, rig_cameras
from va_plugin.errors import ConfigError, DataError


@dataclass
class RigDataParserConfig(GeneratorDataParserConfig):
    """A generator output read as a rig file describes it (a built-in generator's, or the user's)."""

    _target: type = field(default_factory=lambda: RigDataParser)
    rig: str = ""
    """The rig: a built-in generator's name (hunyuan3d-std, sv3d, ...) or a rig file (.json, .yaml)."""
    elevation_deg: float | None = None
    """Elevation of every view in degrees (--elevation), instead of the rig's (rigs with one elevation)."""
    fov_deg: float | None = None
    """Field of view in degrees across a view (--fov), instead of the rig's (perspective rigs)."""
    normalize: str = "silhouettes"
    """Generators leave the object's size free: fit the masks' visual hull into the unit box."""

    def validate(self, prefix: str = "") -> None:
        """A rig that reads, and options it can take."""
        super().validate(prefix)
        if not self.rig:
            raise ConfigError(f"{prefix}rig is empty: name a generator's rig or a rig file (--rig)")
        self.spec()

    def spec(self) -> RigSpec:
        """The rig with ``elevation_deg`` and ``fov_deg`` applied."""
        return resolve_rig(self.rig).with_options(self.elevation_deg, self.fov_deg)


def _square(tile: np.ndarray, where: str, size: int | None) -> None:
    height, width = tile.shape[:2]
    if height != width or (size is not None and height != size):
        want = f"{size}x{size}" if size is not None else "square"
        raise DataError(f"{where} is {width}x{height}; the views must be {want} (all the size of the first)")


class RigDataParser(GeneratorDataParser):
    config: RigDataParserConfig

    def __init__(self, config: RigDataParserConfig) -> None:
        super().__init__(config)
        self.spec = config.spec()
        self.format_name = self.spec.name
        self.layout = self.spec.layout_text()
        self._turns = UP_SIDES[self.spec.up]

    def view_names(self) -> Sequence[str] | None:
        return self.spec.view_names or None

    def split_image(self, image: np.ndarray, where: str) -> list[np.ndarray]:
        spec = self.spec
        if spec.layout == "grid":
            tiles = split_grid(image, spec.rows, spec.columns, where, f"{spec.name}: {self.layout}")
        elif spec.layout == "strip":
            tiles = split_strip(image, spec.count, where, f"{spec.name}: {self.layout}")
        else:
            return super().split_image(image, where)
        return [self._upright(t) for t in tiles]

    def _upright(self, tile: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(np.rot90(tile, self._turns)) if self._turns else tile

    def _folder_files(self, folder: Path) -> list[Path]:
        spec = self.spec
        if spec.files:
            paths = [folder / spec.files.format(view=v) for v in spec.view_names]
            missing = [v for v, p in zip(spec.view_names, paths) if not p.is_file()]
            if missing:
                raise DataError(f"{folder} is missing the {spec.name} view file(s) "
                                f"{', '.join(spec.files.format(view=v) for v in missing)}; expected {self.layout}")
            return paths
        paths = image_files(folder)
        if len(paths) != spec.count:
            what = "frames" if spec.layout == "video" else "view images"
            raise DataError(f"{folder} holds {len(paths)} images; {spec.name} needs {spec.count} {what} "
                            f"({self.layout})")
        return paths

    def read_tiles(self):
        spec, path = self.spec, Path(self.config.data)
        if not path.exists():
            raise DataError(f"data not found: {path}")
        if spec.layout in ("grid", "strip"):
            if not path.is_file():
                raise DataError(f"a {spec.name} input is {self.layout}; {path} is not a file")
            tiles = self.split_image(read_image(path), str(path))
            return tiles, [f"{path.name} view {k}" for k in range(len(tiles))], [path] * len(tiles)
        if spec.layout == "video" and path.is_file():
            if path.suffix.lower() not in VIDEO_SUFFIXES:
                raise DataError(f"a {spec.name} input is {self.layout}; {path} is not a video")
            frames = read_video(path)
            if len(frames) != spec.count:
                raise DataError(f"{path} holds {len(frames)} frames; {spec.name} writes {spec.count}")
            tiles = [self._upright(f) for f in frames]
            names, paths = [f"{path.name} frame {k}" for k in range(len(tiles))], [path] * len(tiles)
        else:
            if not path.is_dir():
                raise DataError(f"a {spec.name} input is {self.layout}; {path} is not a folder")
            paths = self._folder_files(path)
            tiles = [self._upright(read_image(p)) for p in paths]
            names = [str(p) for p in paths]
        size = tiles[0].shape[0]
        for tile, name in zip(tiles, names):
            _square(tile, name, size)
        return tiles, names, paths

    def rig(self, tile_size: int) -> Cameras:
        return rig_cameras(self.spec, tile_size)

    def extra_metadata(self, cameras: Cameras, masks: np.ndarray) -> dict[str, Any]:
        """World-space normal maps when the rig names them and the folder has every one."""
        spec = self.spec
        if not spec.normals:
            return {"rig": spec.name}
        paths = [Path(self.config.data) / spec.normals.format(view=v) for v in spec.view_names]
        if not all(p.is_file() for p in paths):
            return {"rig": spec.name}
        return {"rig": spec.name, **read_normal_maps(paths, cameras, masks, spec.normal_frame, self._turns)}
