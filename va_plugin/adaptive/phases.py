"""The three training phases of the paper's Sec. 3.4, switched by a trainer callback.

Phase 1 trains the shared field alone; phase 2 adds the per-view branches (the shared field at
``shared_lr_scale``); phase 3 the attention fusion. Boundaries are fractions of the step budget, so a
resumed run lands in the same phase. At the end of phase 1 the callback can test whether the inputs
disagree (silhouette support and colour cast) and, if not, keep the run in phase 1.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from va_plugin.adaptive.consistency import colour_cast, silhouette_support
from va_plugin.engine.callbacks import AFTER_STEP, BEFORE_STEP, TrainingCallback, TrainingCallbackAttributes
from va_plugin.model_components.losses import psnr_from_mse
from va_plugin.rays import RayBundle

if TYPE_CHECKING:  # the field builds its callbacks from here: no import back at run time
    from va_plugin.adaptive.field import ViewAdaptiveField

PRETRAIN, BRANCHES, FUSION = 1, 2, 3
PHASE_NAMES = {PRETRAIN: "global pre-training", BRANCHES: "view-adaptive branches", FUSION: "self-attention fusion"}

RESIDUALS_FILE = "view_residuals.json"
COLOUR_CAST_GRID = 96
"""Marching-cubes grid of the surface the colour-cast test fits on."""


def phase_at(step: int, max_steps: int, pretrain_fraction: float, branch_fraction: float) -> int:
    """Phase (1, 2 or 3) of 0-based ``step`` in a budget of ``max_steps``."""
    if step < round(pretrain_fraction * max_steps):
        return PRETRAIN
    if step < round((pretrain_fraction + branch_fraction) * max_steps):
        return BRANCHES
    return FUSION


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


def phase_callback(field: ViewAdaptiveField) -> TrainingCallback:
    """The trainer callback that sets the field's phase; it returns the learning-rate factor of the
    shared field's optimizer groups (``shared_lr_scale`` once the branches train)."""
    cfg = field.config

    def switch(step: int, attributes: TrainingCallbackAttributes) -> dict[str, float]:
        wanted = phase_at(step, attributes.horizon, cfg.pretrain_fraction, cfg.branch_fraction)
        if (field.branches is None or bool(field.skipped)
                or (wanted > PRETRAIN and field.current_phase == PRETRAIN and cfg.skip_consistent_scenes
                    and _decide_skip(field, attributes, step))):
            wanted = PRETRAIN
        if wanted != field.current_phase:
            field.set_phase(wanted)
            attributes.announce(step, f"phase {wanted}: {PHASE_NAMES[wanted]}", phase=wanted)
        factor = cfg.shared_lr_scale if wanted >= BRANCHES else 1.0
        return dict.fromkeys(SHARED_GROUPS, factor)  # the shared field and NeuS's inv_s

    return TrainingCallback(switch, BEFORE_STEP)


def diagnostics_callback(field: ViewAdaptiveField) -> TrainingCallback:
    """After the last step, the attention heat map and the inconsistency maps go to the run folder."""

    def write(step: int, attributes: TrainingCallbackAttributes) -> None:
        if step + 1 != attributes.max_steps:
            return
        from va_plugin.adaptive.diagnostics import write_diagnostics

        run_dir = attributes.run_dir
        try:
            written = write_diagnostics(attributes.pipeline, run_dir, field.config.diagnostics_scale,
                                        progress=attributes.progress)
        except Exception as exc:  # pictures must never cost the trained run (its checkpoint comes after)
            warnings.warn(f"the diagnostics pictures failed ({type(exc).__name__}: {exc}); the trained run is "
                          f"kept: retry with va-export diagnostics --load-dir {run_dir}", stacklevel=2)
            return
        if written:
            attributes.announce(step, "diagnostics written: " + ", ".join(Path(p).name for p in written))

    return TrainingCallback(write, AFTER_STEP)


def _decide_skip(field: ViewAdaptiveField, attributes: TrainingCallbackAttributes, step: int) -> bool:
    """Measure the silhouette support and the colour cast, record them with the per-view residuals (which
    do not vote), and say whether to skip the adaptive phases (when the inputs agree)."""
    residuals = view_residuals(attributes.pipeline)
    support = input_silhouette_support(attributes.pipeline.datamanager)
    cast = input_colour_cast(attributes.pipeline, field.config.consistent_colour_cast)
    colour_ok = cast is None or cast.worst_shift <= field.config.consistent_colour_cast
    consistent = (support is None or support.consistent) and colour_ok
    record = {"step": step, "consistent": consistent, "views": residuals,
              "silhouette_support": support.as_dict() if support is not None else None,
              "colour_cast": None if cast is None else {**cast.as_dict(), "consistent": colour_ok,
                                                        "threshold": field.config.consistent_colour_cast}}
    run_dir = Path(attributes.run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / RESIDUALS_FILE).write_text(json.dumps(record, indent=2))
    spread = residual_spread_db(residuals)
    details = f", silhouettes {100 * support.worst:.2f}% unsupported" if support is not None else ""
    details += f", colour cast {cast.worst_shift:.3f}" if cast is not None else ""
    if consistent:
        field.skipped.fill_(True)
        attributes.announce(step, f"inputs look consistent (per-view PSNR spread {spread:.2f} dB{details}): "
                                  "adaptive phases skipped; force them with skip_consistent_scenes=false",
                            skipped_adaptive=True)
    else:
        attributes.announce(step, f"inputs disagree (per-view PSNR spread {spread:.2f} dB{details}): "
                                  "adaptive phases on", residual_spread_db=spread)
    return consistent


def input_colour_cast(pipeline, threshold: float):
    """:func:`colour_cast` of the shared field on the training views; None when the test is off, with
    fewer than two views, or when no surface (point seen by two views) exists yet."""
    from va_plugin.errors import VAError
    from va_plugin.export.texture import run_views

    if threshold <= 0 or pipeline.datamanager.num_train_views < 2:
        return None
    views = run_views(pipeline)
    try:
        cast = colour_cast(pipeline.model, views.cameras, views.images, views.masks, resolution=COLOUR_CAST_GRID)
    except VAError:
        return None
    return cast if cast.points > 0 else None


def input_silhouette_support(datamanager):
    """:func:`silhouette_support` of the training views' masks (None without masks)."""
    if datamanager.masks is None:
        return None
    return silhouette_support(datamanager.cameras, datamanager.masks[..., 0] > 0.5, datamanager.scene_radius)


SHARED_GROUPS = ("fields", "variance")
"""Optimizer groups of the shared model, slowed by ``shared_lr_scale`` once the branches train."""
