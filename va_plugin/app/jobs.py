"""The page's jobs: one job folder each, trained by :func:`va_plugin.api.reconstruct` in a child process.

A job folder holds ``input/`` (a copy of the upload's input, so that the run resumes on its own),
``app.json`` (the job's options), ``previews/``, and ``run/``, the run folder ``va-recon`` would write
(outside it, as the input must be).

A job's child (multiprocessing, spawn) reports over a queue: ``started``, ``message`` (the stage lines),
``progress`` (step, total, seconds left, loss; at most twice a second), ``preview`` (a render of the
first training view beside that view, every ``preview_every`` steps), then one final ``done``,
``cancelled`` or ``error``. :meth:`Job.cancel` sends the child SIGINT: the trainer saves a checkpoint and
the run folder can be resumed (the page's Resume, or the ``va-recon ... --resume`` line of
:func:`resume_command`). A crash or an out-of-memory kill ends the child, not the server. The
:class:`Launcher` keeps one child started ahead, so a job does not wait for the imports.
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import os
import queue
import re
import shlex
import shutil
import signal
import threading
import time
import traceback
import warnings
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import cv2
import torch

from va_plugin.api import TrainingInterrupted, reconstruct
from va_plugin.app.settings import AppSettings, RunOptions
from va_plugin.app.uploads import Upload
from va_plugin.callbacks import AFTER_STEP, TrainingCallback, TrainingCallbackAttributes
from va_plugin.data.images import resize, write_image
from va_plugin.engine.trainer import list_checkpoints
from va_plugin.errors import VAError
from va_plugin.export.render import render_view
from va_plugin.utils.files import write_atomic
from va_plugin.utils.interrupts import terminate_as_interrupt

SPEC_FILE = "app.json"
INPUT_DIR = "input"
RUN_DIR = "run"
PREVIEW_DIR = "previews"
LOG_FILE = "app.log"
OBJ_FILES = ("mesh.obj", "mesh.mtl")
OBJ_BUNDLE = "mesh_obj.zip"
BROWSER_VIDEO = "turntable.webm"
FINAL = ("done", "cancelled", "error")
PROGRESS_EVERY_S = 0.5

Send = Callable[[dict[str, Any]], None]


@dataclass
class JobSpec:
    """One job: its folder, its input (a copy in the folder), and every option of the reconstruction."""

    job_dir: str
    input: str
    name: str
    """The upload's file name."""
    quality: str
    views: int | str
    options: RunOptions = field(default_factory=RunOptions)
    resume: bool = False

    @property
    def run_dir(self) -> str:
        return str(Path(self.job_dir) / RUN_DIR)

    def save(self) -> Path:
        record = dataclasses.asdict(self)
        record.pop("resume")
        return write_atomic(Path(self.job_dir) / SPEC_FILE, json.dumps(record, indent=2) + "\n")

    @classmethod
    def load(cls, job_dir: str | Path) -> JobSpec:
        return cls.from_dict(json.loads((Path(job_dir) / SPEC_FILE).read_text(encoding="utf-8")))

    @classmethod
    def from_dict(cls, record: dict[str, Any]) -> JobSpec:
        return cls(**{**record, "options": RunOptions(**record["options"])})


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", text).strip("-.")[:60] or "upload"


def new_job_dir(root: Path, name: str) -> Path:
    """A fresh folder ``ROOT/<date>-<time>-<name>`` (``-2``, ``-3``... when taken)."""
    stem = f"{datetime.now():%Y%m%d-%H%M%S}-{_slug(Path(name).stem)}"
    root.mkdir(parents=True, exist_ok=True)
    for count in range(1, 1000):
        path = root / (stem if count == 1 else f"{stem}-{count}")
        try:
            path.mkdir()
            return path
        except FileExistsError:
            continue
    raise VAError(f"no free job folder name under {root} for {stem}")


