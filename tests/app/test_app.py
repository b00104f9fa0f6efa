"""va-app, driven like a web page: a locally launched app, called through Gradio's Python client
(gradio_client) endpoint by endpoint, the way the page's buttons call them. An upload shows its format,
views and masks; a run streams progress and previews and ends with a textured GLB that trimesh loads, a
browser-playable turntable and the downloads; a bad upload gives one line and writes no run folder;
Cancel, or closing the page, leaves a run with a checkpoint that Resume finishes. Tiny sizes: 32 px views,
60 steps."""

from __future__ import annotations

import json
import time
import zipfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import render_views, toy_albedo, toy_object, write_syncdreamer_strip

pytest.importorskip("gradio", reason="va-app needs the app extra: pip install -e '.[app]'")
gradio_client = pytest.importorskip("gradio_client", reason="the app tests drive the page through gradio_client")
import trimesh  # noqa: E402

from va_plugin.app import server  # noqa: E402
from va_plugin.app.jobs import SPEC_FILE, JobSpec  # noqa: E402
from va_plugin.app.settings import AppSettings  # noqa: E402
from va_plugin.data import rigs  # noqa: E402
from va_plugin.data.images import write_image  # noqa: E402
from va_plugin.engine.trainer import list_checkpoints  # noqa: E402
from va_plugin.raycast import MeshRenderer, position_albedo  # noqa: E402

STEPS = 60
TINY = ["pipeline.datamanager.rays_per_batch=32", "pipeline.model.n_samples=8", "pipeline.model.n_importance=8",
        "pipeline.model.crossings_samples=16"]
UPLOAD_LIMIT_MB = 0.2
PROBLEM = "**Cannot use this upload.**"


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """The app on a free local port, with runs shrunk to test sizes; (url, runs folder, handlers)."""
    runs = tmp_path_factory.mktemp("app") / "runs"
    settings = AppSettings(runs=runs, device="cpu", steps=STEPS, overrides=TINY, texture_size=64, mesh_resolution=32,
                           turntable_frames=4, preview_every=20, preview_size=32, threads=1,
                           max_upload_mb=UPLOAD_LIMIT_MB)
    page, app, url = server.launch(settings, block=False)
    yield url, runs, app
    app.close()
    page.close()


@pytest.fixture(scope="module")
def strip(tmp_path_factory) -> Path:
    return write_syncdreamer_strip(tmp_path_factory.mktemp("upload") / "strip.png", tile=32)


def client(url: str):
    """A fresh page session."""
    return gradio_client.Client(url, verbose=False)


def upload(session, path: Path, quality: str = "default", views: str = "all"):
    return session.predict(gradio_client.handle_file(str(path)), quality, views, api_name="/inspect")


