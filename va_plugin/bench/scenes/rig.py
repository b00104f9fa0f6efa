"""The SyncDreamer camera rig (the paper's evaluation rig) as the benchmark scenes use it; the rig itself
lives in :mod:`va_plugin.data.rigs`.

16 views at azimuth k * 22.5 deg, elevation 30 deg, distance 1.5, z-up world, looking at the origin;
K = [[280, 0, 128], [0, 280, 128], [0, 0, 1]] at 256 x 256. The paper's 4-view input is views 0, 4, 8, 12.
SyncDreamer projects with no half-pixel offset, but the GSO renders have pixel centres at +0.5 (their
masks match only then), so benchmark scenes use :data:`SCENE_PIXEL_OFFSET` (0.5) for every source.
"""

from __future__ import annotations

from va_plugin.cameras import Cameras
from va_plugin.data.rigs import (  # noqa: F401
    RIG_DISTANCE,
    RIG_ELEVATION_DEG,
    RIG_FOCAL_256,
    RIG_VIEWS,
    input_view_ids,
    orbit_cameras,
    syncdreamer_rig,
)

SCENE_PIXEL_OFFSET = 0.5
# Held-out views off the rig's orbit, for sources we can render: below and above the inputs' elevation.
EXTRA_TEST_VIEWS: tuple[tuple[float, float], ...] = tuple(
    (azimuth, elevation) for elevation in (0.0, 45.0) for azimuth in (45.0, 135.0, 225.0, 315.0))


def view_angles(extra: bool = True) -> list[tuple[float, float]]:
    """``(azimuth_deg, elevation_deg)`` of the benchmark views: the 16 rig views (ids 0-15), then with
    ``extra`` the :data:`EXTRA_TEST_VIEWS` (ids 16 on)."""
    rig = [(k * 360.0 / RIG_VIEWS, RIG_ELEVATION_DEG) for k in range(RIG_VIEWS)]
    return rig + (list(EXTRA_TEST_VIEWS) if extra else [])


def benchmark_cameras(resolution: int = 256, extra: bool = True, pixel_offset: float = SCENE_PIXEL_OFFSET) -> Cameras:
    """The cameras of :func:`view_angles`, with the rig's distance and intrinsics."""
    angles = view_angles(extra)
    return orbit_cameras([a for a, _ in angles], [e for _, e in angles], resolution=resolution,
                         pixel_offset=pixel_offset)
