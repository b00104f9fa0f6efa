"""Do the input views agree? The test that decides whether a view-adaptive run skips its adaptive phases.

:func:`silhouette_support`: with consistent views, every foreground pixel's ray holds a point that all
other masks contain; per view, the share of foreground pixels whose ray holds none ("unsupported").
It needs no training. :func:`color_cast`: per-view color gains that make the views agree on the
shared surface. :func:`decide_skip` runs both on a run at the end of its pre-training, records them with
the per-view residuals of the shared field (:func:`view_residuals`, which do not vote) in the run folder
and says whether to skip the adaptive phases.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import torch

from va_plugin.callbacks import TrainingCallbackAttributes
from va_plugin.cameras import Cameras
from va_plugin.errors import VAError
from va_plugin.export.fusion import harmonise
from va_plugin.export.mesh import extract_mesh
from va_plugin.export.texture import run_views
from va_plugin.export.views import Views, view_samples
from va_plugin.model_components.losses import psnr_from_mse
from va_plugin.raycast import smooth_vertex_normals
from va_plugin.rays import RayBundle, near_far_from_sphere

if TYPE_CHECKING:
    from va_plugin.adaptive.field import ViewAdaptiveField


@dataclass
class SilhouetteSupport:
    """Per view the share of foreground pixels whose ray no other silhouette supports."""

    unsupported: list[float]
    pixels: list[int]
    threshold: float
    tolerance_px: int = 0

    @property
    def worst(self) -> float:
        return max(self.unsupported, default=0.0)

    @property
    def consistent(self) -> bool:
        """True when no view has more than ``threshold`` of its foreground unsupported."""
        return self.worst <= self.threshold

    def as_dict(self) -> dict:
        return {"test": "silhouette_support", "consistent": self.consistent, "threshold": self.threshold,
                "tolerance_px": self.tolerance_px, "worst_unsupported": round(self.worst, 5),
                "views": [{"view": k, "unsupported": round(u, 5), "pixels": n}
                          for k, (u, n) in enumerate(zip(self.unsupported, self.pixels))]}


DEFAULT_THRESHOLD = 0.001
"""Share of a view's foreground that may be unsupported before the views count as disagreeing (above
what clean, consistent renders show)."""

DENSE_VIEWS = 8
"""From this many views on, the phase decision's silhouette test allows :data:`DENSE_TOLERANCE_PX`: each
ray is checked against every other view, so with many views a point on the rim of a clean silhouette is
almost surely ruled out by some view's pixel rounding."""
DENSE_TOLERANCE_PX = 1


def silhouette_tolerance_px(n_views: int) -> int:
    """The other masks' dilation (pixels) for the phase decision's silhouette test on ``n_views`` views:
    none below :data:`DENSE_VIEWS`, where a pixel of drift is what the test must see, else
    :data:`DENSE_TOLERANCE_PX`."""
    return DENSE_TOLERANCE_PX if n_views >= DENSE_VIEWS else 0


@torch.no_grad()
def silhouette_support(cameras: Cameras, masks: torch.Tensor, scene_radius: float, samples: int = 192,
                       tolerance_px: int = 0, max_pixels: int = 4096,
                       threshold: float = DEFAULT_THRESHOLD) -> SilhouetteSupport | None:
    """The silhouette test on ``masks [n, H, W]`` (bool) seen by ``cameras``: up to ``max_pixels`` pixels
    per view spread evenly (deterministic), ``samples`` points per ray inside the sphere of
    ``scene_radius``, other masks dilated by ``tolerance_px``. None with fewer than two views or an
    empty mask."""
    cameras = cameras.to(torch.device("cpu"))
    masks = masks.bool().cpu()
    n_views = len(cameras)
    if n_views < 2 or not bool(masks.flatten(1).any(-1).all()):
        return None
    kernel = np.ones((2 * tolerance_px + 1, 2 * tolerance_px + 1), np.uint8)
    grown = torch.from_numpy(np.stack([cv2.dilate(m.numpy().astype(np.uint8), kernel) for m in masks])).bool() \
        if tolerance_px > 0 else masks
    height, width = masks.shape[1:]
    fractions, counts = [], []
    for view in range(n_views):
        inside = masks[view].reshape(-1).nonzero().squeeze(-1)
        if inside.numel() > max_pixels:
            inside = inside[torch.linspace(0, inside.numel() - 1, max_pixels).round().long()]
        rows, cols = inside // width, inside % width
        origins, directions = cameras.generate_rays(view, rows.float(), cols.float())
        nears, fars, _ = near_far_from_sphere(origins, directions, scene_radius)
        t = torch.linspace(0.0, 1.0, samples)[None, :]
        depths = nears + (fars - nears) * t  # [m, s]
        points = (origins[:, None, :] + directions[:, None, :] * depths[..., None]).reshape(-1, 3)
        alive = torch.arange(points.shape[0])  # the points no other view has ruled out yet
        for other in range(n_views):
            if other == view or alive.numel() == 0:
                continue
            uv, depth = cameras.project(points[alive], other)
            col, row = uv[:, 0].round().long(), uv[:, 1].round().long()
            in_frame = (col >= 0) & (col < width) & (row >= 0) & (row < height)
            # beyond the frame: the other view cannot rule the point out
            seen = torch.ones_like(in_frame)
            seen[in_frame] = grown[other, row[in_frame], col[in_frame]]
            alive = alive[seen | (depth <= 0)]
        supported = torch.zeros(points.shape[0], dtype=torch.bool)
        supported[alive] = True
        hit = (fars > nears)[:, 0]
        ok = supported.view(-1, samples).any(-1) & hit
        fractions.append(1.0 - float(ok.float().mean()))
        counts.append(int(inside.numel()))
    return SilhouetteSupport(fractions, counts, threshold, tolerance_px)


