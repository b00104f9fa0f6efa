"""One benchmark row: one method trained on one scene, then evaluated, all through the library.

The config comes from the registry, training is :func:`train_run`, evaluation
:func:`va_plugin.eval.evaluate.evaluate_run` (``va-eval``). Both methods of a pair get the same scene,
seed, step budget and overrides. Checkpoints every ``max_steps // curve_points`` steps are evaluated after
training (error against training seconds); only the last is kept. An interrupted row resumes.
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import time
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import torch

from va_plugin.api import build_config
from va_plugin.bench.catalog import SceneSpec, input_error
from va_plugin.bench.presets import BACKBONE_TITLES, BACKBONES, BenchPreset, EvalSettings
from va_plugin.config import apply_override, config_digest
from va_plugin.engine.trainer import TrainingInterrupted, list_checkpoints, train_run
from va_plugin.errors import VAError
from va_plugin.eval.evaluate import evaluate_run, image_metrics
from va_plugin.registry import get_method

ROW_FILE = "bench_row.json"
"""In a row's run folder: the row's key and settings fingerprint (a rerun resumes only a matching run)."""

ADAPTIVE_OVERRIDES = ("pipeline.model.field.diagnostics_scale=0",)
"""The diagnostics pictures would count in the trainer's clock, so benchmark rows turn them off."""

METRICS = ("psnr", "ssim", "lpips", "cd", "iou", "fscore")


@dataclass(frozen=True)
class RowSpec:
    """What one row trains: a backbone, original or view-adaptive, on a scene, with extra overrides."""

    experiment: str
    scene: SceneSpec
    backbone: str
    adaptive: bool
    variant: str = ""  # label in its table (default: "Original NeuS", "View-adaptive NeuS", ...)
    overrides: tuple[str, ...] = ()
    method_preset: str | None = None  # registry preset (default: the benchmark preset's)
    steps: int | None = None  # step budget (default: the benchmark preset's, else the method's)

    @property
    def method(self) -> str:
        return BACKBONES[self.backbone][int(self.adaptive)]

    @property
    def label(self) -> str:
        if self.variant:
            return self.variant
        return f"{'View-adaptive' if self.adaptive else 'Original'} {BACKBONE_TITLES.get(self.backbone, self.backbone)}"

    @property
    def key(self) -> str:
        slug = re.sub(r"[^A-Za-z0-9]+", "-", self.label).strip("-").lower()
        return f"{self.scene.folder_name}/{self.method}/{slug}"


def row_config(row: RowSpec, preset: BenchPreset, scene_dir: Path, run_dir: Path, seed: int = 42,
               device: str = "auto"):
    """The trainer config of a row (see the module docstring)."""
    steps = row.steps if row.steps is not None else preset.steps.get(row.backbone)
    config = build_config(row.method, preset=row.method_preset or preset.method_preset, steps=steps, seed=seed,
                          device=device, out=run_dir, progress=False)
    config.pipeline.datamanager.dataparser.data = Path(scene_dir)  # benchmark scenes: the method's own parser
    checkpoint_along(config, preset.curve_points)
    extra = ADAPTIVE_OVERRIDES if row.adaptive else ()
    for assignment in (*preset.overrides_for(row.backbone), *extra, *row.overrides):
        apply_override(config, assignment)
    return config