def wait_for(job, text: str, timeout: float = 120.0) -> str:
    """The first status the streaming job shows that contains ``text``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for output in job.outputs():
            if text in output[0]:
                return output[0]
        if job.done():
            break
        time.sleep(0.1)
    raise AssertionError(f"no status with {text!r}; the last: {job.outputs()[-1][0] if job.outputs() else None}")


def run_folders(runs: Path) -> list[Path]:
    return sorted(p for p in runs.iterdir() if p.is_dir()) if runs.is_dir() else []


def check_result(result, runs: Path, views: int) -> Path:
    """The final outputs of a run: the textured GLB (loaded by trimesh), the WebM turntable, the files
    (GLB, PLY, and the OBJ with its material and texture in a zip); the job folder."""
    status, _preview, mesh, video, files = result
    assert "**Done**" in status and f"{STEPS} steps on {views} views" in status, status
    assert mesh.endswith("mesh.glb") and video.endswith("turntable.webm") and Path(video).stat().st_size > 0
    scene = trimesh.load(mesh)
    geometry = list(scene.geometry.values())
    assert geometry and len(geometry[0].faces) > 0
    assert geometry[0].visual.kind == "texture" and geometry[0].visual.material.baseColorTexture is not None
    assert sorted(Path(f).name for f in files) == ["mesh.glb", "mesh.ply", "mesh_obj.zip"]
    with zipfile.ZipFile(next(f for f in files if f.endswith(".zip"))) as bundle:
        assert sorted(bundle.namelist()) == ["mesh.mtl", "mesh.obj", "mesh.png"]
    job_dir = Path(status.split("`")[1])
    assert job_dir.parent == runs and (job_dir / "input" / "strip.png").is_file()
    assert (job_dir / "run" / "mesh.glb").is_file() and (job_dir / "run" / "summary.json").is_file()
    return job_dir


def test_an_upload_shows_its_views_and_masks_then_trains_to_a_textured_mesh(served, strip):
    url, runs, _ = served
    before = run_folders(runs)
    session = client(url)
    info, gallery = upload(session, strip)
    assert info.startswith("**Detected** SyncDreamer strip: 16 training views, 32 x 32 px, masks from the color key")
    assert len(gallery) == 16 and gallery[4]["caption"] == "view 4"
    info, gallery = session.predict("default", "4", api_name="/reinspect")
    assert "4 training views of 16" in info and [g["caption"] for g in gallery] == [f"view {k}" for k in (0, 4, 8, 12)]
    assert run_folders(runs) == before  # nothing is written before Start

    job = session.submit("default", "4", api_name="/run")
    result = job.result(timeout=300)
    statuses = [output[0] for output in job.outputs()]
    assert any("**Training** step" in s and "left" in s for s in statuses), statuses
    assert any(output[1] for output in job.outputs()), "no preview render was shown"
    job_dir = check_result(result, runs, views=4)
    spec = JobSpec.load(job_dir)
    assert spec.views == 4 and spec.options.steps == STEPS and spec.quality == "default"
    assert sorted(p.name for p in (job_dir / "previews").iterdir()) == ["step-000020.png", "step-000040.png"]
    assert json.loads((job_dir / "run" / "summary.json").read_text())["views"] == 4


def _zip(path: Path, folder: Path | None = None, entries: dict[str, bytes] | None = None, skip=()) -> Path:
    with zipfile.ZipFile(path, "w") as archive:
        for file in sorted(folder.rglob("*")) if folder is not None else []:
            if file.is_file() and file.name not in skip:
                archive.write(file, Path(folder.name) / file.relative_to(folder))
        for name, data in (entries or {}).items():
            archive.writestr(name, data)
    return path


def _png(width: int, height: int) -> bytes:
    import cv2

    return cv2.imencode(".png", np.full((height, width, 3), 200, np.uint8))[1].tobytes()


def test_bad_uploads_give_one_line_and_write_nothing(served, strip, tmp_path):
    url, runs, app = served
    before, staged = run_folders(runs), set(app.staging.iterdir())
    session = client(url)
    cases = {
        "notes.txt": (b"not an image", "is neither an image"),
        "broken.png": (b"\x89PNG\r\n\x1a\n" + b"\0" * 64, "is not a readable image"),
        "square.png": (_png(100, 100), "cannot tell the format of square.png (a 100x100 image)"),
        "broken.zip": (b"PK\x03\x04" + b"\0" * 64, "is not a readable zip archive"),
        "text.zip": (_zip(tmp_path / "t.zip", entries={"readme.txt": b"hello"}).read_bytes(), "holds no input"),
        "escape.zip": (_zip(tmp_path / "e.zip", entries={"../outside.png": _png(64, 4)}).read_bytes(),
                       "holds a path outside the archive"),
        "two.zip": (_zip(tmp_path / "2.zip", entries={"a.png": strip.read_bytes(), "b.png": strip.read_bytes()})
                    .read_bytes(), "holds 2 inputs (a.png, b.png)"),
    }
    for name, (data, expected) in cases.items():
        path = tmp_path / name
        path.write_bytes(data)
        info, gallery = upload(session, path)
        assert info.startswith(PROBLEM) and expected in info, (name, info)
        assert "\n" not in info and "Traceback" not in info and str(app.staging) not in info, info
        assert gallery == []
    big = tmp_path / "big.png"
    big.write_bytes(b"\0" * int(UPLOAD_LIMIT_MB * 2e6))
    with pytest.raises(ValueError, match="exceeds the maximum file size"):  # refused before it is sent
        upload(session, big)
    status = session.predict("default", "all", api_name="/run")[0]
    assert status == "Upload a file first."
    # nothing new staged (an earlier test's page may close meanwhile, and its upload goes with it)
    assert run_folders(runs) == before and set(app.staging.iterdir()) <= staged
    assert not (tmp_path / "outside.png").exists()


def test_zips_of_a_scene_folder_and_a_wonder3d_folder_are_read(served, tiny_scene, tmp_path):
    url = served[0]
    session = client(url)
    info, gallery = upload(session, _zip(tmp_path / "scene.zip", tiny_scene, skip=("mesh.ply",)))  # no true mesh
    assert info.startswith("**Detected** transforms.json scene: 4 training views") and len(gallery) == 4, info
    wonder3d = tmp_path / "wonder3d"
    rgb, _ = render_views(MeshRenderer(toy_object(), position_albedo(toy_albedo)), rigs.wonder3d_rig(32), (1, 1, 1))
    for k, (view, _) in enumerate(rigs.WONDER3D_VIEWS):
        write_image(wonder3d / f"rgb_000_{view}.png", rgb[k])
    info, gallery = upload(session, _zip(tmp_path / "w3d.zip", wonder3d), views="4")
    assert info.startswith("**Detected** Wonder3D folder: 6 training views"), info
    assert "a view count applies to SyncDreamer strips only" in info
    assert [g["caption"] for g in gallery][:2] == ["view 0 (rgb_000_front.png)", "view 1 (rgb_000_front_right.png)"]


def test_cancel_leaves_a_run_that_resume_finishes(served, strip):
    url, runs, _ = served
    session = client(url)
    upload(session, strip)
    job = session.submit("default", "all", api_name="/run")
    wait_for(job, "**Training** step")
    assert session.predict(api_name="/cancel").startswith("Cancelling")
    status = job.result(timeout=300)[0]
    assert "**Cancelled** at step" in status and "--resume" in status, status
    job_dir = Path(status.split("`")[1])
    run_dir = job_dir / "run"
    step = int(status.split("**Cancelled** at step ")[1].split(";")[0])
    assert 0 < step < STEPS and [p.name for p in list_checkpoints(run_dir)][-1] == f"step-{step:07d}.ckpt"
    assert not (run_dir / "mesh.glb").exists() and (job_dir / SPEC_FILE).is_file()
    assert f"--out {run_dir}" in status
    assert session.predict(api_name="/cancel") == "Nothing is running."

    job = session.submit(api_name="/resume")
    result = job.result(timeout=300)
    assert any("continues from its checkpoint" in output[0] for output in job.outputs())
    assert check_result(result, runs, views=16) == job_dir
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["resumed_from_step"] == step and summary["steps"] == STEPS


def test_closing_the_page_stops_its_run_with_a_checkpoint_and_drops_its_upload(served, strip, monkeypatch):
    """The page's heartbeat ends (the tab was closed): its run stops at the next step with a checkpoint that
    Resume could finish, and its staged upload is deleted."""
    url, runs, app = served
    monkeypatch.setenv("GRADIO_HEARTBEAT_INTERVAL", "0.2")  # the server notices a closed page within 0.2 s
    before = run_folders(runs)
    session = client(url)
    upload(session, strip)
    staged = app.staged[session.session_hash].staging
    job = session.submit("default", "all", api_name="/run")
    wait_for(job, "**Training** step")
    session.close()  # what a closed tab does: no more heartbeats
    deadline = time.monotonic() + 120
    while (app.running or staged.exists()) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not app.running and not staged.exists()
    [job_dir] = [p for p in run_folders(runs) if p not in before]
    checkpoints = list_checkpoints(job_dir / "run")
    assert checkpoints and 0 < int(checkpoints[-1].stem.split("-")[1]) < STEPS, checkpoints
    assert not (job_dir / "run" / "mesh.glb").exists() and (job_dir / SPEC_FILE).is_file()


def test_an_upload_while_the_run_waits_in_the_queue_keeps_that_runs_input(served, strip, tmp_path):
    """Start clicked (the run queued), then another file dropped in before the run leaves the queue: the
    run trains on the file it was started with, and the newer upload stays staged for the next run."""
    _, runs, app = served
    request = SimpleNamespace(session_hash="queued-session")
    other = write_syncdreamer_strip(tmp_path / "other.png", tile=32)
    assert app.inspect(str(strip), "default", "4", {}, request)[2]["format"] == "syncdreamer"
    app.ask(request)  # what the page's Start does before the run joins the queue
    state = app.inspect(str(other), "default", "4", {}, request)[2]
    outputs = list(app.run("default", "4", state, request))
    job_dir = check_result(outputs[-1][:5], runs, views=4)  # the last item is the page state
    assert [p.name for p in (job_dir / "input").iterdir()] == ["strip.png"]
    staged = app.staged[request.session_hash]
    assert staged.path.name == "other.png" and staged.path.is_file()
    assert not app.claimed  # the claim ends with the run's start
    app.forget(state, request)
    assert not staged.path.exists()


def test_the_page_needs_no_network_and_says_what_it_takes(served):
    url = served[0]
    import urllib.request

    with urllib.request.urlopen(url, timeout=30) as response:
        page = response.read().decode("utf-8", errors="replace")
    assert response.status == 200 and "va-plugin" in page
    config = json.load(urllib.request.urlopen(f"{url.rstrip('/')}/config", timeout=30))
    assert config.get("analytics_enabled") is False
    labels = {c.get("props", {}).get("label") for c in config["components"]}
    assert {"Quality", "Training views", "Turntable"} <= labels