def prepare_job(upload: Upload, settings: AppSettings, quality: str, views: int | str) -> JobSpec:
    """A fresh job folder with a copy of the upload's input and ``app.json``, the job's options."""
    job_dir = new_job_dir(Path(settings.runs), upload.name)
    target = job_dir / INPUT_DIR / upload.path.name
    if upload.path.is_dir():
        shutil.copytree(upload.path, target)
    else:
        target.parent.mkdir(parents=True)
        shutil.copyfile(upload.path, target)
    spec = JobSpec(job_dir=str(job_dir), input=str(target), name=upload.name, quality=quality, views=views,
                   options=settings.run_options())
    spec.save()
    return spec


def resume_command(spec: JobSpec) -> str:
    """The ``va-recon`` line that continues the job's run folder."""
    options, defaults = spec.options, RunOptions()
    words = ["va-recon", spec.input, "--out", spec.run_dir, "--method", options.method, "--quality", spec.quality]
    if spec.views != "all":
        words += ["--views", str(spec.views)]
    for flag, name in (("--steps", "steps"), ("--device", "device"), ("--texture-size", "texture_size"),
                       ("--mesh-resolution", "mesh_resolution"), ("--turntable-frames", "turntable_frames")):
        if getattr(options, name) != getattr(defaults, name):
            words += [flag, str(getattr(options, name))]
    for assignment in options.overrides:
        words += ["--set", assignment]
    return shlex.join([*words, "--resume"])


# -- the child's side ---------------------------------------------------------------------------------
class ProgressReport:
    """``progress(step, total, losses)`` for :func:`~va_plugin.api.reconstruct`: a ``progress`` message at
    most every :data:`PROGRESS_EVERY_S` seconds and at the last step, with the seconds left at this
    session's pace."""

    def __init__(self, send: Send) -> None:
        self.send = send
        self.first: tuple[float, int] | None = None
        self.last = 0.0

    def __call__(self, step: int, total: int, losses: dict[str, float]) -> None:
        now = time.perf_counter()
        if self.first is None:
            self.first = (now, step - 1)
        if step < total and now - self.last < PROGRESS_EVERY_S:
            return
        self.last = now
        began, done_before = self.first
        pace = (now - began) / max(step - done_before, 1)
        self.send({"kind": "progress", "step": step, "total": total, "left": round(pace * (total - step), 1),
                   "loss": losses.get("loss")})


def render_preview(pipeline, path: Path, size: int) -> Path:
    """The first training view and the field's render of it, side by side, at most ``size`` px high,
    written to ``path``. The random generators are put back as they were, so training goes on as it
    would have."""
    train = pipeline.datamanager.train
    cameras = train.cameras
    factor = min(1.0, size / max(cameras.width, cameras.height))
    cameras = cameras.scaled(factor) if factor < 1.0 else cameras
    devices = [pipeline.device] if pipeline.device.type == "cuda" else []
    with torch.random.fork_rng(devices=devices):
        render = render_view(pipeline.model, cameras, 0)
    view = resize(train.images[0].detach().cpu().numpy()[..., :3], cameras.width, cameras.height)
    write_image(path, cv2.hconcat([view, render.astype(view.dtype)]))
    return path


def preview_callback(job_dir: Path, every: int, size: int, send: Send) -> TrainingCallback:
    """A training callback that writes ``JOB/previews/step-N.png`` every ``every`` steps (not at the last,
    which the mesh follows) and sends a ``preview`` message."""

    def preview(step: int, attributes: TrainingCallbackAttributes) -> None:
        done = step + 1
        if done % every == 0 and done < attributes.max_steps:
            path = render_preview(attributes.pipeline, job_dir / PREVIEW_DIR / f"step-{done:06d}.png", size)
            send({"kind": "preview", "step": done, "path": str(path)})

    return TrainingCallback(preview, where=AFTER_STEP, every=1)


def browser_video(mp4: Path) -> Path | None:
    """A WebM (VP8) copy of an MP4 beside it, which browsers play (the MP4's mp4v codec they do not);
    None when OpenCV cannot write one."""
    capture = cv2.VideoCapture(str(mp4))
    fps = capture.get(cv2.CAP_PROP_FPS) or 12.0
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(frame)
    capture.release()
    if not frames:
        return None
    path = Path(mp4).with_name(BROWSER_VIDEO)
    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"VP80"), fps, (width, height))
    if not writer.isOpened():
        return None
    for frame in frames:
        writer.write(frame)
    writer.release()
    return path if path.is_file() and path.stat().st_size > 0 else None


