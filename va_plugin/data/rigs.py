"""The fixed camera rigs of multi-view generators, as their own code and documents state them.

Every rig here lives in one world frame: z up, the generator's input (reference) view at azimuth 0 on
+x, azimuth growing counter-clockwise seen from above (towards +y), cameras looking at the origin; camera
axes are OpenCV's (see :mod:`va_plugin.cameras`).

* **SyncDreamer** (``camera-16.pkl`` of its repository): 16 views at azimuth ``k * 22.5`` deg, elevation
  30 deg, distance 1.5, ``K = [[280, 0, 128], [0, 280, 128], [0, 0, 1]]`` at 256 px (FOV 49.13 deg);
  objects fill the unit box.
* **Zero123++** (its README, and InstantMesh's ``get_zero123plus_input_cameras``): 6 views at azimuth 30,
  90, ..., 330 deg relative to the input view; elevations alternate 30 / -20 deg with FOV 49.13 deg
  (v1.1: ``2 atan(16 / 35)``) or 20 / -10 deg with FOV 30 deg (v1.2). The radius only sets the scale;
  InstantMesh's 4.0 for objects in ``[-1, 1]^3`` is 2.0 for our unit box.
* **Wonder3D** (``instant-nsr-pl/datasets/fixed_poses`` and ``ortho.py``): 6 orthographic views at
  elevation 0, ``front, front_right, right, back, left, front_left`` at azimuth 0, 45, 90, 180, -90,
  -45 deg; ``ortho_scale`` 1.35 (the image spans 1.35 world units), pixel centres at +0.5.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from va_plugin.cameras import ORTHOGRAPHIC, Cameras, look_at
from va_plugin.errors import ConfigError

# SyncDreamer
RIG_VIEWS = 16
RIG_FOCAL_256 = 280.0
RIG_DISTANCE = 1.5
RIG_ELEVATION_DEG = 30.0

# Zero123++: version -> (elevations of the six views, vertical FOV in degrees)
ZERO123PP_AZIMUTHS = (30.0, 90.0, 150.0, 210.0, 270.0, 330.0)
ZERO123PP_RIGS: dict[str, tuple[tuple[float, ...], float]] = {
    "v1.1": ((30.0, -20.0, 30.0, -20.0, 30.0, -20.0), math.degrees(2.0 * math.atan(16.0 / 35.0))),
    "v1.2": ((20.0, -10.0, 20.0, -10.0, 20.0, -10.0), 30.0),
}
ZERO123PP_RADIUS = 2.0  # InstantMesh: 4.0 for objects in [-1, 1]^3; halved for our unit box

# Wonder3D
WONDER3D_VIEWS: tuple[tuple[str, float], ...] = (
    ("front", 0.0), ("front_right", 45.0), ("right", 90.0), ("back", 180.0), ("left", -90.0), ("front_left", -45.0))
WONDER3D_ORTHO_SCALE = 1.35
WONDER3D_DISTANCE = 2.0  # any distance outside the object works for an orthographic camera


def orbit_eyes(azimuths_deg: Sequence[float], elevations_deg: Sequence[float] | float,
               distance: float) -> torch.Tensor:
    """Camera positions ``[n, 3]`` on a z-up sphere: ``r (cos el cos az, cos el sin az, sin el)``."""
    az = torch.tensor([math.radians(a) for a in azimuths_deg], dtype=torch.float64)
    if isinstance(elevations_deg, (int, float)):
        elevations_deg = [float(elevations_deg)] * len(az)
    el = torch.tensor([math.radians(e) for e in elevations_deg], dtype=torch.float64)
    return distance * torch.stack([torch.cos(el) * torch.cos(az), torch.cos(el) * torch.sin(az), torch.sin(el)], -1)


def look_at_origin(eyes: torch.Tensor) -> torch.Tensor:
    """OpenCV camera-to-world ``[n, 3, 4]`` of cameras at ``eyes [n, 3]`` looking at the origin, z up."""
    return look_at(eyes, torch.zeros_like(eyes), torch.tensor([0.0, 0.0, 1.0], dtype=eyes.dtype)).float()


def orbit_cameras(azimuths_deg: Sequence[float], elevations_deg: Sequence[float] | float,
                  distance: float = RIG_DISTANCE, resolution: int = 256,
                  focal_256: float = RIG_FOCAL_256, pixel_offset: float = 0.0) -> Cameras:
    """Perspective cameras on a sphere around the origin (z up), SyncDreamer's intrinsics scaled to
    ``resolution``."""
    c2w = look_at_origin(orbit_eyes(azimuths_deg, elevations_deg, distance))
    scale = resolution / 256.0
    f, c = focal_256 * scale, 128.0 * scale
    return Cameras(c2w, f, f, c, c, resolution, resolution, pixel_offset=pixel_offset)


def check_elevation(elevation_deg: float, option: str = "elevation") -> float:
    """Refuse an orbit elevation that is not a number strictly between -90 and 90 degrees (at the poles the
    cameras' up direction is undefined)."""
    if isinstance(elevation_deg, bool) or not isinstance(elevation_deg, (int, float)) or \
            not -90.0 < elevation_deg < 90.0:
        raise ConfigError(f"{option} must be between -90 and 90 degrees, exclusive (SyncDreamer generates at "
                          f"{RIG_ELEVATION_DEG:g}), got {elevation_deg}")
    return float(elevation_deg)


def syncdreamer_rig(resolution: int = 256, elevation_deg: float = RIG_ELEVATION_DEG,
                    pixel_offset: float = 0.0) -> Cameras:
    """All 16 SyncDreamer cameras at ``elevation_deg`` (in (-90, 90))."""
    check_elevation(elevation_deg)
    return orbit_cameras([k * 360.0 / RIG_VIEWS for k in range(RIG_VIEWS)], elevation_deg, resolution=resolution,
                         pixel_offset=pixel_offset)


def input_view_ids(n_views: int) -> list[int]:
    """SyncDreamer rig indices of ``n_views`` inputs uniform in azimuth from 0 (4 -> 0, 4, 8, 12;
    12 -> 0, 1, 3, 4, 5, 7, ...: as evenly as the rig allows)."""
    if not isinstance(n_views, int) or n_views < 1 or n_views > RIG_VIEWS:
        raise ConfigError(f"the SyncDreamer rig has {RIG_VIEWS} views; cannot take {n_views} input views")
    return sorted({round(k * RIG_VIEWS / n_views) % RIG_VIEWS for k in range(n_views)})


def zero123pp_rig(version: str = "v1.2", resolution: int = 320, radius: float = ZERO123PP_RADIUS,
                  pixel_offset: float = 0.5) -> Cameras:
    """The six Zero123++ output cameras (grid order) for square tiles of ``resolution`` pixels."""
    if version not in ZERO123PP_RIGS:
        raise ConfigError(f"unknown Zero123++ rig {version!r}; known: {', '.join(ZERO123PP_RIGS)}")
    elevations, fov_deg = ZERO123PP_RIGS[version]
    c2w = look_at_origin(orbit_eyes(ZERO123PP_AZIMUTHS, elevations, radius))
    focal = 0.5 * resolution / math.tan(math.radians(fov_deg) / 2.0)
    centre = resolution / 2.0
    return Cameras(c2w, focal, focal, centre, centre, resolution, resolution, pixel_offset=pixel_offset)


def wonder3d_rig(resolution: int = 256, ortho_scale: float = WONDER3D_ORTHO_SCALE) -> Cameras:
    """The six Wonder3D orthographic cameras in :data:`WONDER3D_VIEWS` order."""
    c2w = look_at_origin(orbit_eyes([az for _, az in WONDER3D_VIEWS], 0.0, WONDER3D_DISTANCE))
    pixels_per_unit = resolution / ortho_scale
    centre = resolution / 2.0
    return Cameras(c2w, pixels_per_unit, pixels_per_unit, centre, centre, resolution, resolution,
                   camera_type=ORTHOGRAPHIC, pixel_offset=0.5)
