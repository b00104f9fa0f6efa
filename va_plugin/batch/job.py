"""The job of one object: what ``va-train``, ``va-export mesh`` and ``va-eval`` do by hand, in one call.

:func:`run_object` is the one job function of every engine (the engines only decide where and when it
runs). It trains the object's run folder (continuing from its newest checkpoint when a killed batch left
one), loads the finished run back as ``va-export`` and ``va-eval`` do, writes ``mesh.ply`` (vertex
colours), the textured ``mesh.glb`` (unless the batch turned textures off), a small grey picture of the
mesh (``thumbnail.png``, for the contact sheet), optionally a turntable of the textured mesh, and evaluates
the run when the object has ground truth. :func:`reconstruct` is that work (``va-recon`` calls it with
progress bars); :func:`run_object` wraps it for a batch: it never raises for a bad object (the record says
``failed`` with the error's one line) and sends the traceback and everything the job prints to the
object's ``batch.log``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import traceback
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Optional, Tuple

LOG_FILE = "batch.log"
MESH_FILE = "mesh.ply"
TEXTURED_MESH_FILE = "mesh.glb"
THUMBNAIL_FILE = "thumbnail.png"
TURNTABLE_DIR = "turntable"
METRICS = ("cd", "iou", "fscore", "psnr", "ssim", "lpips")


@dataclass(frozen=True)
class Evaluation:
    """How an object with ground truth is evaluated, and how its mesh is extracted."""

    mesh_resolution: int = 128
    image_scale: float = 1.0
    max_views: Optional[int] = None
    n_samples: int = 100_000
    """Surface samples per mesh for the Chamfer distance and F-score (va-eval's 100k by default)."""
    thumbnail_views: int = 2
    thumbnail_resolution: int = 96


@dataclass(frozen=True)
class ObjectJob:
    """Everything one object's job needs (plain values: it travels to worker processes and Ray nodes)."""

    name: str
    data: Path
    run_dir: Path
    method: str
    options: Dict[str, Any]
    """va-train's per-object options (``add_object_options``), by their argparse names."""
    threads: int = 1
    evaluation: Evaluation = field(default_factory=Evaluation)
    texture_size: int = 0
    """Side of the baked texture (``va-export mesh --texture``); 0: vertex colours only."""
    fusion: str = "robust"
    """How the texture fuses disagreeing views (``va-export mesh --fusion``)."""
    turntable_frames: int = 0
    """Frames of a turntable of the textured mesh (``RUN/turntable/``); 0: none."""
    progress: bool = False
    """Progress bars for training, bake and turntable (off in batches, whose jobs log to a file)."""


def _one_line(exc: BaseException) -> str:
    from va_plugin.errors import VAError

    text = str(exc).strip().splitlines()
    text = text[0] if text else ""
    return text if isinstance(exc, VAError) else f"{type(exc).__name__}: {text}".rstrip(": ")


def failed_record(job: ObjectJob, error: str, seconds: float = 0.0) -> Dict[str, Any]:
    """The record of an object whose job could not report itself (its worker died, the engine failed)."""
    return {"name": job.name, "input": str(job.data), "run_dir": str(job.run_dir), "status": "failed",
            "error": error, "seconds": round(seconds, 2)}


def run_object(job: ObjectJob) -> Dict[str, Any]:
    """Train, export and evaluate one object; its manifest record (status ``ok`` or ``failed``)."""
    started = time.perf_counter()
    record: Dict[str, Any] = {"name": job.name, "input": str(job.data), "run_dir": str(job.run_dir)}
    Path(job.run_dir).mkdir(parents=True, exist_ok=True)
    with open(Path(job.run_dir) / LOG_FILE, "a", encoding="utf-8") as log, redirect_stdout(log), \
            redirect_stderr(log):
        print(f"--- {time.strftime('%Y-%m-%d %H:%M:%S')} {job.method} on {job.data} (pid {os.getpid()})")
        try:
            record.update(reconstruct(job))
            record["status"] = "ok"
        except Exception as exc:  # a bad object is recorded, the batch goes on
            traceback.print_exc()
            record.update(status="failed", error=_one_line(exc))
    record["seconds"] = round(time.perf_counter() - started, 2)
    return record


def train_config(job: ObjectJob):
    """The object's trainer config, made from its options exactly as va-train makes it."""
    from va_plugin.cli.train import make_config
    from va_plugin.registry import discover_methods

    args = argparse.Namespace(**{"masks": None, **job.options}, method=job.method, data=Path(job.data),
                              output_dir=Path(job.run_dir), no_progress=not job.progress, default_scene_resolution=None)
    config = make_config(args, discover_methods())
    config.num_threads = job.threads
    return config


def reconstruct(job: ObjectJob, on_resume=None) -> Dict[str, Any]:
    """Train (or continue) the object's run, then export, picture and evaluate it; the paths and figures.
    Raises on a bad object (:func:`run_object` turns that into a record). ``on_resume(step)`` is called
    when the run continues from a checkpoint."""
    import torch

    from va_plugin.cli.run import load_run
    from va_plugin.engine.trainer import train_run

    if job.threads > 0:
        torch.set_num_threads(job.threads)
    # a Ctrl-C in a batch run in this process leaves a checkpoint: --resume continues from there
    resumed_from = train_run(train_config(job), resume=True, on_resume=on_resume).resumed_from
    # what va-export and va-eval see: the run as its last checkpoint holds it
    pipeline, state = load_run(Path(job.run_dir), device=job.options.get("device"))
    mesh, textured, paths = export_mesh(pipeline, job)
    train = pipeline.datamanager.train
    out: Dict[str, Any] = {"steps": int(state["step"]), "train_seconds": round(float(state["train_seconds"]), 2),
                           "views": len(train), "masks": train.metadata.get("mask_source", "scene's alpha"),
                           **paths, "resumed_from_step": resumed_from}
    out["thumbnail"] = str(write_thumbnail(mesh, job))
    if job.turntable_frames and textured is not None:
        from va_plugin.eval.mesh_render import textured_turntable

        out["turntable"] = str(textured_turntable(textured, Path(job.run_dir) / TURNTABLE_DIR, job.turntable_frames,
                                                  progress=job.progress))
    out.update(evaluate(pipeline, state, mesh, job))
    return out


def say(job: ObjectJob, text: str) -> None:
    """A stage line on stderr for a job that shows progress (``va-recon``)."""
    if job.progress:
        print(text, file=sys.stderr, flush=True)


def export_mesh(pipeline, job: ObjectJob) -> Tuple[Any, Any, Dict[str, str]]:
    """The run's mesh as ``va-export mesh`` writes it: ``RUN/mesh.ply`` with vertex colours from the
    canonical colour path, and with a texture size also ``RUN/mesh.glb`` (``va-export mesh --texture``:
    UV atlas, texture baked from the input views; ``mesh_bake.png`` and ``mesh_bake.json`` beside it).
    Returns the mesh, the textured mesh (None without a texture) and the paths written."""
    from va_plugin.export.mesh import extract_mesh, write_mesh

    say(job, f"extracting the mesh ({job.evaluation.mesh_resolution}^3 grid)")
    mesh = extract_mesh(pipeline.model, resolution=job.evaluation.mesh_resolution)
    paths = {"mesh": str(write_mesh(mesh, Path(job.run_dir) / MESH_FILE))}
    textured = None
    if job.texture_size:
        from va_plugin.export.texture import texture_run_mesh

        say(job, f"UV-unwrapping the mesh and baking a {job.texture_size}^2 texture from the views")
        textured, _, written = texture_run_mesh(pipeline, mesh, Path(job.run_dir) / TEXTURED_MESH_FILE,
                                                job.texture_size, job.fusion, progress=job.progress)
        paths["textured_mesh"] = str(written[0])
    return mesh, textured, paths


def write_thumbnail(mesh, job: ObjectJob) -> Path:
    """Grey shaded views of the mesh side by side (geometry only), for the contact sheet."""
    from va_plugin.data.images import write_image
    from va_plugin.export.render import mesh_views

    path = Path(job.run_dir) / THUMBNAIL_FILE
    write_image(path, mesh_views([mesh], job.evaluation.thumbnail_views, job.evaluation.thumbnail_resolution))
    return path


def evaluate(pipeline, state: Dict[str, Any], mesh, job: ObjectJob) -> Dict[str, Any]:
    """va-eval's metrics when the object has ground truth, also written to ``RUN/eval.json``; ``{}`` when
    it has none. Ground truth is a scene folder's: its held-out views and the mesh its scene.json names.
    A generator output's other views are not ground truth (they are generated too), so those objects
    get no metrics."""
    from va_plugin.data.dataparsers.transforms import TransformsDataParserConfig
    from va_plugin.eval.evaluate import evaluate_run, ground_truth_mesh_path

    scene = isinstance(state["config_object"].pipeline.datamanager.dataparser, TransformsDataParserConfig)
    if not scene or (pipeline.datamanager.test is None and ground_truth_mesh_path(pipeline) is None):
        return {}
    settings = job.evaluation
    result = evaluate_run(pipeline, state, None, settings.mesh_resolution, settings.image_scale,
                          settings.max_views, settings.n_samples, progress=False, mesh=mesh)
    path = Path(job.run_dir) / "eval.json"
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(result, indent=2))
    tmp.replace(path)
    return {name: result[name] for name in METRICS if name in result}