def obj_bundle(run_dir: Path, into: Path) -> Path | None:
    """``INTO/mesh_obj.zip``: the run's OBJ export with its material and the textures that names, when the
    run has ``mesh.obj``; else None."""
    run_dir = Path(run_dir)
    if not (run_dir / OBJ_FILES[0]).is_file():
        return None
    files = [run_dir / name for name in OBJ_FILES if (run_dir / name).is_file()]
    material = run_dir / OBJ_FILES[1]
    if material.is_file():
        for line in material.read_text(encoding="utf-8", errors="replace").splitlines():
            words = line.split()
            if len(words) >= 2 and words[0].lower().startswith("map_") and (run_dir / words[-1]).is_file():
                files.append(run_dir / words[-1])
    path = Path(into) / OBJ_BUNDLE
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as bundle:
        for file in dict.fromkeys(files):
            bundle.write(file, file.name)
    return path


def _show_warning(send: Send):
    def show(message, category, filename, lineno, file=None, line=None) -> None:
        send({"kind": "message", "line": f"warning: {message}"})
    return show


def run_job(spec: JobSpec, send: Send) -> None:
    """Run one job in this process, reporting through ``send``; ends with one final message."""
    job_dir, run_dir, options = Path(spec.job_dir), Path(spec.run_dir), spec.options
    try:
        send({"kind": "started", "pid": os.getpid()})
        warnings.showwarning = _show_warning(send)
        callbacks = [preview_callback(job_dir, options.preview_every, options.preview_size, send)] \
            if options.preview_every > 0 else []
        result = reconstruct(spec.input, run_dir, method=options.method, quality=spec.quality, views=spec.views,
                             steps=options.steps, device=options.device, progress=ProgressReport(send),
                             on_message=lambda line: send({"kind": "message", "line": line}),
                             callbacks=callbacks, resume=spec.resume, export=options.export(),
                             turntable_frames=options.turntable_frames,
                             threads=options.threads, overrides=list(options.overrides))
        record = dict(result.record)
        video = browser_video(result.turntable) if result.turntable is not None else None
        bundle = obj_bundle(run_dir, job_dir)
        record.update(run_dir=str(run_dir), job_dir=str(job_dir), webm=None if video is None else str(video),
                      obj_zip=None if bundle is None else str(bundle))
        send({"kind": "done", "record": record})
    except TrainingInterrupted as stop:
        send({"kind": "cancelled", "step": stop.step, "checkpoint": str(stop.checkpoint)})
    except KeyboardInterrupt:  # before training began, or after it ended (the mesh, the texture)
        saved = list_checkpoints(run_dir)
        send({"kind": "cancelled", "step": None, "checkpoint": str(saved[-1]) if saved else None})
    except VAError as exc:
        send({"kind": "error", "message": str(exc)})
    except Exception as exc:  # anything else: one line on the page, the traceback in the run folder
        log = job_dir / LOG_FILE
        with open(log, "a", encoding="utf-8") as handle:
            handle.write(traceback.format_exc())
        first = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else ""
        send({"kind": "error", "message": f"the job failed ({type(exc).__name__}{': ' + first if first else ''}); "
                                          f"the details are in {log}"})


def child_main(inbox, outbox) -> None:
    """A job process: wait for one spec (None: nothing to do), run it, exit; exit too when the server
    is gone. The child is a process group of its own, so that a Ctrl-C in the server's terminal does not
    reach it: the server sends its one SIGINT (a second one would cut the checkpoint's writing). SIGINT
    is Python's own here (a server started in the background would pass on an ignored one), SIGTERM
    taken like it."""
    os.setpgrp()
    signal.signal(signal.SIGINT, signal.default_int_handler)
    server = os.getppid()
    record = None
    while record is None:
        try:
            record = inbox.get(timeout=1.0)
            if record is None:
                return
        except queue.Empty:
            if os.getppid() != server:
                return
        except KeyboardInterrupt:
            return
    with terminate_as_interrupt():
        try:
            run_job(JobSpec.from_dict(record), outbox.put)
        except KeyboardInterrupt:  # a second Ctrl-C while the first was being handled
            outbox.put({"kind": "cancelled", "step": None, "checkpoint": None})
    outbox.close()
    outbox.join_thread()


