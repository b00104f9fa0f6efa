"""Rig files: a declarative description of how a multi-view generator lays out its views and where its
cameras are.

A rig file is a small JSON (or YAML) object. The generators this package knows are described by the files
in ``va_plugin/data/rig_files/`` in exactly this form, and a user's file goes through the same code::

    {
      "name": "my-generator",
      "source": "where the values come from (a file of the generator's code)",
      "layout": {"type": "grid", "rows": 2, "columns": 2},
      "views": {"azimuths": [0, 90, 180, 270], "elevation": 10},
      "camera": {"type": "perspective", "fov_deg": 40, "distance": 2.0},
      "background": "white",
      "up": "top"
    }

* ``layout.type``: ``grid`` (``rows`` x ``columns`` square tiles in one image, read row by row), ``strip``
  (``count`` square tiles side by side), ``folder`` (one image per view; ``files`` is a file name pattern,
  or a list of them, with ``{view}``, the view's name, or omitted for the folder's images sorted by name),
  or ``video`` (an MP4 of ``count`` square frames, or a folder of ``count`` frame images sorted by name).
  Optional: ``normals`` (a pattern of normal maps, encoded ``(n + 1) / 2`` in OpenGL camera axes),
  ``normal_frame`` (``front``: the first view's camera; ``view``: each view's own), ``tile_sizes`` and
  ``names`` (file name patterns) used by format detection, ``any_size`` (detect views of other sizes than
  ``tile_sizes`` too, below those) and ``require_name`` (detect only when the name matches).
* File patterns (``files``, ``normals``): ``{view}`` is the view's name, ``_{index}`` an optional
  ``_`` and number (``rgb_{index}_{view}`` matches ``rgb_000_front`` and ``rgb_front``), a pattern without
  an extension matches any image extension, and a pattern may name a subfolder (``masked_colors/...``).
  With a list, the first pattern under which every view has a file is read; when none has them all, the
  last one's missing files are named.
* ``views``: in file order (tile, frame or ``names`` order). ``azimuths`` in degrees (a list, or ``{"start":
  a, "step": s}``), ``elevation`` one number for every view or ``elevations`` a list; optional ``names``
  (required by a ``{view}`` folder pattern), ``azimuth_direction`` (``counterclockwise`` seen from above,
  the default, or ``clockwise``).
* ``camera.type``: ``perspective`` with ``fov_deg`` (the full angle across a square view) or ``focal``
  (the focal length in view widths, as generators that state ``K`` give it: 280 px at 256 px is 1.09375),
  or ``orthographic`` with ``scale`` (world units across a view); ``distance`` from the centre (default
  2); ``pixel_offset``, where a pixel is sampled (default 0.5: pixel centres, as Blender renders).
* ``background``: what the generator paints behind the object: ``white``, ``grey``, ``black``, ``rgba``
  (transparent) or ``[r, g, b]`` in [0, 1]; views without alpha are keyed out by their border's colour
  whatever it says, the benchmark scene builder paints it.
* ``up``: the side of each view the object's top faces: ``top`` (default), ``bottom``, ``left`` or ``right``
  (views are turned upright on reading).

World frame (as in :mod:`va_plugin.data.rigs`): z up, the generator's input view at azimuth 0 on +x,
azimuth counter-clockwise seen from above. A camera at elevation +-90 deg (a top or bottom view) keeps
image-up along the direction of growing elevation, which for other views is the world's up.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from functools import cache
from pathlib import Path
from typing import Any

import torch

from va_plugin.cameras import ORTHOGRAPHIC, PERSPECTIVE, Cameras, look_at
from va_plugin.errors import DataError

RIG_FILE_DIR = Path(__file__).resolve().parent / "rig_files"
RIG_SUFFIXES = (".json", ".yaml", ".yml")
LAYOUTS = ("grid", "strip", "folder", "video")
BACKGROUNDS = {"white": (1.0, 1.0, 1.0), "grey": (0.5, 0.5, 0.5), "gray": (0.5, 0.5, 0.5),
               "black": (0.0, 0.0, 0.0), "rgba": None}
UP_SIDES = {"top": 0, "right": 1, "bottom": 2, "left": 3}
"""The side of a view the object's top faces -> quarter turns (counter-clockwise) that make it upright."""
NORMAL_FRAMES = ("front", "view")
DIRECTIONS = ("counterclockwise", "clockwise")
MAX_FOV_DEG = 170.0
DEFAULT_DISTANCE = 2.0
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".webp", ".bmp")
EXAMPLE_INDEX = "000"  # what ``{index}`` is in file names we show or write


