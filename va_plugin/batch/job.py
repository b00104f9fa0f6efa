"""The job of one object: what ``va-train``, ``va-export mesh`` and ``va-eval`` do by hand, in one call.

:func:`run_object` is the one job function of every engine (the engines only decide where and when it
runs). It trains the object's run folder (continuing from its newest checkpoint when a killed batch left
one), loads the finished run back as ``va-export`` and ``va-eval`` do, writes ``mesh.ply`` (vertex
colors), the textured ``mesh.glb`` and ``mesh.obj`` (unless the batch turned textures off), a small grey
picture of the mesh (``thumbnail.png``, for the contact sheet), optionally a turntable of the textured
mesh, and evaluates the run when the object has ground truth. :func:`reconstruct` is that work
(:func:`va_plugin.api.reconstruct`, which ``va-recon`` calls, and the thumbnail); :func:`run_object` wraps
it for a batch: it never raises for a bad object (the record says ``failed`` with the error's one line)
and sends the traceback and everything the job prints to the object's ``batch.log``.
"""

from __future__ import annotations

import os
import time
import traceback
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from va_plugin import api
from va_plugin.data.images import write_image
from va_plugin.engine.run_folder import is_run_folder
from va_plugin.errors import VAError
from va_plugin.export.config import ExportConfig
from va_plugin.export.render import mesh_views

LOG_FILE = "batch.log"
THUMBNAIL_FILE = "thumbnail.png"
METRICS = api.METRICS


@dataclass(frozen=True)
class Evaluation:
    """How an object with ground truth is evaluated (its mesh: the job's :class:`ExportConfig`)."""

    image_scale: float = 1.0
    max_views: int | None = None
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
    options: dict[str, Any]
    """The per-object options (``va-batch``'s ``add_object_options``), as :func:`va_plugin.api.build_config`
    keywords."""
    threads: int = 1
    evaluation: Evaluation = field(default_factory=Evaluation)
    export: ExportConfig = field(default_factory=ExportConfig)
    """The mesh and texture options (``va-export mesh``'s; ``mesh.ply`` stays in the training frame)."""
    turntable_frames: int = 0
    """Frames of a turntable of the textured mesh (``RUN/turntable/``); 0: none."""
    progress: bool = False
    """Progress bars for training, bake and turntable (off in batches, whose jobs log to a file)."""


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    text = text[0] if text else ""
    return text if isinstance(exc, VAError) else f"{type(exc).__name__}: {text}".rstrip(": ")


def failed_record(job: ObjectJob, error: str, seconds: float = 0.0) -> dict[str, Any]:
    """The record of an object whose job could not report itself (its worker died, the engine failed)."""
    return {"name": job.name, "input": str(job.data), "run_dir": str(job.run_dir), "status": "failed",
            "error": error, "seconds": round(seconds, 2)}


def run_object(job: ObjectJob) -> dict[str, Any]:
    """Train, export and evaluate one object; its manifest record (status ``ok`` or ``failed``)."""
    started = time.perf_counter()
    record: dict[str, Any] = {"name": job.name, "input": str(job.data), "run_dir": str(job.run_dir)}
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


def reconstruct(job: ObjectJob, on_message=None) -> dict[str, Any]:
    """Train (or continue) the object's run, then export, picture and evaluate it with
    :func:`va_plugin.api.reconstruct`; the paths and figures of its manifest record. Raises on a bad object
    (:func:`run_object` turns that into a record)."""
    settings = job.evaluation
    result = api.reconstruct(
        job.data, job.run_dir, job.method, views=job.options.get("views") or "all", export=job.export,
        turntable_frames=job.turntable_frames, threads=job.threads, show_progress=job.progress,
        on_message=on_message, resume=is_run_folder(job.run_dir),  # continue an interrupted object
        overwrite=True,  # runs/<name> is the batch's own (its batch.log)
        evaluate_options={
            "image_scale": settings.image_scale, "max_views": settings.max_views, "n_samples": settings.n_samples},
        **{name: value for name, value in job.options.items() if name != "views"})
    dropped = ("input", "method", "quality", "seconds", "mesh_frame")  # the frame: in the run's summary.json
    out = {key: value for key, value in result.record.items() if key not in dropped}
    out["thumbnail"] = str(write_thumbnail(result.files.mesh, job))
    return out


def write_thumbnail(mesh, job: ObjectJob) -> Path:
    """Grey shaded views of the mesh side by side (geometry only), for the contact sheet."""
    path = Path(job.run_dir) / THUMBNAIL_FILE
    write_image(path, mesh_views([mesh], job.evaluation.thumbnail_views, job.evaluation.thumbnail_resolution))
    return path