@dataclass
class ColorCast:
    """Per-view color gains that make the training views agree on the shared surface (view 0 fixed at 1)."""

    gains: np.ndarray  # [n, 3]
    points: int  # surface points the fit used (seen by two views)
    seconds: float
    levels: np.ndarray | None = None  # [n, 3] each view's mean color where another view sees too

    @property
    def log_gains(self) -> np.ndarray:
        """``[n, 3]``: the log of each view's per-channel gain (gains floored at 1e-6)."""
        return np.log(np.clip(self.gains, 1e-6, None))

    @property
    def chroma(self) -> np.ndarray:
        """``[n, 3]``: per view, |log gain of each channel minus the view's mean log gain| (a white-balance
        shift; brightness is left out, as lighting differs between sides)."""
        logs = self.log_gains
        return np.abs(logs - logs.mean(1, keepdims=True))

    @property
    def worst(self) -> float:
        """The largest chromatic deviation (:attr:`chroma`)."""
        return float(self.chroma.max()) if self.gains.size else 0.0

    @property
    def worst_shift(self) -> float:
        """The largest chromatic deviation in color units: :attr:`chroma` times the view's mean level of
        the channel, so a dark channel's ill-defined gain counts for little."""
        if not self.gains.size or self.levels is None:
            return self.worst
        return float(np.max(self.chroma * self.levels))

    @property
    def brightness(self) -> float:
        """The largest deviation of a view's mean log gain from view 0's."""
        return float(np.max(np.abs(self.log_gains.mean(1)))) if self.gains.size else 0.0

    def as_dict(self) -> dict:
        return {"test": "color_cast", "worst_chroma": round(self.worst, 5), "worst_shift": round(self.worst_shift, 5),
                "worst_brightness": round(self.brightness, 5), "points": self.points,
                "seconds": round(self.seconds, 2), "gains": np.round(self.gains, 4).tolist(),
                "levels": None if self.levels is None else np.round(self.levels, 4).tolist()}


@torch.no_grad()
def color_cast(model, cameras: Cameras, images: np.ndarray, masks: np.ndarray | None = None,
                resolution: int = 64, max_gain: float = float("inf")) -> ColorCast:
    """How far apart the views' colors are on the shared surface: the per-view gains of
    :func:`va_plugin.export.fusion.harmonise` on the vertices of a ``resolution``^3 mesh of ``model``
    projected into every view (``images [n, H, W, 3]`` composited, ``masks [n, H, W]`` bool or None).
    Raises VAError when the model has no surface."""
    import time


    started = time.perf_counter()
    mesh = extract_mesh(model, resolution=resolution, with_color=False)
    vertices = np.asarray(mesh.vertices, np.float32)
    faces = np.asarray(mesh.faces, np.int64)
    normals = smooth_vertex_normals(vertices, faces)
    views = Views(cameras.to(torch.device("cpu")), images, masks)
    colors, weights, _ = view_samples(vertices, faces, vertices, normals, views)
    gains = harmonise(colors, weights, max_gain=max_gain)
    seen = weights > 0
    shared = seen.sum(1) >= 2
    w = np.where(seen & shared[:, None], weights, 0.0)
    levels = np.einsum("mn,mnc->nc", w, colors) / np.maximum(w.sum(0), 1e-12)[:, None]
    return ColorCast(gains, int(shared.sum()), time.perf_counter() - started, levels.astype(np.float32))


RESIDUALS_FILE = "view_residuals.json"
COLOR_CAST_GRID = 96
"""Marching-cubes grid of the surface the color-cast test fits on."""