def checkpoint_along(config, points: int) -> int:
    """Have a run write (and keep) a checkpoint every ``max_steps // points`` steps, for evaluating
    error against training time afterwards (:func:`evaluate_checkpoints`); returns that interval."""
    every = max(1, config.max_steps // max(1, points))
    config.checkpoint_every = every
    config.keep_checkpoints = config.max_steps // every + 10  # room for interrupt checkpoints
    return every


def fingerprint(config, evaluation: EvalSettings, out: Path) -> str:
    """A short hash of everything that decides a row's result (paths under ``out`` written relatively,
    so a moved benchmark folder still resumes)."""
    text = config_digest(config).replace(str(Path(out).resolve()), "<out>")
    text += json.dumps(asdict(evaluation), sort_keys=True)
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def evaluate_state(pipeline, state: dict[str, Any], scene_dir: Path, evaluation: EvalSettings) -> dict[str, Any]:
    """``evaluate_run`` of a loaded state; when the run has no mesh to score (no surface, or one that
    encloses nothing) the image metrics are kept and the geometry metrics are NaN, with the reason."""

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*not watertight.*")
        try:
            return evaluate_run(pipeline, state, scene_dir, evaluation.mesh_resolution, evaluation.image_scale,
                                evaluation.max_views, evaluation.n_samples, progress=False)
        except (VAError, ValueError) as exc:
            result = {"method": state.get("method_name"), "steps": int(state["step"]),
                      "train_seconds": float(state.get("train_seconds", 0.0)),
                      "cd": float("nan"), "iou": float("nan"), "fscore": float("nan"), "error": str(exc)}
            result.update(image_metrics(pipeline, evaluation.image_scale, evaluation.max_views, progress=False))
            return result


def evaluate_checkpoints(pipeline, run_dir: Path, scene_dir: Path, evaluation: EvalSettings, every: int,
                         max_steps: int) -> list[dict[str, Any]]:
    """Evaluate the run's checkpoints at multiples of ``every`` (and the last step), oldest first."""
    points = []
    for path in list_checkpoints(run_dir):
        state = torch.load(path, map_location=pipeline.device, weights_only=False)
        step = int(state["step"])
        if step % every and step != max_steps:
            continue  # written on an interrupt, off the schedule
        pipeline.model.load_state_dict(state["model"])
        pipeline.model.update_step(step)
        pipeline.model.eval()
        points.append(evaluate_state(pipeline, state, scene_dir, evaluation))
    return points


def _adaptive_ran(model) -> bool:
    """Whether the run reached the view-adaptive phases (False for original methods and skipped scenes)."""
    return model.field.current_phase > 1


def run_row(row: RowSpec, config, scene_dir: Path, evaluation: EvalSettings, row_fingerprint: str,
            on_interrupt=None) -> dict[str, Any]:
    """Train (or resume) the row's run, evaluate it along the way and at the end; the finished row."""
    run_dir = Path(config.output_dir)
    marker = run_dir / ROW_FILE
    resumable = marker.is_file() and json.loads(marker.read_text()).get("fingerprint") == row_fingerprint
    if not resumable:
        shutil.rmtree(run_dir, ignore_errors=True)
        run_dir.mkdir(parents=True)
        marker.write_text(json.dumps({"key": row.key, "fingerprint": row_fingerprint}))
    try:
        run = train_run(config, resume=resumable)
    except TrainingInterrupted as interrupt:
        if on_interrupt is not None:
            on_interrupt(interrupt.checkpoint)
        raise
    trainer, resumed_from = run.trainer, run.resumed_from
    started = time.perf_counter()
    curve = evaluate_checkpoints(trainer.pipeline, run_dir, scene_dir, evaluation, config.checkpoint_every,
                                 config.max_steps)
    for path in list_checkpoints(run_dir)[:-1]:
        path.unlink()
    final = curve[-1]
    result: dict[str, Any] = {
        "experiment": row.experiment, "key": row.key, "fingerprint": row_fingerprint,
        "scene": row.scene.name, "method": row.method, "backbone": row.backbone, "adaptive": row.adaptive,
        **{name: final.get(name, float("nan")) for name in METRICS},
        "train_seconds": round(final["train_seconds"], 2), "steps": final["steps"],
        "variant": row.label, "level": row.scene.level, "views": row.scene.views, "seed": config.seed,
        "adaptive_ran": _adaptive_ran(trainer.pipeline.model), **input_error(scene_dir),
        "eval_seconds": round(time.perf_counter() - started, 2),
        "source": row.scene.source, "run_dir": str(run_dir), "resumed_from_step": resumed_from,
        "evaluation": {k: final[k] for k in ("image_params", "geometry_params") if k in final},
        "curve": [{"step": p["steps"], "train_seconds": round(p["train_seconds"], 2),
                   **{name: p.get(name, float("nan")) for name in METRICS}} for p in curve],
    }
    problems = [final[k] for k in ("error", "lpips_missing") if k in final]
    if problems:
        result["error"] = "; ".join(problems)
    return result


def run_steps(row: RowSpec, preset: BenchPreset) -> int:
    """The step budget a row will train for (for progress estimates)."""
    if row.steps is not None:
        return row.steps
    if row.backbone in preset.steps:
        return preset.steps[row.backbone]
    return int(get_method(row.method).make_config(row.method_preset or preset.method_preset).max_steps)


def scene_of(source: str, preset: BenchPreset, seed: int, level: int | None = None,
             views: int | None = None, kinds: tuple[str, ...] | None = None) -> SceneSpec:
    """The scene of a source under a preset (its level, views and resolution unless given; every
    inconsistency kind unless ``kinds`` names fewer)."""
    spec = SceneSpec(source, preset.level if level is None else level, preset.views if views is None else views,
                     preset.resolution, seed, preset.scene_mesh_resolution)
    return spec if kinds is None else replace(spec, kinds=tuple(kinds))