@dataclass(frozen=True)
class RigSpec:
    """A rig file, read and checked."""

    name: str
    layout: str
    count: int  # views
    azimuths: tuple[float, ...]  # degrees, file order, counter-clockwise from above
    elevations: tuple[float, ...]
    camera_type: str
    fov_deg: float | None  # perspective
    ortho_scale: float | None  # orthographic: world units across a view
    distance: float
    rows: int = 1
    columns: int = 1
    files: tuple[str, ...] = ()  # folder patterns with {view}, tried in order
    normals: str | None = None
    normal_frame: str = "front"
    view_names: tuple[str, ...] = ()
    tile_sizes: tuple[int, ...] = ()
    any_size: bool = False  # detected at other sizes than tile_sizes too
    names: tuple[str, ...] = ()
    require_name: bool = False
    detect: bool = True
    background: tuple[float, float, float] | None = (1.0, 1.0, 1.0)  # None: RGBA
    up: str = "top"
    source: str = ""
    description: str = ""
    elevation_shared: bool = True  # one elevation for every view (--elevation may replace it)
    origin: str = ""  # the file it was read from
    focal: float | None = None  # perspective: focal length in view widths, when the file gives it (else fov_deg)
    pixel_offset: float = 0.5

    def layout_text(self) -> str:
        """One phrase saying what the generator writes (for messages and format listings)."""
        sizes = f" of {' or '.join(str(s) for s in self.tile_sizes)} px" if self.tile_sizes else ""
        if len(self.tile_sizes) == 1 and self.layout in ("grid", "strip"):
            columns, rows = (self.columns, self.rows) if self.layout == "grid" else (self.count, 1)
            sizes += f" ({columns * self.tile_sizes[0]} wide x {rows * self.tile_sizes[0]} high)"
        if self.layout == "grid":
            return (f"one image of {self.rows} rows x {self.columns} columns of square views{sizes}"
                    + (f", named like {self.names[0]}" if self.require_name and self.names else ""))
        if self.layout == "strip":
            return f"one image of {self.count} square views{sizes} side by side"
        if self.layout == "video":
            return f"an MP4 of {self.count} square frames{sizes}, or a folder of its {self.count} frames"
        if self.files:
            *others, main = self.files
            optional = [shown_name(p) for p in (*others, *([self.normals] if self.normals else []))]
            return (f"a folder with {shown_name(main)} for the views {', '.join(self.view_names)}"
                    + (f" (optionally {' and '.join(optional)})" if optional else ""))
        return f"a folder of {self.count} square view images, in view order when sorted by name"

    def with_options(self, elevation_deg: float | None = None, fov_deg: float | None = None) -> RigSpec:
        """This rig with the elevation of every view and/or the field of view replaced; a clear error
        where the rig has no such thing to replace."""
        changes: dict[str, Any] = {}
        if elevation_deg is not None:
            if not self.elevation_shared:
                raise DataError(f"rig {self.name} gives each view its own elevation, so --elevation cannot set "
                                "one for all; write a rig file instead (docs/data.md)")
            changes["elevations"] = (_elevation(elevation_deg, "--elevation"),) * self.count
        if fov_deg is not None:
            if self.camera_type != PERSPECTIVE:
                raise DataError(f"rig {self.name} is orthographic; --fov applies to perspective rigs only")
            changes["fov_deg"] = _fov(fov_deg, "--fov")
            changes["focal"] = None
        return replace(self, **changes) if changes else self


