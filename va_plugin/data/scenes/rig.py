"""The SyncDreamer camera rig (the paper's evaluation rig).

16 views at azimuth k * 22.5 deg, elevation 30 deg, distance 1.5, z-up world, looking at the origin;
K = [[280, 0, 128], [0, 280, 128], [0, 0, 1]] at 256 x 256. Camera 0 sits on +x at (1.299, 0, 0.75).
The paper's 4-view input is views 0, 4, 8, 12.

Half-pixel convention: SyncDreamer's code projects with ``K @ X_cam`` and no offset (``pixel_offset 0``,
the default here). The ground-truth GSO renders, however, were made with pixel centres at +0.5 (Blender's
convention): ray-casting their aligned meshes with ``pixel_offset 0.5`` reproduces every render's
``alpha > 0.5`` mask pixel for pixel, while ``pixel_offset 0`` misses 250-370 pixels per view. Benchmark
scenes are therefore written with :data:`SCENE_PIXEL_OFFSET` (0.5) for every source.
"""

from __future__ import annotations

import math
from typing import List, Sequence, Tuple

import torch

from va_plugin.cameras import Cameras, look_at
from va_plugin.errors import ConfigError

RIG_VIEWS = 16
RIG_FOCAL_256 = 280.0
RIG_DISTANCE = 1.5
RIG_ELEVATION_DEG = 30.0
SCENE_PIXEL_OFFSET = 0.5  # measured on the GSO renders, see the module docstring
# Held-out views off the rig's orbit, for sources we can render: below and above the inputs' elevation.
EXTRA_TEST_VIEWS: Tuple[Tuple[float, float], ...] = tuple(
    (azimuth, elevation) for elevation in (0.0, 45.0) for azimuth in (45.0, 135.0, 225.0, 315.0))


def orbit_cameras(azimuths_deg: Sequence[float], elevations_deg: Sequence[float] | float,
                  distance: float = RIG_DISTANCE, resolution: int = 256,
                  focal_256: float = RIG_FOCAL_256, pixel_offset: float = 0.0) -> Cameras:
    """Perspective cameras on a sphere around the origin (z up), SyncDreamer's intrinsics scaled to
    ``resolution``."""
    az = torch.tensor([math.radians(a) for a in azimuths_deg], dtype=torch.float64)
    if isinstance(elevations_deg, (int, float)):
        elevations_deg = [float(elevations_deg)] * len(az)
    el = torch.tensor([math.radians(e) for e in elevations_deg], dtype=torch.float64)
    eye = distance * torch.stack([torch.cos(el) * torch.cos(az), torch.cos(el) * torch.sin(az), torch.sin(el)], -1)
    c2w = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)).float()
    scale = resolution / 256.0
    f, c = focal_256 * scale, 128.0 * scale
    return Cameras(c2w, f, f, c, c, resolution, resolution, pixel_offset=pixel_offset)


def input_view_ids(n_views: int) -> List[int]:
    """Rig indices of ``n_views`` inputs uniform in azimuth starting at 0 (4 -> 0, 4, 8, 12).

    Counts that do not divide 16 (12 -> 0, 1, 3, 4, 5, 7, ...) are spread as evenly as the rig allows.
    """
    if not isinstance(n_views, int) or n_views < 1 or n_views > RIG_VIEWS:
        raise ConfigError(f"the SyncDreamer rig has {RIG_VIEWS} views; cannot take {n_views} input views")
    return sorted({round(k * RIG_VIEWS / n_views) % RIG_VIEWS for k in range(n_views)})


def syncdreamer_rig(resolution: int = 256, elevation_deg: float = RIG_ELEVATION_DEG,
                    pixel_offset: float = 0.0) -> Cameras:
    """All 16 rig cameras."""
    return orbit_cameras([k * 360.0 / RIG_VIEWS for k in range(RIG_VIEWS)], elevation_deg, resolution=resolution,
                         pixel_offset=pixel_offset)


def view_angles(extra: bool = True) -> List[Tuple[float, float]]:
    """``(azimuth_deg, elevation_deg)`` of the benchmark views: the 16 rig views (ids 0-15), then with
    ``extra`` the :data:`EXTRA_TEST_VIEWS` (ids 16 on)."""
    rig = [(k * 360.0 / RIG_VIEWS, RIG_ELEVATION_DEG) for k in range(RIG_VIEWS)]
    return rig + (list(EXTRA_TEST_VIEWS) if extra else [])


def benchmark_cameras(resolution: int = 256, extra: bool = True, pixel_offset: float = SCENE_PIXEL_OFFSET) -> Cameras:
    """The cameras of :func:`view_angles`, with the rig's distance and intrinsics."""
    angles = view_angles(extra)
    return orbit_cameras([a for a, _ in angles], [e for _, e in angles], resolution=resolution,
                         pixel_offset=pixel_offset)
