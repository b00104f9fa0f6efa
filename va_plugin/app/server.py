"""The page of ``va-app`` (Gradio): drop a file, see what it holds, train, turn the result.

Endpoints (what the page's buttons call, and what ``gradio_client`` can call): ``/inspect`` (an upload:
its format, views and masks), ``/reinspect`` (the same upload with another quality or view count),
``/run`` (a job on the staged upload: progress, previews, then the mesh, the video and the files),
``/resume`` (the session's stopped run, continued), ``/cancel`` (stop the session's job; it saves a
checkpoint). Runs queue and train one at a time; inspecting and cancelling never wait for them.
"""

from __future__ import annotations

import shutil
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gradio as gr

from va_plugin.api import QUALITIES
from va_plugin.app.jobs import JobSpec, Launcher, prepare_job, resume_command
from va_plugin.app.settings import AppSettings
from va_plugin.app.uploads import VIEW_CHOICES, Upload, inspect_upload, parse_views, stage_upload
from va_plugin.engine.trainer import list_checkpoints
from va_plugin.errors import VAError
from va_plugin.export.files import MESH_FILE, TEXTURED_MESH_FILE

TITLE = "va-plugin: generator output to textured mesh"
INTRO = ("Drop a **SyncDreamer strip** or a **Zero123++ grid** (PNG), or a **zip** of a Wonder3D folder or of a "
         "folder with `transforms.json`. The views and the masks found in them show before any training; "
         "**Start** trains, **Cancel** stops with a checkpoint that **Resume** continues.")
PREVIEW_LABEL = "training view 0 (left) and the field's render of it (right)"


