"""Stopping a run from code (request_stop, api stop=) and writes that fail (full disk, read-only folder),
in process: each stop resumes bit for bit, each failed write is one line that says what is kept."""

import errno
import json
import os
import signal
import threading
import time

import pytest
import torch
from conftest import tiny_config

import va_plugin.api as api
from va_plugin.cli import train as train_cli
from va_plugin.engine import trainer as trainer_module
from va_plugin.engine.metrics_log import training_records
from va_plugin.engine.trainer import TrainingInterrupted, list_checkpoints, load_checkpoint
from va_plugin.errors import ConfigError, OutputError
from va_plugin.utils.interrupts import terminate_as_interrupt


def _params(trainer):
    return {k: v.detach().clone() for k, v in trainer.model.state_dict().items()}


def _same(a, b) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def _losses(run):
    return [r["loss"] for r in training_records(run)]


@pytest.fixture(scope="module")
def full_neus(tiny_scene, tmp_path_factory):
    """An uninterrupted 6-step neus run: its folder and final parameters."""
    run = tmp_path_factory.mktemp("full") / "run"
    trainer = tiny_config("neus", tiny_scene, run, steps=6, checkpoint_every=4).setup()
    trainer.train()
    return run, _params(trainer)


def _stopped_then_resumed(tiny_scene, run, stop_kind):
    first = tiny_config("neus", tiny_scene, run, steps=6, checkpoint_every=4).setup()
    event = threading.Event()

    def at_step(step, total, losses):
        if step == 3:
            first.request_stop() if stop_kind == "request" else event.set()

    stop = {"request": None, "event": event, "callable": event.is_set}[stop_kind]
    with pytest.raises(TrainingInterrupted) as stopped:
        first.train(on_step=at_step, stop=stop)
    assert stopped.value.saved and stopped.value.step == 3 and stopped.value.cause == "request"
    assert stopped.value.checkpoint.name == "step-0000003.ckpt" and first.step == 3
    second = tiny_config("neus", tiny_scene, run, steps=6, checkpoint_every=4).setup()
    assert second.resume() and second.step == 3
    second.train()
    return second


@pytest.mark.parametrize("stop_kind", ["request", "event", "callable"])
def test_a_stop_from_code_ends_the_step_and_resumes_bitwise(stop_kind, full_neus, tiny_scene, tmp_path):
    full_run, full_params = full_neus
    resumed = _stopped_then_resumed(tiny_scene, tmp_path / "run", stop_kind)
    assert _same(_params(resumed), full_params)
    assert _losses(tmp_path / "run") == _losses(full_run)


def test_api_train_takes_a_stop_event(tiny_scene, tmp_path, full_neus):
    config = tiny_config("neus", tiny_scene, tmp_path / "run", steps=6, checkpoint_every=4)
    event = threading.Event()
    with pytest.raises(TrainingInterrupted) as stopped:
        api.train(config, stop=event, progress=lambda step, total, losses: step == 2 and event.set())
    assert stopped.value.step == 2 and stopped.value.saved
    api.train(config, resume=True)
    assert _losses(tmp_path / "run") == _losses(full_neus[0])