# -- the server's side --------------------------------------------------------------------------------
@dataclass
class _Child:
    process: Any
    inbox: Any
    outbox: Any


class Job:
    """A job running in its child: its messages, and a way to stop it."""

    def __init__(self, child: _Child, spec: JobSpec, on_end: Callable[[], None]) -> None:
        self.child, self.spec, self._on_end = child, spec, on_end
        self._lock = threading.Lock()
        self._started = self._cancel_asked = self._signalled = self.ended = False

    def _signal(self) -> None:
        """SIGINT once, when the child runs the job and a cancel was asked (lock held)."""
        if self._started and self._cancel_asked and not self._signalled and self.child.process.is_alive():
            os.kill(self.child.process.pid, signal.SIGINT)
            self._signalled = True

    def cancel(self) -> bool:
        """Ask the job to stop (it saves a checkpoint); False when it has already ended."""
        with self._lock:
            if self.ended:
                return False
            self._cancel_asked = True
            self._signal()
            return True

    def stop(self, timeout: float = 120.0) -> None:
        """Cancel, and wait for the child to save its checkpoint and exit, reading what it still sends."""
        self.cancel()
        deadline = time.monotonic() + timeout
        while self.child.process.is_alive() and time.monotonic() < deadline:
            try:
                self.child.outbox.get(timeout=0.5)
            except queue.Empty:
                continue

    @property
    def cancel_asked(self) -> bool:
        return self._cancel_asked

    def messages(self, poll: float = 0.5) -> Iterator[dict[str, Any]]:
        """The child's messages until its final one; a child that dies without one gives an ``error``."""
        try:
            while True:
                try:
                    message = self.child.outbox.get(timeout=poll)
                except queue.Empty:
                    if self.child.process.is_alive():
                        continue
                    try:
                        message = self.child.outbox.get(timeout=1.0)
                    except queue.Empty:
                        code = self.child.process.exitcode
                        how = f"exit status {code}" if code is None or code >= 0 else (
                            "killed: out of memory?" if code == -signal.SIGKILL else f"signal {-code}")
                        yield {"kind": "error", "message": f"the job's process ended without a result ({how}); "
                                                           f"{self.spec.job_dir} keeps what it saved"}
                        return
                if message["kind"] == "started":
                    with self._lock:
                        self._started = True
                        self._signal()
                    continue
                yield message
                if message["kind"] in FINAL:
                    return
        finally:
            with self._lock:
                self.ended = True
            self.child.process.join(timeout=30)
            if self.child.process.is_alive():
                self.child.process.terminate()
            self._on_end()


class Launcher:
    """Starts jobs in child processes, with one child started ahead (``warm``) so that a job begins at
    once; a child runs one job and exits."""

    def __init__(self, warm: bool = True) -> None:
        self._context = multiprocessing.get_context("spawn")
        self._warm = warm
        self._lock = threading.Lock()
        self._spare: _Child | None = None
        self._closed = False
        if warm:
            self._spare = self._new_child()

    def _new_child(self) -> _Child:
        inbox, outbox = self._context.Queue(), self._context.Queue()
        process = self._context.Process(target=child_main, args=(inbox, outbox), name="va-app-job")
        process.start()
        return _Child(process, inbox, outbox)

    def start(self, spec: JobSpec) -> Job:
        with self._lock:
            child, self._spare = self._spare, None
        if child is None or not child.process.is_alive():
            child = self._new_child()
        child.inbox.put(dataclasses.asdict(spec))
        return Job(child, spec, self._refill)

    def _refill(self) -> None:
        with self._lock:
            if self._warm and not self._closed and self._spare is None:
                self._spare = self._new_child()

    def close(self) -> None:
        """Let the waiting child go (running jobs are the caller's to cancel)."""
        with self._lock:
            self._closed = True
            spare, self._spare = self._spare, None
        if spare is not None:  # it holds no job: no need to wait for its imports to end
            spare.process.terminate()
            spare.process.join(timeout=10)