@torch.no_grad()
def view_residuals(pipeline, max_pixels: int = 4096, total_pixels: int = 16384,
                   foreground_pixels: int = 4096) -> list[dict[str, float]]:
    """How well the shared (canonical) field explains each training input: per view, the PSNR over the
    rendered pixels and, with masks, over their foreground.

    With masks, ``foreground_pixels`` in all are spread evenly over the views' foregrounds; without
    (or with ``foreground_pixels=0`` or an empty mask), up to ``max_pixels`` per view and
    ``total_pixels`` in all on an even stride. No random draw: a resumed run decides the same.
    """
    dm = pipeline.datamanager
    height, width = dm.images.shape[1:3]
    n_views = max(dm.num_train_views, 1)
    per_view = max(1, min(max_pixels, total_pixels // n_views))
    stride = max(1, math.ceil(math.sqrt(height * width / per_view)))
    grid_rows, grid_cols = torch.meshgrid(torch.arange(stride // 2, height, stride, device=dm.device),
                                          torch.arange(stride // 2, width, stride, device=dm.device), indexing="ij")
    grid_rows, grid_cols = grid_rows.reshape(-1), grid_cols.reshape(-1)
    per_view_foreground = max(1, foreground_pixels // n_views)
    results = []
    for view in range(dm.num_train_views):
        rows, cols = grid_rows, grid_cols
        if dm.masks is not None and foreground_pixels > 0:
            inside = (dm.masks[view, ..., 0].reshape(-1) > 0.5).nonzero().squeeze(-1)
            if inside.numel() > 0:
                if inside.numel() > per_view_foreground:  # evenly spaced over the foreground, in scan order
                    pick = torch.linspace(0, inside.numel() - 1, per_view_foreground, device=inside.device)
                    inside = inside[pick.round().long()]
                rows, cols = inside // width, inside % width
        views = torch.full_like(rows, view)
        origins, directions = dm.cameras.generate_rays(views, rows, cols)
        rays = RayBundle(origins, directions, torch.full_like(views, -1))
        rgb = pipeline.model.render_rays(rays, keys=("rgb",))["rgb"]
        target = dm.images[view, rows, cols]
        err = ((rgb - target) ** 2).mean(-1)
        entry = {"view": view, "psnr": float(psnr_from_mse(err.mean())), "pixels": int(rows.numel())}
        if dm.masks is not None:
            fg = dm.masks[view, rows, cols, 0] > 0.5
            if bool(fg.any()):
                entry["psnr_foreground"] = float(psnr_from_mse(err[fg].mean()))
        results.append(entry)
    return results


def residual_spread_db(residuals: list[dict[str, float]]) -> float:
    """How far the worst-explained view falls below the best one, in dB: the spread of the per-view
    foreground PSNRs of :func:`view_residuals` (of the whole-image PSNRs when a view has no foreground)."""
    key = "psnr_foreground" if all("psnr_foreground" in r for r in residuals) else "psnr"
    values = [r[key] for r in residuals]
    return max(values) - min(values)


def decide_skip(field: ViewAdaptiveField, attributes: TrainingCallbackAttributes, step: int) -> bool:
    """Measure the silhouette support and the color cast, record them with the per-view residuals (which
    do not vote), and say whether to skip the adaptive phases (when the inputs agree)."""
    residuals = view_residuals(attributes.pipeline)
    support = input_silhouette_support(attributes.pipeline.datamanager)
    cast = input_color_cast(attributes.pipeline, field.config.consistent_color_cast)
    color_ok = cast is None or cast.worst_shift <= field.config.consistent_color_cast
    consistent = (support is None or support.consistent) and color_ok
    record = {"step": step, "consistent": consistent, "views": residuals,
              "silhouette_support": support.as_dict() if support is not None else None,
              "color_cast": None if cast is None else {**cast.as_dict(), "consistent": color_ok,
                                                        "threshold": field.config.consistent_color_cast}}
    run_dir = Path(attributes.run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / RESIDUALS_FILE).write_text(json.dumps(record, indent=2))
    spread = residual_spread_db(residuals)
    details = f", silhouettes {100 * support.worst:.2f}% unsupported" if support is not None else ""
    details += f", color cast {cast.worst_shift:.3f}" if cast is not None else ""
    if consistent:
        field.skipped.fill_(True)
        attributes.announce(step, f"inputs look consistent (per-view PSNR spread {spread:.2f} dB{details}): "
                                  "adaptive phases skipped; force them with skip_consistent_scenes=false",
                            skipped_adaptive=True)
    else:
        attributes.announce(step, f"inputs disagree (per-view PSNR spread {spread:.2f} dB{details}): "
                                  "adaptive phases on", residual_spread_db=spread)
    return consistent


def input_color_cast(pipeline, threshold: float):
    """:func:`color_cast` of the shared field on the training views; None when the test is off, with
    fewer than two views, or when no surface (point seen by two views) exists yet."""

    if threshold <= 0 or pipeline.datamanager.num_train_views < 2:
        return None
    views = run_views(pipeline)
    try:
        cast = color_cast(pipeline.model, views.cameras, views.images, views.masks, resolution=COLOR_CAST_GRID)
    except VAError:
        return None
    return cast if cast.points > 0 else None


def input_silhouette_support(datamanager):
    """:func:`silhouette_support` of the training views' masks (None without masks), with the tolerance
    of :func:`silhouette_tolerance_px` for their number."""
    if datamanager.masks is None:
        return None
    return silhouette_support(datamanager.cameras, datamanager.masks[..., 0] > 0.5, datamanager.scene_radius,
                              tolerance_px=silhouette_tolerance_px(len(datamanager.cameras)))