@pytest.mark.parametrize("every, last_good", [(8, 4), (5, 5)])
def test_a_roll_back_after_a_resume_goes_where_the_uninterrupted_run_went(every, last_good, tiny_scene, tmp_path):
    """The guard's last good state is in the checkpoint: a blow-up in step 6, after a stop at step 5,
    restores in the resumed run too the state of step 4 (the last snapshot), or of step 5 when a scheduled
    checkpoint was written there (it is the last good state, and the checkpoint holds no second copy)."""
    options = {"steps": 8, "checkpoint_every": every, "health.snapshot_every": 2}

    def with_blow_up(trainer):
        def spike(outputs, batch, step):
            return {"spike": torch.tensor(1e6 if step == 5 else 0.0)}

        trainer.model.extra_losses.append(spike)
        return trainer

    full = with_blow_up(tiny_config("neus", tiny_scene, tmp_path / "full", **options).setup())
    with pytest.warns(UserWarning, match=f"restored the state after step {last_good}"):
        full.train()
    assert full.guard.restores == 1
    first = with_blow_up(tiny_config("neus", tiny_scene, tmp_path / "cut", **options).setup())
    with pytest.raises(TrainingInterrupted):
        first.train(stop=lambda: first.step == 5)
    second = with_blow_up(tiny_config("neus", tiny_scene, tmp_path / "cut", **options).setup())
    assert second.resume() and second.step == 5
    with pytest.warns(UserWarning, match=f"restored the state after step {last_good}"):
        second.train()
    assert _same(_params(second), _params(full))
    stored = torch.load(list_checkpoints(tmp_path / "cut")[0], weights_only=False)["health"]["snapshot"]
    assert isinstance(stored, str) == (every == 5)


def _failing_save(monkeypatch, code: int, at_step: int, times: int = 99):
    """Checkpoint writes of step ``at_step`` fail with ``code`` (after half their bytes), ``times`` times."""
    real = trainer_module._torch_save
    failures = []

    def save(obj, handle):
        if obj["step"] == at_step and len(failures) < times:
            failures.append(code)
            handle.write(b"half a checkpoint")
            raise OSError(code, os.strerror(code))  # the disk's error, as the handle raises it
        real(obj, handle)

    monkeypatch.setattr(trainer_module, "_torch_save", save)
    return failures


def _no_temporary_files(run):
    return not list(run.rglob("*.tmp"))


@pytest.mark.parametrize("code, advice", [(errno.ENOSPC, "free some disk space"),
                                          (errno.EROFS, "make the folder writable")])
def test_a_failed_checkpoint_write_keeps_the_previous_one_and_resumes_bitwise(code, advice, monkeypatch,
                                                                              tiny_scene, tmp_path, full_neus):
    run = tmp_path / "run"
    options = {"steps": 6, "checkpoint_every": 2, "keep_checkpoints": 1}
    failures = _failing_save(monkeypatch, code, at_step=4)
    trainer = tiny_config("neus", tiny_scene, run, **options).setup()
    with pytest.raises(OutputError) as failed:
        trainer.train()
    message = str(failed.value)
    assert "\n" not in message and os.strerror(code) in message and advice in message
    assert "training stopped at step 4" in message and "step-0000002.ckpt (step 2), is kept" in message
    assert failures == [code]  # one try: with keep_checkpoints=1 no old checkpoint may make room
    assert [p.name for p in list_checkpoints(run)] == ["step-0000002.ckpt"] and _no_temporary_files(run)
    assert load_checkpoint(run)["step"] == 2
    monkeypatch.undo()
    resumed = tiny_config("neus", tiny_scene, run, **options).setup()
    assert resumed.resume() and resumed.step == 2
    resumed.train()
    assert _same(_params(resumed), full_neus[1])


def test_a_full_disk_makes_room_with_the_checkpoints_that_go_anyway(monkeypatch, tiny_scene, tmp_path, full_neus):
    run = tmp_path / "run"
    failures = _failing_save(monkeypatch, errno.ENOSPC, at_step=3, times=1)
    trainer = tiny_config("neus", tiny_scene, run, steps=6, checkpoint_every=1, keep_checkpoints=2).setup()
    trainer.train()
    assert failures == [errno.ENOSPC]
    assert [p.name for p in list_checkpoints(run)] == ["step-0000005.ckpt", "step-0000006.ckpt"]
    assert _no_temporary_files(run) and _same(_params(trainer), full_neus[1])