def _duration(seconds: float) -> str:
    seconds = max(0, round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    minutes, seconds = divmod(seconds, 60)
    return f"{minutes} min {seconds:02d} s" if minutes < 60 else f"{minutes // 60} h {minutes % 60:02d} min"


NO_UPLOAD = "Upload a file to begin."


def _problem(text: str) -> str:
    return f"**Cannot use this upload.** {text}"


class Status:
    """The status box of a job: the run, the training line, the stage lines, the ending."""

    def __init__(self, spec: JobSpec) -> None:
        views = "all views" if spec.views == "all" else f"{spec.views} views"
        self.job_dir = spec.job_dir
        self.head = f"**Run** `{spec.job_dir}`: {spec.options.method}, {spec.quality} quality, {views}"
        self.training = ""
        self.lines: list[str] = []
        self.ending = ""

    def add(self, line: str) -> None:
        """A stage line, with the job folder's paths shown relative to it."""
        self.lines.append(line.replace(f"{self.job_dir}/", "").replace(self.job_dir, "the job folder"))

    def progress(self, message: dict[str, Any], cancelling: bool) -> None:
        step, total = message["step"], message["total"]
        loss = message.get("loss")
        text = f"**Training** step {step} / {total} ({100 * step // max(total, 1)}%)"
        if step < total:
            text += f", about {_duration(message['left'])} left"
        if loss is not None:
            text += f", loss {loss:.4f}"
        self.training = text + (" (cancelling: a checkpoint is being saved)" if cancelling else "")

    def text(self) -> str:
        parts = [self.head]
        if self.training:
            parts.append(self.training)
        parts.extend(f"- {line}" for line in self.lines[-8:])
        if self.ending:
            parts.append(self.ending)
        return "\n\n".join(parts)


class App:
    """The page's handlers, with the staging folder, the job launcher and the sessions' jobs."""

    def __init__(self, settings: AppSettings) -> None:
        self.settings = settings
        self.staging = Path(tempfile.mkdtemp(prefix="va-app-uploads-"))
        self.launcher = Launcher(warm=settings.warm_worker)
        self.lock = threading.Lock()
        self.running: dict[str, Any] = {}
        self.staged: dict[str, Upload] = {}
        self.claimed: dict[str, Upload] = {}  # the upload a session's queued run will train on
        self.waiting: set[str] = set()
        self.cancel_waiting: set[str] = set()

    def close(self) -> None:
        """Stop the running jobs (each saves its checkpoint), let the waiting child go, drop the uploads."""
        with self.lock:
            jobs = list(self.running.values())
        for job in jobs:
            job.stop()
        self.launcher.close()
        shutil.rmtree(self.staging, ignore_errors=True)

    # -- uploads ----------------------------------------------------------------------------------
    def _drop_upload(self, session: str) -> None:
        """The session's staged upload goes (its files stay while a queued run still needs them)."""
        with self.lock:
            upload = self.staged.pop(session, None)
            keep = upload is not None and upload is self.claimed.get(session)
        if upload is not None and not keep:
            upload.discard()

    def _take_claim(self, session: str) -> Upload | None:
        """The upload the session's run was queued with (else the one staged now), claimed no longer."""
        with self.lock:
            return self.claimed.pop(session, None) or self.staged.get(session)

    def _release(self, session: str, upload: Upload | None) -> None:
        """Discard a claimed upload that is no longer the session's staged one."""
        with self.lock:
            stale = upload is not None and self.staged.get(session) is not upload
        if stale:
            upload.discard()

    def _inspect(self, upload: Upload, quality: str, views: str, state: dict) -> tuple[str, list, dict]:
        try:
            inspection, used = inspect_upload(upload, self.settings.method, quality, parse_views(views))
        except VAError as exc:
            return _problem(str(exc)), [], {**state, "format": None}
        text = "**Detected** " + inspection.summary().replace("\n", "\n\n")
        return text, inspection.gallery, {**state, "format": inspection.format, "views": used}

    def inspect(self, file: str | None, quality: str, views: str, state: dict | None,
                request: gr.Request) -> tuple[str, list, dict]:
        """An upload taken in and read: what it holds, or one line on what is wrong with it."""
        state = {**(state or {}), "format": None}
        self._drop_upload(request.session_hash)
        if file is None:
            return NO_UPLOAD, [], state
        try:
            upload = stage_upload(file, self.staging, self.settings.max_upload_bytes)
        except VAError as exc:
            return _problem(str(exc)), [], state
        with self.lock:
            self.staged[request.session_hash] = upload
        return self._inspect(upload, quality, views, state)

    def reinspect(self, quality: str, views: str, state: dict | None, request: gr.Request) -> tuple[str, list, dict]:
        """The staged upload read again with another quality or view count."""
        state = dict(state or {})
        upload = self.staged.get(request.session_hash)
        if upload is None:
            return NO_UPLOAD, [], state
        return self._inspect(upload, quality, views, state)

    def forget(self, state: dict | None, request: gr.Request) -> tuple[str, list, dict]:
        """The upload box was cleared: the staged upload goes."""
        self._drop_upload(request.session_hash)
        return NO_UPLOAD, [], {**(state or {}), "format": None}

    def leave(self, request: gr.Request) -> None:
        """The page was closed: its run stops with a checkpoint (resumable), its upload goes."""
        with self.lock:
            job = self.running.get(request.session_hash)
        if job is not None:
            job.cancel()
        self._drop_upload(request.session_hash)

    # -- jobs -------------------------------------------------------------------------------------
    def ask(self, request: gr.Request) -> None:
        """The page's Start or Resume was clicked: the run may wait in the queue now."""
        with self.lock:
            self.waiting.add(request.session_hash)
            self.cancel_waiting.discard(request.session_hash)
            upload = self.staged.get(request.session_hash)
            if upload is not None:  # a newer upload while the run waits must not change or delete its input
                self.claimed[request.session_hash] = upload

    def cancel(self, request: gr.Request) -> str:
        """Stop the session's job (it saves a checkpoint), or keep its queued run from starting."""
        session = request.session_hash
        with self.lock:
            job = self.running.get(session)
            if job is None and session in self.waiting:
                self.cancel_waiting.add(session)
                return "The run waiting in the queue will not start."
        if job is not None and job.cancel():
            return "Cancelling: the run stops at the next step and saves a checkpoint."
        return "Nothing is running."

    def _empty(self, state: dict, text: str) -> tuple:
        return text, None, None, None, None, state

    def run(self, quality: str, views: str, state: dict | None, request: gr.Request) -> Iterator[tuple]:
        """A job on the staged upload, followed to its end."""
        state = dict(state or {})
        upload = self._take_claim(request.session_hash)
        try:
            if not self._begin(request.session_hash):
                yield self._empty(state, "Cancelled before it started.")
                return
            if upload is None or not state.get("format"):
                self._end(request.session_hash)
                yield self._empty(state, "Upload a file first." if upload is None else
                                  "This upload cannot be used (see above); upload another.")
                return
            try:
                if quality not in QUALITIES:
                    raise VAError(f"quality {quality!r} is not one of {', '.join(QUALITIES)}")
                chosen = parse_views(views)
                spec = prepare_job(upload, self.settings, quality,
                                   chosen if state.get("format") == "syncdreamer" else "all")
            except (VAError, OSError) as exc:
                self._end(request.session_hash)
                yield self._empty(state, _problem(upload.tell(str(exc))))
                return
        finally:
            self._release(request.session_hash, upload)
        yield from self._follow(spec, state, request.session_hash)

    def resume(self, state: dict | None, request: gr.Request) -> Iterator[tuple]:
        """The session's stopped run, continued from its checkpoint."""
        state = dict(state or {})
        self._release(request.session_hash, self._take_claim(request.session_hash))
        if not self._begin(request.session_hash):
            yield self._empty(state, "Cancelled before it started.")
            return
        job_dir = state.get("stopped")
        spec = JobSpec.load(job_dir) if job_dir else None
        if spec is None or not list_checkpoints(Path(spec.run_dir)):
            self._end(request.session_hash)
            yield self._empty(state, "No stopped run with a checkpoint to resume in this session.")
            return
        spec.resume = True
        yield from self._follow(spec, state, request.session_hash)

    def _begin(self, session: str) -> bool:
        """The session's run leaves the queue: False when it was cancelled while it waited."""
        with self.lock:
            self.waiting.discard(session)
            if session in self.cancel_waiting:
                self.cancel_waiting.discard(session)
                return False
            return True

    def _end(self, session: str) -> None:
        with self.lock:
            self.running.pop(session, None)

    def _follow(self, spec: JobSpec, state: dict, session: str) -> Iterator[tuple]:
        began = time.perf_counter()
        status = Status(spec)
        state = {**state, "job": spec.job_dir, "stopped": None}
        job = self.launcher.start(spec)
        with self.lock:
            self.running[session] = job
        preview = None
        status.add("starting (the run continues from its checkpoint)" if spec.resume else "starting")
        yield status.text(), preview, None, None, None, state
        messages = job.messages()
        try:
            for message in messages:
                kind = message["kind"]
                if kind == "message":
                    status.add(message["line"])
                elif kind == "progress":
                    status.progress(message, job.cancel_asked)
                elif kind == "preview":
                    preview = gr.update(value=message["path"], label=f"Preview at step {message['step']}: "
                                                                     f"{PREVIEW_LABEL}")
                elif kind == "done":
                    yield self._done(status, message["record"], began, preview, state)
                    return
                elif kind == "cancelled":
                    state["stopped"] = spec.job_dir if list_checkpoints(Path(spec.run_dir)) else None
                    status.ending = self._stopped_text(spec, message, state["stopped"] is not None)
                elif kind == "error":
                    state["stopped"] = spec.job_dir if list_checkpoints(Path(spec.run_dir)) else None
                    status.ending = f"**Failed.** {message['message']}"
                yield status.text(), preview, None, None, None, state
        except GeneratorExit:  # Gradio let go of the event: the run stops with a checkpoint, not orphaned
            threading.Thread(target=lambda: (job.stop(), messages.close()), daemon=True).start()
            raise
        finally:
            self._end(session)

    def _stopped_text(self, spec: JobSpec, message: dict, resumable: bool) -> str:
        where = f" at step {message['step']}" if message.get("step") is not None else ""
        if not resumable:
            return f"**Cancelled**{where}, before any checkpoint; Start begins afresh."
        return (f"**Cancelled**{where}; the checkpoint `{message.get('checkpoint') or 'of the run'}` is saved. "
                f"**Resume** continues the run, as does\n\n`{resume_command(spec)}`")

    def _done(self, status: Status, record: dict, began: float, preview: str | None, state: dict) -> tuple:
        run_dir = Path(record["run_dir"])
        glb = run_dir / TEXTURED_MESH_FILE
        files = [str(p) for p in (glb, run_dir / MESH_FILE, record.get("obj_zip")) if p and Path(p).is_file()]
        video = record.get("webm") or record.get("turntable")
        status.training = ""
        status.ending = (f"**Done** in {_duration(time.perf_counter() - began)}: {record['steps']} steps on "
                         f"{record['views']} views, masks from the {record['masks']}. Drag the mesh to turn it; "
                         "the files are below.")
        return (status.text(), preview, str(glb) if glb.is_file() else None, video, files or None, state)

    # -- the page ---------------------------------------------------------------------------------
    def blocks(self) -> gr.Blocks:
        with gr.Blocks(title=TITLE, analytics_enabled=False) as page:  # no network: nothing is sent anywhere
            gr.Markdown(f"## {TITLE}\n{INTRO}")
            state = gr.State({})
            with gr.Row():
                with gr.Column(scale=1):
                    # every kind of file reaches inspect(), which says in one line what it cannot use
                    upload = gr.File(label="Generator output (PNG or JPG, an SV3D MP4, or a zip of a folder)",
                                     elem_id="upload")
                    quality = gr.Radio(list(QUALITIES), value="default", label="Quality",
                                       info="fast: a rough mesh in a fraction of the time; accurate: the paper's large "
                                            "network, hours on a CPU (meant for a GPU)")
                    views = gr.Dropdown(list(VIEW_CHOICES), value="all", label="Training views",
                                        info="SyncDreamer strips: 4, 8, 12 or 16 of the 16 views")
                    with gr.Row():
                        start = gr.Button("Start", variant="primary", elem_id="start")
                        cancel = gr.Button("Cancel", variant="stop", elem_id="cancel")
                        resume = gr.Button("Resume", elem_id="resume")
                    cancel_note = gr.Markdown(elem_id="cancel-note")
                    info = gr.Markdown(NO_UPLOAD, elem_id="info")
                with gr.Column(scale=1):
                    status = gr.Markdown(elem_id="status")
                    preview = gr.Image(label=f"Preview: {PREVIEW_LABEL}",
                                       type="filepath", interactive=False, height=220, elem_id="preview")
            gallery = gr.Gallery(label="Training views (top) and their masks (bottom)", columns=8, height="auto",
                                 object_fit="contain", elem_id="views")
            with gr.Row():
                mesh = gr.Model3D(label="Textured mesh (drag to turn, scroll to zoom)", clear_color=(1, 1, 1, 1),
                                  height=480, elem_id="mesh")
                video = gr.Video(label="Turntable", autoplay=True, loop=True, interactive=False, height=480,
                                 elem_id="turntable")
            files = gr.File(label="Downloads: GLB (textured), PLY (vertex colours), OBJ (zip)",
                            file_count="multiple", interactive=False, elem_id="downloads")
            run_outputs = [status, preview, mesh, video, files, state]
            upload.upload(self.inspect, [upload, quality, views, state], [info, gallery, state], api_name="inspect",
                          concurrency_limit=None)
            upload.clear(self.forget, [state], [info, gallery, state], api_name=False, concurrency_limit=None)
            for choice in (quality, views):
                choice.input(self.reinspect, [quality, views, state], [info, gallery, state],
                             api_name="reinspect" if choice is quality else False, concurrency_limit=None)
            start.click(self.ask, None, None, api_name=False, queue=False).then(
                self.run, [quality, views, state], run_outputs, api_name="run", concurrency_limit=1,
                concurrency_id="train", show_progress="minimal", show_progress_on=[status])
            resume.click(self.ask, None, None, api_name=False, queue=False).then(
                self.resume, [state], run_outputs, api_name="resume", concurrency_limit=1, concurrency_id="train",
                show_progress="minimal", show_progress_on=[status])
            cancel.click(self.cancel, None, cancel_note, api_name="cancel", concurrency_limit=None)
            page.unload(self.leave)
        return page


def build(settings: AppSettings) -> tuple[gr.Blocks, App]:
    """The page and its handlers (call ``App.close`` when the server stops)."""
    app = App(settings.validate())
    page = app.blocks()
    page.queue(default_concurrency_limit=1)
    return page, app


def launch(settings: AppSettings, block: bool = True) -> tuple[gr.Blocks, App, str]:
    """Serve the page; with ``block``, until Ctrl-C. The page, its handlers and the local URL."""
    page, app = build(settings)
    runs = Path(settings.runs).resolve()
    runs.mkdir(parents=True, exist_ok=True)
    try:
        _, url, _ = page.launch(server_name=settings.host, server_port=settings.port, share=settings.share,
                                prevent_thread_lock=True, quiet=not block, allowed_paths=[str(runs)],
                                max_file_size=settings.max_upload_bytes)
    except BaseException:
        app.close()
        raise
    if block:
        try:
            page.block_thread()
        finally:
            app.close()
    return page, app, url
