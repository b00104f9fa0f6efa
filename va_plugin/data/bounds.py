"""Does the object fit in the scene's bounding sphere (where every model samples)? Inputs that stick out
are refused; an object the image frame cuts off is allowed, with a warning. Do the views see it from
different places? Views that all share one pose are refused, duplicated poses warned about."""

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
SAME_POSE_TOLERANCE = 1e-3
"""Two views share a pose when their camera centres lie within this share of the scene radius and their
rotations differ by at most this in every entry."""


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
        origins, directions = cameras.generate_rays(view, rows, cols)
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


def same_pose_groups(outputs: DataparserOutputs) -> list[list[int]]:
    """The groups of two or more training views that share one camera pose (centre and rotation, within
    :data:`SAME_POSE_TOLERANCE`), each in view order."""
    c2w = outputs.cameras.c2w.double()
    if len(c2w) < 2:
        return []
    centres, rotations = c2w[:, :, 3], c2w[:, :, :3].reshape(len(c2w), 9)
    scale = SAME_POSE_TOLERANCE * max(float(outputs.scene_radius), 1e-6)
    same = (torch.cdist(centres, centres) <= scale) & \
        ((rotations[:, None] - rotations[None]).abs().amax(-1) <= SAME_POSE_TOLERANCE)
    groups, seen = [], set()
    for view in range(len(c2w)):
        if view in seen:
            continue
        group = [int(v) for v in same[view].nonzero().flatten() if int(v) not in seen]
        seen.update(group)
        if len(group) > 1:
            groups.append(group)
    return groups


def check_distinct_views(outputs: DataparserOutputs) -> list[list[int]]:
    """Raise :class:`DataError` when every training view (two or more) has the same camera pose: one
    viewpoint holds no depth. Warn when there is only one view, and when some share a pose (a duplicate
    adds no viewpoint; often a copy-paste error in the poses). Returns the groups of views that share a
    pose."""
    groups = same_pose_groups(outputs)
    count = len(outputs.cameras)
    if count == 1:
        warnings.warn("only one training view: a single viewpoint gives no depth, so the shape away from what "
                      "that view sees (its depth, its back) is a guess; give a multi-view input (a generator's "
                      "views, or frames from several poses)", stacklevel=2)
    if groups and len(groups[0]) == count:
        raise DataError(f"all {count} training views have the same camera pose, so they see the object from one "
                        "viewpoint and give no depth; check the poses (transform_matrix of each frame)")
    if groups:
        shown = "; ".join(", ".join(str(v) for v in group) for group in groups[:5])
        warnings.warn(f"training views with the same camera pose: {shown}{' ...' if len(groups) > 5 else ''}; "
                      "a view repeated from the same place adds no viewpoint (check the poses)", stacklevel=2)
    return groups