def test_the_command_line_says_a_full_disk_in_one_line(monkeypatch, tiny_scene, tmp_path, capsys):
    _failing_save(monkeypatch, errno.ENOSPC, at_step=2)
    argv = ["neus", "--data", str(tiny_scene), "--steps", "3", "--device", "cpu", "--output-dir", str(tmp_path / "run"),
            "--no-progress", "--set", "pipeline.datamanager.rays_per_batch=32", "--set", "checkpoint_every=1",
            "--set", "keep_checkpoints=1"]
    assert train_cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: could not write ") and "No space left on device" in err[-1]
    assert "Traceback" not in "\n".join(err) and _no_temporary_files(tmp_path / "run")


def test_a_metrics_write_that_fails_is_one_line_too(monkeypatch, tiny_scene, tmp_path):
    def full(run_dir, record):
        raise OSError(errno.ENOSPC, "No space left on device", str(run_dir / "metrics.jsonl"))

    monkeypatch.setattr(trainer_module, "append_record", full)
    trainer = tiny_config("neus", tiny_scene, tmp_path / "run", steps=2).setup()
    with pytest.raises(OutputError, match=r"could not write .*metrics.jsonl: No space left on device; free some"):
        trainer.train()


def test_config_json_is_written_whole(tiny_scene, tmp_path):
    trainer = tiny_config("neus", tiny_scene, tmp_path / "run", steps=1).setup()
    trainer.train()
    assert json.loads((tmp_path / "run" / "config.json").read_text())["max_steps"] == 1
    assert _no_temporary_files(tmp_path / "run")


@pytest.mark.parametrize("second", ["TERM", "INT"])
def test_a_second_signal_while_the_checkpoint_is_written_lets_it_finish(second, monkeypatch, tiny_scene, tmp_path):
    """The second signal lands inside torch.save's write: raised there, it surfaced as torch's RuntimeError
    (inline_container.cc), a traceback. It waits for the write's end now, and the stop is the first's."""
    monkeypatch.setenv(trainer_module.SIGNALS_ENV, "2:TERM@end")
    real, sent = trainer_module._torch_save, []

    class SignalMidWrite:
        def __init__(self, handle):
            self.handle = handle

        def write(self, data):
            if not sent:
                sent.append(second)
                os.kill(os.getpid(), getattr(signal, "SIG" + second))
                time.sleep(0.05)  # the handler runs here
            return self.handle.write(data)

        def flush(self):
            self.handle.flush()

    monkeypatch.setattr(trainer_module, "_torch_save", lambda obj, handle: real(obj, SignalMidWrite(handle)))
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with terminate_as_interrupt(), pytest.raises(TrainingInterrupted) as stopped:
            tiny_config("neus", tiny_scene, tmp_path / "run", steps=6, checkpoint_every=10).setup().train()
    finally:
        signal.signal(signal.SIGINT, previous)
    assert sent and stopped.value.saved and stopped.value.step == 2 and stopped.value.cause == "SIGTERM"
    assert load_checkpoint(tmp_path / "run")["step"] == 2 and _no_temporary_files(tmp_path / "run")


def test_a_bad_signal_plan_is_refused(monkeypatch, tiny_scene, tmp_path):
    monkeypatch.setenv(trainer_module.SIGNALS_ENV, "three:INT")
    with pytest.raises(ConfigError, match="STEP:SIGNAL"):
        tiny_config("neus", tiny_scene, tmp_path / "run", steps=1).setup()


@pytest.mark.parametrize("method", ["neus", "ngp"])
def test_the_periodic_evaluation_draws_no_random_number(method, tiny_scene, tmp_path):
    """It runs between steps, before the checkpoint: were it to draw, a run resumed there would differ."""
    trainer = tiny_config(method, tiny_scene, tmp_path / "run", steps=1).setup()
    trainer.train()
    before = (torch.get_rng_state(), trainer.pipeline.datamanager.generator.get_state())
    metrics, _ = trainer.pipeline.evaluate_views(1)
    assert metrics and torch.equal(before[0], torch.get_rng_state())
    assert torch.equal(before[1], trainer.pipeline.datamanager.generator.get_state())
