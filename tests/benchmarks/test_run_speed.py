"""benchmarks/run_speed.py in smoke mode: well-formed JSON and pictures with every field filled; bad input."""

from __future__ import annotations

import json
import math

import pytest
from bench_scripts import load_script

METHODS = ["neus", "ngp", "va-neus", "va-ngp"]
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def speed():
    return load_script("run_speed")


@pytest.fixture(scope="module")
def smoke_run(speed, tmp_path_factory):
    out = tmp_path_factory.mktemp("speed")
    assert speed.main(["--smoke", "--out", str(out), "--device", "cpu"]) == 0
    return out, json.loads((out / "speed.json").read_text())


def finite(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def test_json_has_the_machine_and_a_filled_entry_per_method(smoke_run):
    _, data = smoke_run
    meta = data["meta"]
    assert meta["command"].startswith("python benchmarks/run_speed.py --smoke")
    assert meta["device"] == "cpu" and meta["smoke"] is True
    for key in ("cpus", "platform", "torch", "torch_threads"):
        assert meta["machine"][key] not in (None, ""), key
    assert [r["method"] for r in data["rows"]] == METHODS
    for row in data["rows"]:
        assert row["steps"] == 4 and finite(row["train_seconds"]) and row["train_seconds"] > 0
        for key in ("it_per_s", "samples_per_ray", "probed_per_ray", "cd", "psnr"):
            assert finite(row[key]) and row[key] >= 0, (row["method"], key, row[key])
        curve = row["curve"]
        assert [p["step"] for p in curve] == [2, 4] and curve[-1]["cd"] == row["cd"]
        assert all(finite(p[k]) for p in curve for k in ("train_seconds", "cd", "psnr"))
        assert curve[0]["train_seconds"] < curve[1]["train_seconds"] <= row["train_seconds"] + 1e-3
        reach = row["time_to_110pct_cd"]
        assert reach["step"] in (2, 4) and finite(reach["train_seconds"])
        assert reach["target_cd"] == pytest.approx(1.1 * row["cd"])


def test_stage_times_are_non_negative_and_fit_in_the_step(smoke_run, speed):
    _, data = smoke_run
    for row in data["rows"]:
        breakdown = row["breakdown"]
        stages = breakdown["stages"]
        assert set(stages) == {*speed.STAGES, "other"}
        assert all(finite(v) and v >= 0 for v in stages.values()), stages
        step = breakdown["step_seconds"]
        assert finite(step) and step > 0 and breakdown["timed_steps"] == 3
        # medians of the stages need not add up exactly to the median step; within 25% (+ 2 ms) they must
        assert sum(v for k, v in stages.items() if k != "other") <= 1.25 * step + 0.002, (row["method"], stages, step)
        for name in ("sampling", "mlp", "rendering", "backward", "optimizer"):
            assert stages[name] > 0, (row["method"], name)
        assert (stages["sdf_gradient"] > 0) == row["method"].endswith("neus")
        assert stages["encoding"] > 0
        for name, value in breakdown["inclusive"].items():
            assert value >= stages[name] - 1e-9


def test_pictures_and_tables_are_written(smoke_run):
    out, _ = smoke_run
    for name in ("speed.png", "speed_stages.png"):
        data = (out / name).read_bytes()
        assert data.startswith(PNG) and len(data) > 5000, name
    text = (out / "speed.md").read_text()
    assert "| neus |" in text and "| va-ngp |" in text and "sdf_gradient" in text


@pytest.mark.parametrize("argv, message", [
    (["--methods", "neus", "nope"], "unknown method 'nope'"),
    (["--data", "/no/such/scene"], "not found: /no/such/scene"),
    (["--steps", "0"], "--steps must be at least 1"),
])
def test_bad_input_is_one_line_and_exit_2(speed, argv, message, capsys, tmp_path):
    assert speed.main(argv + ["--smoke", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], err
    assert not any(tmp_path.iterdir())  # refused before anything was built or trained


def test_stage_markers_are_exclusive_and_do_nothing_unless_recording():
    import time

    import torch
    from torch import nn

    from va_plugin.utils import stages

    @stages.timed("outer")
    def work(layer):
        with stages.stage("inner"):
            time.sleep(0.02)
        layer(torch.zeros(1, 2))
        time.sleep(0.01)

    layer = nn.Linear(2, 2)
    handles = stages.time_modules([layer], "layer")
    work(layer)  # not recording: no error, nothing kept
    with stages.recording() as recorder:
        work(layer)
    for handle in handles:
        handle.remove()
    assert stages._recorder is None
    assert recorder.inclusive["inner"] >= 0.02 and recorder.inclusive["outer"] >= 0.03
    assert recorder.exclusive["outer"] == pytest.approx(
        recorder.inclusive["outer"] - recorder.inclusive["inner"] - recorder.inclusive["layer"])
    assert 0.01 <= recorder.exclusive["outer"] < recorder.inclusive["outer"]


def test_time_to_reach_waits_until_the_cd_stays_close():
    speed = load_script("run_speed")
    curve = [{"train_seconds": 10.0, "step": 1, "cd": 0.030},   # touches 110% of 0.0276 (0.03036) by chance
             {"train_seconds": 20.0, "step": 2, "cd": 0.037},
             {"train_seconds": 30.0, "step": 3, "cd": 0.030},   # from here on it stays
             {"train_seconds": 40.0, "step": 4, "cd": 0.0276}]
    reach = speed.time_to_reach(curve)
    assert (reach["step"], reach["train_seconds"]) == (3, 30.0)
    assert (reach["first_touch_step"], reach["first_touch_seconds"]) == (1, 10.0)
    assert reach["target_cd"] == pytest.approx(1.1 * 0.0276)
    assert speed.time_to_reach([{"train_seconds": 5.0, "step": 9, "cd": 0.02}])["step"] == 9
    assert speed.time_to_reach([{"train_seconds": 5.0, "step": 9, "cd": None}])["step"] is None
