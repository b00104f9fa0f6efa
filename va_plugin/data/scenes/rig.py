"""The SyncDreamer camera rig (the paper's evaluation rig).

16 views at azimuth k * 22.5 deg, elevation 30 deg, distance 1.5, z-up world, looking at the origin;
K = [[280, 0, 128], [0, 280, 128], [0, 0, 1]] at 256 x 256 with no half-pixel offset (pixel_offset 0).
Camera 0 sits on +x at (1.299, 0, 0.75). The paper's 4-view input is views 0, 4, 8, 12.
"""

from __future__ import annotations

import math
from typing import List, Sequence

import torch

from va_plugin.cameras import Cameras, look_at
from va_plugin.errors import ConfigError

RIG_VIEWS = 16
RIG_FOCAL_256 = 280.0
RIG_DISTANCE = 1.5
RIG_ELEVATION_DEG = 30.0


def orbit_cameras(azimuths_deg: Sequence[float], elevations_deg: Sequence[float] | float,
                  distance: float = RIG_DISTANCE, resolution: int = 256,
                  focal_256: float = RIG_FOCAL_256) -> Cameras:
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
    return Cameras(c2w, f, f, c, c, resolution, resolution, pixel_offset=0.0)


def input_view_ids(n_views: int) -> List[int]:
    """Rig indices of ``n_views`` inputs uniform in azimuth starting at 0 (4 -> 0, 4, 8, 12)."""
    if n_views not in (1, 2, 4, 8, 16) and RIG_VIEWS % n_views != 0:
        # 12 views do not divide 16 evenly: spread them as evenly as the rig allows
        return sorted({round(k * RIG_VIEWS / n_views) % RIG_VIEWS for k in range(n_views)})
    if n_views < 1 or n_views > RIG_VIEWS:
        raise ConfigError(f"the SyncDreamer rig has {RIG_VIEWS} views; cannot take {n_views}")
    step = RIG_VIEWS // n_views
    return list(range(0, RIG_VIEWS, step))


def syncdreamer_rig(resolution: int = 256, elevation_deg: float = RIG_ELEVATION_DEG) -> Cameras:
    """All 16 rig cameras."""
    return orbit_cameras([k * 360.0 / RIG_VIEWS for k in range(RIG_VIEWS)], elevation_deg, resolution=resolution)