# -- file patterns ------------------------------------------------------------------------------------
def shown_name(pattern: str, view: str = "<view>") -> str:
    """A file name of ``pattern`` as a generator writes it (``{index}`` as 000, ``.png`` when it names no
    extension), for messages and for writing a generator's layout."""
    name = pattern.replace("{index}", EXAMPLE_INDEX).replace("{view}", view)
    return name if Path(pattern).suffix else name + ".png"


def _pattern_regex(name: str, view: str) -> re.Pattern:
    """The regular expression of a pattern's file name for one view (see the module docstring)."""
    parts = re.split(r"(_\{index\}|\{index\}|\{view\})", name)
    tokens = {"_{index}": r"(?:_\d+)?", "{index}": r"\d*", "{view}": re.escape(view)}
    body = "".join(tokens.get(part, re.escape(part)) for part in parts)
    if Path(name).suffix:
        return re.compile(body)
    return re.compile(body + "(?i:" + "|".join(re.escape(s) for s in IMAGE_SUFFIXES) + ")")


def find_file(folder: Path, pattern: str, view: str) -> Path | None:
    """The first image file (by name) in ``folder`` that ``pattern`` names for ``view``, or None."""
    where = folder / Path(pattern).parent
    if not where.is_dir():
        return None
    regex = _pattern_regex(Path(pattern).name, view)
    for path in sorted(where.iterdir()):
        if path.is_file() and path.suffix.lower() in IMAGE_SUFFIXES and regex.fullmatch(path.name):
            return path
    return None


def view_files(spec: RigSpec, folder: Path) -> tuple[str, list[Path | None]]:
    """The files of every view in ``folder`` under the first of the rig's patterns that finds them all,
    else under its last one (None where missing), with that pattern."""
    found: list[Path | None] = []
    for pattern in spec.files:
        found = [find_file(folder, pattern, view) for view in spec.view_names]
        if all(found):
            return pattern, found
    return spec.files[-1], found


def normal_files(spec: RigSpec, folder: Path) -> list[Path] | None:
    """The normal maps of every view in ``folder``, or None when the rig names none or any is missing."""
    if not spec.normals:
        return None
    found = [find_file(folder, spec.normals, view) for view in spec.view_names]
    return found if all(found) else None


