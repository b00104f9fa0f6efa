"""va-batch end to end on tiny objects: the local engine (two scenes and one bad input), a SIGKILL of the
batch followed by --resume, and the Ray engine in local mode against the local engine's results."""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from va_plugin.cli import batch as cli

REPO = Path(__file__).resolve().parents[2]
TINY = ["--steps", "3", "--mesh-resolution", "24", "--eval-max-views", "1", "--eval-samples", "2000",
        "--texture-size", "16", "--no-progress", "--device", "cpu",
        "--set", "pipeline.datamanager.rays_per_batch=32", "--set", "pipeline.model.n_samples=8",
        "--set", "pipeline.model.n_importance=8"]
COMPARED = ("name", "status", "cd", "iou", "fscore", "psnr", "ssim", "lpips", "steps", "error")
"""The summary columns that must not depend on the engine or on interruptions (not seconds or paths)."""


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """Two 32-px scenes with ground truth (the mug and the bowl) and a file that is no image."""
    from va_plugin.bench.scenes.builder import build_procedural_scene

    root = tmp_path_factory.mktemp("inputs")
    for name in ("mug", "bowl"):
        build_procedural_scene(root / name, name, n_views=4, resolution=32, mesh_resolution=48)
    (root / "broken.png").write_bytes(b"this is not an image")
    return root


@pytest.fixture(scope="module")
def reference(inputs, tmp_path_factory):
    """The local engine with two workers on the three inputs: (exit status, batch folder)."""
    out = tmp_path_factory.mktemp("batch") / "out"
    return cli.main([str(inputs), "--method", "neus", "--out", str(out), "--workers", "2", *TINY]), out


def summary(out: Path):
    with open(out / "summary.csv", newline="") as handle:
        return {row["name"]: {k: row[k] for k in COMPARED} for row in csv.DictReader(handle)}


def test_local_engine_records_every_object_and_goes_on_after_a_bad_one(reference):
    code, out = reference
    assert code == 1  # one object failed
    rows = summary(out)
    assert list(rows) == ["bowl", "broken", "mug"]
    assert rows["broken"]["status"] == "failed" and "cannot decode image" in rows["broken"]["error"]
    assert "\n" not in rows["broken"]["error"] and rows["broken"]["cd"] == ""
    for name in ("mug", "bowl"):
        row = rows[name]
        assert row["status"] == "ok" and row["error"] == "" and row["steps"] == "3"
        assert all(float(row[k]) >= 0 for k in ("cd", "iou", "psnr", "lpips"))
        run = out / "runs" / name
        for produced in ("mesh.ply", "mesh.glb", "thumbnail.png", "eval.json", "batch.log"):
            assert (run / produced).is_file(), produced
    assert len((out / "manifest.jsonl").read_text().splitlines()) == 3
    md = (out / "summary.md").read_text()
    assert "**mean** (2 ok)" in md and "| broken | failed |" in md
    assert (out / "contact_sheet.png").is_file()


def test_a_batch_folder_is_continued_only_with_resume(reference, inputs, capsys):
    _, out = reference
    assert cli.main([str(inputs), "--method", "neus", "--out", str(out), *TINY]) == 2
    assert "--resume" in capsys.readouterr().err
    # nothing left to run: the manifest holds every object
    assert cli.main([str(inputs), "--method", "neus", "--out", str(out), "--resume", *TINY]) == 1
    assert "0 to run" in capsys.readouterr().err
    assert cli.main([str(inputs), "--method", "neus", "--out", str(out), "--resume", "--quiet", *TINY]) == 1
    printed = capsys.readouterr()  # --quiet: the final line alone
    assert printed.err == "" and len(printed.out.splitlines()) == 1 and "2 ok, 1 failed" in printed.out


def _children(pid: int):
    """The child processes of ``pid`` (Linux /proc), or None where that is not readable."""
    try:
        tasks = Path(f"/proc/{pid}/task").iterdir()
        return {int(c) for t in tasks for c in (t / "children").read_text().split()}
    except OSError:
        return None


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


def test_a_killed_batch_resumes_to_the_same_summary(inputs, reference, tmp_path):
    out = tmp_path / "out"
    command = [sys.executable, "-m", "va_plugin.cli.batch", str(inputs), "--method", "neus", "--out", str(out),
               "--workers", "2", *TINY]
    proc = subprocess.Popen(command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    manifest = out / "manifest.jsonl"
    deadline = time.monotonic() + 180
    while not (manifest.is_file() and manifest.read_text().strip()) and proc.poll() is None:
        assert time.monotonic() < deadline, "no object finished in 180 s"
        time.sleep(0.05)
    workers = _children(proc.pid) or set()
    proc.send_signal(signal.SIGKILL)  # the batch alone: its workers must notice and stop by themselves
    proc.wait()
    deadline = time.monotonic() + 15
    while any(_alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(_alive(w) for w in workers), "workers outlived the killed batch"
    done_before = {json.loads(line)["name"] for line in manifest.read_text().splitlines()}
    assert 1 <= len(done_before) < 3

    assert cli.main([str(inputs), "--method", "neus", "--out", str(out), "--workers", "1", "--resume", *TINY]) == 1
    assert summary(out) == summary(reference[1])
    for name in done_before:  # finished objects were not run again
        assert (out / "runs" / name / "batch.log").read_text().count("\n--- ") + 1 == 1


def test_ray_engine_in_local_mode_matches_the_local_engine(inputs, reference, tmp_path):
    pytest.importorskip("ray", reason="ray is not installed (pip install 'va-plugin[ray]')")
    listing = tmp_path / "objects.txt"
    listing.write_text(f"# two of the inputs, by path\n{inputs / 'mug'}\n{inputs / 'bowl'}\n")
    out = tmp_path / "out"
    code = cli.main([str(listing), "--method", "neus", "--out", str(out), "--engine", "ray", "--workers", "2", *TINY])
    assert code == 0
    ray_rows, local_rows = summary(out), summary(reference[1])
    assert list(ray_rows) == ["mug", "bowl"]  # the list's order
    assert ray_rows == {name: local_rows[name] for name in ray_rows}
    records = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    assert sorted(r["name"] for r in records) == ["bowl", "mug"]
    assert (out / "contact_sheet.png").is_file()
