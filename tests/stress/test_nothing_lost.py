"""Nothing lost: a run killed (SIGKILL, in a child process) while writing a checkpoint keeps the
previous one usable, and resuming after a kill ends bitwise where an uninterrupted run ends, with the
same metrics log: ``neus`` killed in a checkpoint write, ``va-neus`` killed mid-run across its phase
switches."""

import json
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import torch
from conftest import tiny_config

from va_plugin.engine.trainer import list_checkpoints, load_checkpoint

TESTS = Path(__file__).resolve().parents[1]

CHILD = textwrap.dedent("""
    import os, signal, sys
    sys.path.insert(0, {tests!r})
    import torch
    torch.set_num_threads(1)
    from conftest import tiny_config
    from va_plugin.engine import trainer as trainer_module
    from va_plugin.callbacks import BEFORE_STEP, TrainingCallback

    config = tiny_config({method!r}, {scene!r}, {run!r}, steps={steps}, checkpoint_every={every}, **{overrides!r})
    trainer = config.setup()
    kill_at_step, kill_in_save = {kill_at_step!r}, {kill_in_save!r}
    if kill_in_save is not None:
        real_save = torch.save

        def dying_save(obj, handle, *args, **kwargs):
            if obj["step"] == kill_in_save:  # half the bytes on disk, then the process dies
                handle.write(b"PK\\x03\\x04 half a checkpoint")
                handle.flush()
                os.kill(os.getpid(), signal.SIGKILL)
            real_save(obj, handle, *args, **kwargs)

        trainer_module.torch.save = dying_save
    if kill_at_step is not None:
        def die(step, _):
            if step == kill_at_step:
                os.kill(os.getpid(), signal.SIGKILL)

        trainer.callbacks.append(TrainingCallback(die, BEFORE_STEP))
    trainer.train()
""")


def run_and_kill(method, scene, run, steps, every, overrides, kill_at_step=None, kill_in_save=None):
    script = CHILD.format(tests=str(TESTS), method=method, scene=str(scene), run=str(run), steps=steps,
                          every=every, overrides=overrides, kill_at_step=kill_at_step, kill_in_save=kill_in_save)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == -signal.SIGKILL, done.stderr[-2000:]


def params(trainer):
    return {k: v.detach().clone() for k, v in trainer.model.state_dict().items()}


def log_without_timing(run):
    lines = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    return [{k: v for k, v in r.items() if k not in ("train_seconds", "it_per_s")} for r in lines]


def test_killed_while_writing_a_checkpoint_keeps_the_previous_one(tiny_scene, tmp_path):
    run = tmp_path / "run"
    run_and_kill("neus", tiny_scene, run, steps=4, every=1, overrides={}, kill_in_save=3)
    assert [p.name for p in list_checkpoints(run)] == ["step-0000001.ckpt", "step-0000002.ckpt"]
    assert (run / "checkpoints" / "step-0000003.ckpt.tmp").exists()  # the half-written file, never renamed
    state = load_checkpoint(run)
    assert state["step"] == 2 and torch.isfinite(next(iter(state["model"].values()))).all()
    resumed = tiny_config("neus", tiny_scene, run, steps=4, checkpoint_every=1).setup()
    assert resumed.resume() and resumed.step == 2
    resumed.train()
    assert not list((run / "checkpoints").glob("*.tmp"))  # cleaned up by the next save
    full = tiny_config("neus", tiny_scene, tmp_path / "full", steps=4, checkpoint_every=1).setup()
    full.train()
    a, b = params(full), params(resumed)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert log_without_timing(run) == log_without_timing(tmp_path / "full")  # step 3's line was logged twice


def test_resume_after_a_kill_is_bitwise_an_uninterrupted_run(tiny_scene, tmp_path):
    """va-neus killed mid-run: its phases switch at steps 3 and 5 of 8, and the checkpoint at 3 and the
    kill at 5 straddle both switches."""
    method = "va-neus"
    overrides = {"pipeline.model.field.skip_consistent_scenes": "false", "pipeline.model.field.diagnostics_scale": 0}
    run = tmp_path / "cut"
    run_and_kill(method, tiny_scene, run, steps=8, every=3, overrides=overrides, kill_at_step=5)
    assert load_checkpoint(run)["step"] == 3
    resumed = tiny_config(method, tiny_scene, run, steps=8, checkpoint_every=3, **overrides).setup()
    assert resumed.resume() and resumed.step == 3
    resumed.train()
    full = tiny_config(method, tiny_scene, tmp_path / "full", steps=8, checkpoint_every=3, **overrides).setup()
    full.train()
    a, b = params(full), params(resumed)
    assert all(torch.equal(a[k], b[k]) for k in a), "resumed run differs from the uninterrupted one"
    # the log of the killed steps 4-5 was dropped on resume: the two logs read the same
    assert log_without_timing(run) == log_without_timing(tmp_path / "full")
    assert [r["phase"] for r in log_without_timing(run) if "loss" in r] == [1, 1, 1, 2, 2, 3, 3, 3]