# -- reading ------------------------------------------------------------------------------------------
def _elevation(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not -90.0 <= value <= 90.0:
        raise DataError(f"{where}: an elevation must be a number from -90 to 90 degrees, got {value!r}")
    return float(value)


def _fov(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 < value < MAX_FOV_DEG:
        raise DataError(f"{where}: the field of view must be a number between 0 and {MAX_FOV_DEG:g} degrees, "
                        f"got {value!r}")
    return float(value)


def _number(value: Any, where: str, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or \
            (positive and value <= 0):
        raise DataError(f"{where} must be a {'positive ' if positive else ''}number, got {value!r}")
    return float(value)


def _count(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise DataError(f"{where} must be a whole number of at least 1, got {value!r}")
    return value


class _Fields:
    """A JSON object whose keys are checked: missing ones and unknown ones give one clear line."""

    def __init__(self, data: Any, where: str, known: Sequence[str]) -> None:
        if not isinstance(data, Mapping):
            raise DataError(f"{where} must be an object (a JSON {{...}}), got {type(data).__name__}")
        unknown = sorted(set(data) - set(known))
        if unknown:
            raise DataError(f"{where} has unknown field(s) {', '.join(unknown)}; known: {', '.join(known)}")
        self.data, self.where = data, where

    def required(self, key: str) -> Any:
        if key not in self.data:
            raise DataError(f"{self.where} is missing the field {key!r}")
        return self.data[key]

    def get(self, key: str, default: Any = None) -> Any:
        return self.data.get(key, default)

    def at(self, key: str) -> str:
        return f"{self.where}.{key}"


def _background(value: Any, where: str) -> tuple[float, float, float] | None:
    if isinstance(value, str) and value.lower() in BACKGROUNDS:
        return BACKGROUNDS[value.lower()]
    if isinstance(value, (list, tuple)) and len(value) == 3 and \
            all(not isinstance(v, bool) and isinstance(v, (int, float)) and 0 <= v <= 1 for v in value):
        return tuple(float(v) for v in value)
    raise DataError(f"{where} must be white, grey, black, rgba or [r, g, b] in [0, 1], got {value!r}")


def _strings(value: Any, where: str) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) and v for v in value):
        raise DataError(f"{where} must be a list of names, got {value!r}")
    return tuple(value)


def _azimuths(value: Any, count: int, where: str) -> tuple[float, ...]:
    if isinstance(value, Mapping):
        step = _Fields(value, where, ("start", "step"))
        start = _number(step.required("start"), step.at("start"))
        delta = _number(step.required("step"), step.at("step"))
        return tuple((start + k * delta) % 360.0 for k in range(count))
    if not isinstance(value, (list, tuple)):
        raise DataError(f"{where} must be a list of degrees or {{\"start\": a, \"step\": s}}, got {value!r}")
    if len(value) != count:
        raise DataError(f"{where} lists {len(value)} azimuths but the layout holds {count} views")
    return tuple(_number(v, where) for v in value)


def rig_from_dict(data: Any, where: str = "rig file", origin: str = "") -> RigSpec:
    """A :class:`RigSpec` from a rig file's content; DataError (one line) for a missing, unknown or
    contradictory field."""
    top = _Fields(data, where, ("name", "description", "source", "layout", "views", "camera", "background",
                                "up", "detect"))
    name = top.get("name", Path(origin).stem if origin else "rig")
    if not isinstance(name, str) or not name:
        raise DataError(f"{where}: 'name' must be a non-empty string")
    layout = _Fields(top.required("layout"), top.at("layout"),
                     ("type", "rows", "columns", "count", "files", "normals", "normal_frame", "tile_sizes",
                      "any_size", "names", "require_name"))
    kind = layout.required("type")
    if kind not in LAYOUTS:
        raise DataError(f"{layout.at('type')} must be one of {', '.join(LAYOUTS)}, got {kind!r}")
    views = _Fields(top.required("views"), top.at("views"),
                    ("azimuths", "elevation", "elevations", "names", "azimuth_direction"))
    view_names = _strings(views.get("names", []), views.at("names")) if "names" in views.data else ()
    rows = columns = 1
    if kind == "grid":
        rows, columns = _count(layout.required("rows"), layout.at("rows")), \
            _count(layout.required("columns"), layout.at("columns"))
        count = rows * columns
        if "count" in layout.data and layout.get("count") != count:
            raise DataError(f"{layout.at('count')} is {layout.get('count')!r} but rows x columns is {count}")
    elif kind in ("strip", "video"):
        count = _count(layout.required("count"), layout.at("count"))
    else:
        count = len(view_names) if view_names else _count(layout.required("count"), layout.at("count"))
        if view_names and "count" in layout.data and layout.get("count") != count:
            raise DataError(f"{layout.at('count')} is {layout.get('count')!r} but views.names lists {count} views")
    files = layout.get("files")
    files = () if files is None else tuple(files) if isinstance(files, list) and files else (files,)
    normals = layout.get("normals")
    for key, patterns in (("files", files), ("normals", (normals,) if normals is not None else ())):
        for pattern in patterns:
            if kind != "folder":
                raise DataError(f"{layout.at(key)} applies to a folder layout only, not {kind}")
            if not isinstance(pattern, str) or "{view}" not in pattern:
                raise DataError(f"{layout.at(key)} must be a file name pattern with {{view}} (or, for files, a "
                                f"list of them), got {pattern!r}")
            if not view_names:
                raise DataError(f"{layout.at(key)} names files by view, so views.names must list the views")
    if view_names and len(view_names) != count:
        raise DataError(f"{views.at('names')} lists {len(view_names)} views but the layout holds {count}")
    normal_frame = layout.get("normal_frame", "front")
    if normal_frame not in NORMAL_FRAMES:
        raise DataError(f"{layout.at('normal_frame')} must be front or view, got {normal_frame!r}")
    tile_sizes = tuple(int(_count(s, layout.at("tile_sizes"))) for s in layout.get("tile_sizes", []))
    names = _strings(layout.get("names", []), layout.at("names")) if "names" in layout.data else ()
    require_name = layout.get("require_name", False)
    if not isinstance(require_name, bool) or (require_name and not names):
        raise DataError(f"{layout.at('require_name')} must be true or false, and true needs layout.names")
    any_size = layout.get("any_size", False)
    if not isinstance(any_size, bool) or (any_size and not tile_sizes):
        raise DataError(f"{layout.at('any_size')} must be true or false, and true needs layout.tile_sizes")

    azimuths = _azimuths(views.required("azimuths"), count, views.at("azimuths"))
    direction = views.get("azimuth_direction", "counterclockwise")
    if direction not in DIRECTIONS:
        raise DataError(f"{views.at('azimuth_direction')} must be counterclockwise or clockwise, got {direction!r}")
    if direction == "clockwise":
        azimuths = tuple((-a) % 360.0 for a in azimuths)
    if "elevation" in views.data and "elevations" in views.data:
        raise DataError(f"{where}: views has both 'elevation' and 'elevations'; give one")
    if "elevations" in views.data:
        values = views.get("elevations")
        if not isinstance(values, (list, tuple)) or len(values) != count:
            raise DataError(f"{views.at('elevations')} must list {count} elevations, one per view, got {values!r}")
        elevations = tuple(_elevation(v, views.at("elevations")) for v in values)
        shared = len(set(elevations)) == 1
    else:
        elevations = (_elevation(views.required("elevation"), views.at("elevation")),) * count
        shared = True

    camera = _Fields(top.required("camera"), top.at("camera"),
                     ("type", "fov_deg", "focal", "scale", "distance", "pixel_offset"))
    camera_type = camera.required("type")
    fov = scale = focal = None
    if camera_type == PERSPECTIVE:
        if "scale" in camera.data:
            raise DataError(f"{top.at('camera')} is perspective but gives an orthographic 'scale'; give fov_deg")
        if "focal" in camera.data:
            if "fov_deg" in camera.data:
                raise DataError(f"{top.at('camera')} gives both 'fov_deg' and 'focal'; give one")
            focal = _number(camera.get("focal"), camera.at("focal"), positive=True)
            fov = _fov(math.degrees(2.0 * math.atan(0.5 / focal)), camera.at("focal"))
        else:
            fov = _fov(camera.required("fov_deg"), camera.at("fov_deg"))
    elif camera_type == ORTHOGRAPHIC:
        if "fov_deg" in camera.data or "focal" in camera.data:
            raise DataError(f"{top.at('camera')} is orthographic but gives a 'fov_deg' or 'focal'; give scale")
        scale = _number(camera.required("scale"), camera.at("scale"), positive=True)
    else:
        raise DataError(f"{camera.at('type')} must be perspective or orthographic, got {camera_type!r}")
    distance = _number(camera.get("distance", DEFAULT_DISTANCE), camera.at("distance"), positive=True)
    pixel_offset = _number(camera.get("pixel_offset", 0.5), camera.at("pixel_offset"))
    if not 0.0 <= pixel_offset <= 1.0:
        raise DataError(f"{camera.at('pixel_offset')} must be from 0 to 1, got {pixel_offset}")
    if camera_type == PERSPECTIVE and distance <= 1.0:
        raise DataError(f"{camera.at('distance')} must be more than 1 (the object's bounding sphere), got {distance}")
    up = top.get("up", "top")
    if up not in UP_SIDES:
        raise DataError(f"{top.at('up')} must be one of {', '.join(UP_SIDES)}, got {up!r}")
    detect = top.get("detect", True)
    if not isinstance(detect, bool):
        raise DataError(f"{top.at('detect')} must be true or false, got {detect!r}")
    for key in ("description", "source"):
        if not isinstance(top.get(key, ""), str):
            raise DataError(f"{top.at(key)} must be a string")
    return RigSpec(
        name=name, layout=kind, count=count, azimuths=azimuths, elevations=elevations, camera_type=camera_type,
        fov_deg=fov, ortho_scale=scale, distance=distance, rows=rows, columns=columns, files=files,
        normals=normals, normal_frame=normal_frame, view_names=view_names, tile_sizes=tile_sizes,
        any_size=any_size, names=names,
        require_name=require_name, detect=detect, background=_background(top.get("background", "white"),
                                                                             top.at("background")),
        up=up, source=top.get("source", ""), description=top.get("description", ""), elevation_shared=shared,
        origin=origin, focal=focal, pixel_offset=pixel_offset)


def read_rig_file(path: str | Path) -> RigSpec:
    """A rig file (``.json``, ``.yaml`` or ``.yml``) read and checked."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"rig file not found: {path}")
    if path.suffix.lower() not in RIG_SUFFIXES:
        raise DataError(f"rig file {path} must be .json, .yaml or .yml")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise DataError(f"rig file {path} is not a text file") from None
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DataError(f"rig file {path} is not valid JSON ({exc.msg} at line {exc.lineno})") from None
    else:
        try:
            import yaml
        except ImportError:
            raise DataError(f"rig file {path}: reading YAML needs PyYAML (pip install pyyaml); or write it "
                            "as JSON") from None
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise DataError(f"rig file {path} is not valid YAML ({str(exc).splitlines()[0]})") from None
    return rig_from_dict(data, where=f"rig file {path}", origin=str(path))


@cache
def builtin_rigs() -> dict[str, RigSpec]:
    """The rigs of the generators this package knows, read from ``rig_files/`` like any user's file."""
    return {spec.name: spec for spec in (read_rig_file(p) for p in sorted(RIG_FILE_DIR.glob("*.json")))}


def is_rig_file(value: str | Path) -> bool:
    """Whether ``value`` names a rig file (by its suffix) rather than a rig or version name."""
    return Path(str(value)).suffix.lower() in RIG_SUFFIXES


def resolve_rig(value: str | Path | RigSpec) -> RigSpec:
    """A rig by built-in name, or read from a rig file."""
    if isinstance(value, RigSpec):
        return value
    rigs = builtin_rigs()
    if str(value) in rigs:
        return rigs[str(value)]
    if is_rig_file(value) or Path(str(value)).is_file():
        return read_rig_file(value)
    raise DataError(f"unknown rig {str(value)!r}: give a rig file (.json, .yaml) or one of {', '.join(rigs)}")


# -- cameras ------------------------------------------------------------------------------------------
def orbit_c2w(azimuths_deg: Sequence[float], elevations_deg: Sequence[float], distance: float) -> torch.Tensor:
    """OpenCV camera-to-world ``[n, 3, 4]`` of cameras on a z-up sphere looking at the origin, image-up the
    world's up; for top and bottom views (elevation +-90) the direction of growing elevation."""
    az = torch.tensor([math.radians(a) for a in azimuths_deg], dtype=torch.float64)
    el = torch.tensor([math.radians(e) for e in elevations_deg], dtype=torch.float64)
    eyes = distance * torch.stack([torch.cos(el) * torch.cos(az), torch.cos(el) * torch.sin(az), torch.sin(el)], -1)
    poles = torch.tensor([abs(e) >= 90.0 for e in elevations_deg])[:, None]
    along = torch.stack([-torch.sin(el) * torch.cos(az), -torch.sin(el) * torch.sin(az), torch.cos(el)], -1)
    ups = torch.where(poles, along, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(along))
    return look_at(eyes, torch.zeros_like(eyes), ups).float()


def rig_cameras(spec: RigSpec, tile_size: int) -> Cameras:
    """The rig's cameras for square views of ``tile_size`` pixels, in file order (pixel centres at +0.5)."""
    c2w = orbit_c2w(spec.azimuths, spec.elevations, spec.distance)
    centre = tile_size / 2.0
    if spec.camera_type == PERSPECTIVE:
        focal = spec.focal * tile_size if spec.focal is not None else \
            0.5 * tile_size / math.tan(math.radians(spec.fov_deg) / 2.0)
        return Cameras(c2w, focal, focal, centre, centre, tile_size, tile_size, pixel_offset=spec.pixel_offset)
    per_unit = tile_size / spec.ortho_scale
    return Cameras(c2w, per_unit, per_unit, centre, centre, tile_size, tile_size, camera_type=ORTHOGRAPHIC,
                   pixel_offset=spec.pixel_offset)
