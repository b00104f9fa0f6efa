"""The dataparser of every generator format: a generator's output read as its rig file says
(:mod:`va_plugin.data.rigfile`), with the masks, silhouette check and normalisation shared by all
generator parsers (:mod:`va_plugin.data.dataparsers.generators`).

Every built-in generator (SyncDreamer, Zero123++, Wonder3D, Hunyuan3D-1, MV-Adapter, SV3D, Era3D, CRM,
Wonder3D++, 4-view grids and folders) is a rig file shipped in ``va_plugin/data/rig_files``; a user's rig
file takes the same path. SyncDreamer, Zero123++ and Wonder3D keep their own configs, whose options
(``num_views``, ``elevation_deg``, ``pixel_offset``; ``rig`` the model version; ``ortho_scale``,
``normal_frame``) adjust their rig file's values.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from va_plugin.cameras import Cameras
from va_plugin.data import rigs
from va_plugin.data.dataparsers.generators import (
    GeneratorDataParser,
    GeneratorDataParserConfig,
    image_files,
    read_normal_maps,
    split_grid,
    split_strip,
)
from va_plugin.data.images import VIDEO_SUFFIXES, read_image, read_video
from va_plugin.data.rigfile import (
    NORMAL_FRAMES,
    UP_SIDES,
    RigSpec,
    normal_files,
    resolve_rig,
    rig_cameras,
    shown_name,
    view_files,
)
from va_plugin.errors import ConfigError, DataError

ZERO123PP_VERSIONS = {"v1.1": "zero123pp-v1.1", "v1.2": "zero123pp"}
"""Zero123++ model version (``--rig``) -> its rig file."""


@dataclass
class RiggedDataParserConfig(GeneratorDataParserConfig):
    """Options of a generator output read through a rig (:class:`RigDataParser`)."""

    _target: type = field(default_factory=lambda: RigDataParser)

    def spec(self) -> RigSpec:
        """The rig, with this config's options applied."""
        raise NotImplementedError

    def train_ids(self, count: int) -> list[int]:
        """The views that train (the others are held out)."""
        return list(range(count))


@dataclass
class RigDataParserConfig(RiggedDataParserConfig):
    """A generator output read as a rig file describes it (a built-in generator's, or the user's)."""

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


@dataclass
class SyncDreamerDataParserConfig(RiggedDataParserConfig):
    """A SyncDreamer output: one strip of 16 views on its 30-degree orbit (rig file ``syncdreamer``)."""

    num_views: int = 16
    """Training views, uniform in azimuth from view 0 (4, 8, 12 or 16: all); the others are held out."""
    elevation_deg: float = rigs.RIG_ELEVATION_DEG
    """Elevation of the 16 cameras (SyncDreamer generates at 30 degrees)."""
    pixel_offset: float = 0.5
    """Where pixels are sampled: 0.5 matches the Blender renders SyncDreamer was trained on."""

    def validate(self, prefix: str = "") -> None:
        """The elevation (``--elevation``) strictly between -90 and 90 degrees."""
        super().validate(prefix)
        rigs.check_elevation(self.elevation_deg, f"option {prefix}elevation_deg (--elevation)")
        rigs.input_view_ids(self.num_views)

    def spec(self) -> RigSpec:
        spec = resolve_rig("syncdreamer").with_options(rigs.check_elevation(self.elevation_deg))
        return replace(spec, pixel_offset=self.pixel_offset)

    def train_ids(self, count: int) -> list[int]:
        return rigs.input_view_ids(self.num_views)


@dataclass
class Zero123ppDataParserConfig(RiggedDataParserConfig):
    """A Zero123++ output: a 3 x 2 grid of six views around the input view (rig file ``zero123pp``, or
    ``zero123pp-v1.1``)."""

    rig: str = "v1.2"
    """Model version, which fixes elevations and field of view: v1.1 or v1.2."""
    normalize: str = "silhouettes"
    """Zero123++ leaves the camera radius (hence the object's size) free: fit it from the masks."""

    def validate(self, prefix: str = "") -> None:
        """A known rig (``--rig``)."""
        super().validate(prefix)
        self.spec()

    def spec(self) -> RigSpec:
        if self.rig not in ZERO123PP_VERSIONS:
            raise ConfigError(f"unknown Zero123++ rig {self.rig!r} (--rig); known: {', '.join(ZERO123PP_VERSIONS)}")
        return resolve_rig(ZERO123PP_VERSIONS[self.rig])


@dataclass
class Wonder3DDataParserConfig(RiggedDataParserConfig):
    """A Wonder3D output folder: six orthographic views, RGB and normal maps when present (rig file
    ``wonder3d``)."""

    ortho_scale: float = rigs.WONDER3D_ORTHO_SCALE
    """World units across an image (Wonder3D rendered with 1.35)."""
    normal_frame: str = "front"
    """Camera frame of the normal maps: "front" (what Wonder3D's own reconstruction assumes) or "view"."""
    normalize: str = "silhouettes"
    """Fit the masks' visual hull into the unit box."""

    def validate(self, prefix: str = "") -> None:
        """A known ``normal_frame``."""
        super().validate(prefix)
        if self.normal_frame not in NORMAL_FRAMES:
            raise ConfigError(f"{prefix}normal_frame must be front or view, got {self.normal_frame!r}")

    def spec(self) -> RigSpec:
        if self.normal_frame not in NORMAL_FRAMES:
            raise ConfigError(f"normal_frame must be front or view, got {self.normal_frame!r}")
        return replace(resolve_rig("wonder3d"), ortho_scale=self.ortho_scale, normal_frame=self.normal_frame)


def _square(tile: np.ndarray, where: str, size: int | None) -> None:
    height, width = tile.shape[:2]
    if height != width or (size is not None and height != size):
        want = f"{size}x{size}" if size is not None else "square"
        raise DataError(f"{where} is {width}x{height}; the views must be {want} (all the size of the first)")


class RigDataParser(GeneratorDataParser):
    config: RiggedDataParserConfig

    def __init__(self, config: RiggedDataParserConfig) -> None:
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

    def train_ids(self, count: int) -> list[int]:
        return self.config.train_ids(count)

    def _folder_files(self, folder: Path) -> list[Path]:
        spec = self.spec
        if spec.files:
            pattern, paths = view_files(spec, folder)
            missing = [v for v, p in zip(spec.view_names, paths) if p is None]
            if missing:
                raise DataError(f"{folder} is missing the {spec.name} view file(s) "
                                f"{', '.join(shown_name(pattern, v) for v in missing)}; expected {self.layout}")
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
        paths = normal_files(spec, Path(self.config.data))
        if paths is None:
            return {"rig": spec.name}
        return {"rig": spec.name, **read_normal_maps(paths, cameras, masks, spec.normal_frame, self._turns)}
