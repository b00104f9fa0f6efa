"""Does the object fit in the scene's bounding sphere (where every model samples)? Inputs that stick out
are refused; an object the image frame cuts off is allowed, with a warning."""

from __future__ import annotations

import math
import warnings

import torch

from va_plugin.data.dataparsers.base import DataparserOutputs
from va_plugin.errors import DataError
from va_plugin.rays import near_far_from_sphere

MAX_OUTSIDE_FRACTION = 0.01
"""Share of a view's foreground pixels whose rays may miss the sphere (mask edges, rounding)."""
MAX_BORDER_FRACTION = 0.01
"""Share of a view's border pixels that may be foreground before the object counts as cut off."""
MAX_CHECKED_PIXELS = 16384
"""Foreground pixels checked per view (an even subsample beyond that)."""


def check_object_in_bound(outputs: DataparserOutputs) -> None:
    """Raise :class:`DataError` when the scene radius is not a positive number, or when, in some view,
    more than 1% of the foreground pixels look past the bounding sphere (the object lies partly
    outside it, or the cameras do not look at the origin). Views without masks are not checked."""
    radius = outputs.scene_radius
    if not (math.isfinite(radius) and radius > 0):
        raise DataError(f"the scene radius must be a positive number, got {radius}")
    if outputs.masks is None:
        return
    cameras = outputs.cameras
    for view in range(len(cameras)):
        rows, cols = (outputs.masks[view, :, :, 0] > 0.5).nonzero(as_tuple=True)
        if rows.numel() == 0:
            continue
        stride = max(1, rows.numel() // MAX_CHECKED_PIXELS)
        rows, cols = rows[::stride], cols[::stride]
        origins, directions = cameras.generate_rays(torch.full_like(rows, view), rows, cols)
        _, _, hits = near_far_from_sphere(origins, directions, radius)
        outside = 1.0 - float(hits.float().mean())
        if outside > MAX_OUTSIDE_FRACTION:
            raise DataError(f"the object does not fit in the bounding sphere of radius {radius:g}: "
                            f"{outside:.0%} of the foreground of training view {view} lies outside it; "
                            "use a larger scene radius (scene_radius in transforms.json, or --set "
                            "pipeline.datamanager.dataparser.scene_radius=R) or check the camera poses")


def border_foreground(masks: torch.Tensor) -> list[float]:
    """Per view, the share of the image's outermost pixels (all four edges) that are foreground."""
    fg = masks[..., 0] > 0.5  # [n, H, W]
    edges = torch.cat([fg[:, 0, :], fg[:, -1, :], fg[:, 1:-1, 0], fg[:, 1:-1, -1]], dim=1)
    return edges.float().mean(dim=1).tolist()


def warn_object_cut_by_frame(outputs: DataparserOutputs) -> list[float]:
    """Warn when the frame cuts the object off in some training view (foreground on more than 1% of
    the image border: unsupervised surface). Returns the per-view shares (empty without masks)."""
    if outputs.masks is None:
        return []
    shares = border_foreground(outputs.masks)
    cut = [view for view, share in enumerate(shares) if share > MAX_BORDER_FRACTION]
    if cut:
        warnings.warn(f"the image frame cuts the object off in training view(s) {cut} (up to "
                      f"{max(shares):.0%} of a view's border is foreground): what lies outside every frame is "
                      "seen by no view, so the surface there is a guess; inputs with a margin around the object "
                      "avoid this", stacklevel=2)
    return shares
