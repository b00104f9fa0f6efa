"""Exact resume from any interrupt, with real ``va-train`` processes and real signals.

Each run trains 12 steps of a tiny config (checkpoints every 5) and is cut by signals the process sends
itself at chosen points of chosen steps (the ``VA_TEST_SIGNALS`` hook: SIGINT, SIGTERM, a second SIGINT,
SIGKILL, SIGSTOP while the test fills or write-protects the disk); each cut run is continued with
``--resume``, and the last time in this process (what ``--resume`` runs, without another start-up). Its
losses (bits), final parameters and mesh bytes must be those of one uninterrupted run of the method (in
process, module-scoped).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

import va_plugin.api as api
from va_plugin.engine.metrics_log import training_records
from va_plugin.engine.trainer import SIGNALS_ENV, list_checkpoints, load_checkpoint

STEPS, EVERY = 12, 5
COMMON = {"pipeline.datamanager.rays_per_batch": 32, "pipeline.model.eval_chunk": 256, "checkpoint_every": EVERY,
          "log_every": 1, "num_threads": 1}
NEUS = {"pipeline.model.n_samples": 8, "pipeline.model.n_importance": 8, "pipeline.model.crossings_rays": 8,
        "pipeline.model.crossings_samples": 16}
OVERRIDES = {
    "neus": {**COMMON, **NEUS, "pipeline.model.field.log2_hashmap_size": 12},
    "ngp": {**COMMON, "pipeline.model.n_samples": 16, "pipeline.model.field.log2_hashmap_size": 12,
            "pipeline.model.occupancy_grid.update_every": 3, "pipeline.model.occupancy_grid.warmup_steps": 3,
            "pipeline.model.density_threshold": 0.5},  # a surface after 12 steps
    # phases 1, 2, 3 in steps 1-4, 5-8, 9-12
    "va-neus": {**COMMON, **NEUS, "pipeline.model.field.base.log2_hashmap_size": 12,
                "pipeline.model.field.skip_consistent_scenes": "false", "pipeline.model.field.diagnostics_scale": 0},
}
MESH_RESOLUTION = 24


def _config(method, scene, run, extra=None):
    overrides = [f"{k}={v}" for k, v in {**OVERRIDES[method], **(extra or {})}.items()]
    return api.build_config(method, scene, preset="fast", steps=STEPS, device="cpu", out=run, progress=False,
                            overrides=overrides)


def _command(method, scene, run, extra=None) -> list[str]:
    command = [sys.executable, "-m", "va_plugin.cli.train", method, "--data", str(scene), "--preset", "fast",
               "--steps", str(STEPS), "--device", "cpu", "--output-dir", str(run), "--no-progress", "--resume"]
    for key, value in {**OVERRIDES[method], **(extra or {})}.items():
        command += ["--set", f"{key}={value}"]
    return command


def _env(signals: str) -> dict[str, str]:
    return {**os.environ, "OMP_NUM_THREADS": "1", SIGNALS_ENV: signals}


def _python_sigint() -> None:
    """In the child before it starts: SIGINT at its default, so that Python installs its Ctrl-C handler
    even under a test run started in the background (which inherits SIGINT ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def train(method, scene, run, signals="", expect=0, extra=None) -> str:
    """One ``va-train`` process on ``run`` (resuming it) with the planned ``signals``; its stderr."""
    done = subprocess.run(_command(method, scene, run, extra), env=_env(signals), capture_output=True, text=True,
                          timeout=600, preexec_fn=_python_sigint)
    assert done.returncode == expect, f"exit {done.returncode}, expected {expect}:\n{done.stderr[-3000:]}"
    return done.stderr


def finish(method, scene, run, extra=None) -> None:
    """The last resume, in this process: ``va-train --resume``'s call."""
    api.train(_config(method, scene, run, extra), resume=True)


def outcome(run: Path) -> dict:
    """What must not differ: every logged loss, the final parameters, the mesh's bytes."""
    losses = [(r["step"], r["loss"]) for r in training_records(run)]
    state = load_checkpoint(run)
    assert state["step"] == STEPS
    mesh = api.export_mesh(run, texture=False, resolution=MESH_RESOLUTION, device="cpu").path.read_bytes()
    return {"losses": losses, "model": state["model"], "mesh": mesh}


def assert_same(run: Path, baseline: dict, all_losses: bool = True) -> None:
    got = outcome(run)
    if all_losses:
        assert got["losses"] == baseline["losses"], "the losses differ from the uninterrupted run's"
    assert got["losses"][-1] == baseline["losses"][-1], "the final loss differs from the uninterrupted run's"
    assert got["model"].keys() == baseline["model"].keys()
    assert all(torch.equal(got["model"][k], baseline["model"][k]) for k in got["model"]), "parameters differ"
    assert got["mesh"] == baseline["mesh"], "the mesh differs from the uninterrupted run's"


@pytest.fixture(scope="module")
def baselines(tiny_scene, tmp_path_factory):
    """One uninterrupted run per method, trained when first asked for."""
    done = {}

    def baseline(method):
        if method not in done:
            run = tmp_path_factory.mktemp("baseline") / method
            api.train(_config(method, tiny_scene, run))
            done[method] = outcome(run)
        return done[method]

    return baseline


def checkpoint_steps(run):
    return [int(p.name[5:12]) for p in list_checkpoints(run)]


def test_neus_after_sigterm_sigkill_and_a_truncated_checkpoint(baselines, tiny_scene, tmp_path):
    run = tmp_path / "run"
    err = train("neus", tiny_scene, run, "7:TERM@start", expect=130)  # before step 7's callbacks
    assert "interrupted at step 7; saved" in err and "continue with --resume" in err
    assert checkpoint_steps(run) == [5, 7]
    train("neus", tiny_scene, run, "9:KILL", expect=-signal.SIGKILL)  # nothing saved: 7 is the newest
    assert checkpoint_steps(run) == [5, 7]
    newest = list_checkpoints(run)[-1]
    newest.write_bytes(newest.read_bytes()[: newest.stat().st_size // 2])  # as a disk that lost its tail
    with pytest.warns(UserWarning, match=r"skipped unreadable checkpoint\(s\): step-0000007.ckpt .*using step-0000005"):
        finish("neus", tiny_scene, run)
    assert (newest.parent / (newest.name + ".unreadable")).is_file()
    assert_same(run, baselines("neus"))


def test_ngp_after_sigterm_and_a_second_ctrl_c_that_aborts_a_step(baselines, tiny_scene, tmp_path):
    run = tmp_path / "run"
    err = train("ngp", tiny_scene, run, "4:TERM@end", expect=130)  # after step 4's callbacks
    assert "interrupted at step 4; saved" in err
    # a first Ctrl-C at the start of step 8 waits for the step's end; a second one in its middle does not
    err = train("ngp", tiny_scene, run, "8:INT@start,8:INT@mid", expect=130)
    assert "interrupted during step 8, which was left unfinished" in err and "step-0000005.ckpt" in err, err
    assert checkpoint_steps(run) == [4, 5]
    finish("ngp", tiny_scene, run)
    assert_same(run, baselines("ngp"))


def test_va_neus_across_its_phase_switches(baselines, tiny_scene, tmp_path):
    """Stopped after the last step of phase 1: the resumed run switches to phase 2 in its first step."""
    run = tmp_path / "run"
    err = train("va-neus", tiny_scene, run, "4:INT@end", expect=130)
    assert "interrupted at step 4; saved" in err
    finish("va-neus", tiny_scene, run)
    assert_same(run, baselines("va-neus"))
    phases = [r["phase"] for r in training_records(run)]
    assert phases == [1] * 4 + [2] * 4 + [3] * 4


@contextlib.contextmanager
def small_disk(path: Path):
    """A 64 MB tmpfs at ``path`` (root only; skips the test otherwise)."""
    path.mkdir(parents=True)
    if os.geteuid() != 0:
        pytest.skip("mounting a small disk needs root")
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64m", "tmpfs", str(path)], capture_output=True,
                             text=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


def run_paused(method, scene, run, step, while_paused, extra) -> subprocess.CompletedProcess:
    """A ``va-train`` process that stops itself (SIGSTOP) in ``step``; ``while_paused()`` runs, then it
    continues to its end."""
    process = subprocess.Popen(_command(method, scene, run, extra), env=_env(f"{step}:STOP"),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_python_sigint)
    try:
        deadline = time.monotonic() + 300
        while _state(process.pid) != "T":
            assert process.poll() is None and time.monotonic() < deadline, "the run did not pause"
            time.sleep(0.05)
        while_paused()
        process.send_signal(signal.SIGCONT)
        out, err = process.communicate(timeout=300)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    return subprocess.CompletedProcess(process.args, process.returncode, out, err)


def _state(pid: int) -> str:
    with open(f"/proc/{pid}/stat") as stat:
        return stat.read().rsplit(")", 1)[1].split()[0]


def _fill(folder: Path) -> Path:
    """Fill the disk of ``folder`` to the last byte."""
    filler = folder / "filler"
    with open(filler, "wb", buffering=0) as handle:
        for size in (1 << 20, 1 << 12, 1):
            with contextlib.suppress(OSError):
                while True:
                    handle.write(b"\0" * size)
    return filler


def _one_error_line(done: subprocess.CompletedProcess) -> str:
    assert done.returncode == 2, done.stderr[-3000:]
    lines = done.stderr.strip().splitlines()
    assert "Traceback" not in done.stderr and lines[-1].startswith("error: "), done.stderr[-3000:]
    return lines[-1]


def test_a_full_disk_and_a_read_only_disk_during_a_save_lose_nothing(baselines, tiny_scene, tmp_path):
    """The checkpoint of step 10 cannot be written: the disk is full (first run), then read-only (second
    run). Each ends with one error line, keeps the checkpoint of step 5 and leaves no temporary file; the
    run resumed once the disk is fine ends as the uninterrupted one."""
    extra = {"keep_checkpoints": 1, "log_every": 100}  # no log line before the save at step 10
    with small_disk(tmp_path / "disk") as disk:
        run = disk / "run"
        filler = []
        line = _one_error_line(run_paused("neus", tiny_scene, run, 9, lambda: filler.append(_fill(disk)), extra))
        assert "could not write" in line and "step-0000010.ckpt: No space left on device; free some disk" in line
        assert "step-0000005.ckpt (step 5), is kept" in line, line
        assert checkpoint_steps(run) == [5] and not list(run.rglob("*.tmp"))
        filler[0].unlink()

        def read_only():
            subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)

        line = _one_error_line(run_paused("neus", tiny_scene, run, 7, read_only, extra))
        assert "Read-only file system; make the folder writable" in line and "(step 5), is kept" in line, line
        subprocess.run(["mount", "-o", "remount,rw", str(disk)], check=True)
        assert checkpoint_steps(run) == [5] and not list(run.rglob("*.tmp"))
        finish("neus", tiny_scene, run, extra)
        assert_same(run, baselines("neus"), all_losses=False)
