"""The benchmark library: row plans, paired configs, scene names, the result store and resume, reports."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest
from bench_scripts import scripts  # noqa: F401  (fixture)

from va_plugin.bench import experiment
from va_plugin.bench.catalog import SceneSpec, expand_scene_names, input_error
from va_plugin.bench.presets import get_preset
from va_plugin.bench.report import delta_table, metric_delta, summary_table
from va_plugin.bench.rows import RowSpec, fingerprint, row_config, run_row, scene_of
from va_plugin.bench.store import ResultStore
from va_plugin.config import to_dict
from va_plugin.errors import ConfigError, VAError

SMOKE = get_preset("smoke")


def args_for(script, *extra):
    from va_plugin.cli.bench import build_parser

    return build_parser(script.EXPERIMENT).parse_args(["--preset", "smoke", *extra])


# -- plans and configs ---------------------------------------------------------------------------------------
def test_paired_rows_share_inputs_seed_and_budget(tmp_path):
    scene = scene_of("procedural:mug", SMOKE, seed=7)
    original = row_config(RowSpec("t", scene, "neus", False), SMOKE, tmp_path / "scene", tmp_path / "a", seed=7)
    adaptive = row_config(RowSpec("t", scene, "neus", True), SMOKE, tmp_path / "scene", tmp_path / "b", seed=7)
    assert to_dict(original.pipeline.datamanager) == to_dict(adaptive.pipeline.datamanager)
    assert original.seed == adaptive.seed == 7 and original.max_steps == adaptive.max_steps == 3
    assert to_dict(adaptive.pipeline.model.field.base) == to_dict(original.pipeline.model.field)
    model_a, model_o = to_dict(adaptive.pipeline.model), to_dict(original.pipeline.model)
    assert {k for k in model_o if model_o[k] != model_a[k]} == {"field"}
    assert adaptive.pipeline.model.field.diagnostics_scale == 0  # outside the timed training
    assert fingerprint(original, SMOKE.evaluation, tmp_path) != fingerprint(adaptive, SMOKE.evaluation, tmp_path)


def test_table1_plan_pairs_every_scene_and_backbone(scripts):
    args = args_for(scripts["table1"], "--scenes", "mug,knot")
    rows = scripts["table1"].plan(SMOKE, args, expand_scene_names(["mug", "knot"], None))
    assert [(r.scene.name, r.method) for r in rows[:4]] == [("mug", "neus"), ("mug", "va-neus"),
                                                            ("mug", "ngp"), ("mug", "va-ngp")]
    assert len(rows) == 8 and len({r.key for r in rows}) == 8


def test_views_and_sweep_vary_their_axis(scripts):
    views = scripts["views"].plan(SMOKE, args_for(scripts["views"], "--view-counts", "4,8,16"), ["procedural:mug"])
    assert sorted({r.scene.views for r in views}) == [4, 8, 16] and len({r.key for r in views}) == len(views) == 12
    sweep = scripts["sweep"].plan(SMOKE, args_for(scripts["sweep"], "--backbones", "neus"), ["procedural:mug"])
    assert [r.scene.level for r in sweep] == [0, 0, 2, 2]


def test_adaptive_set_changes_the_adaptive_rows_only(scripts, tmp_path):
    setting = "pipeline.model.field.shared_lr_scale=0.5"
    args = args_for(scripts["table1"], "--backbones", "ngp", "--adaptive-set", setting)
    rows = scripts["table1"].plan(SMOKE, args, ["procedural:mug"])
    configs = [row_config(r, SMOKE, tmp_path, tmp_path / r.key) for r in rows]
    assert [r.overrides for r in rows] == [(), (setting,)]
    assert configs[1].pipeline.model.field.shared_lr_scale == 0.5
    default = row_config(scripts["table1"].plan(SMOKE, args_for(scripts["table1"], "--backbones", "ngp"),
                                                ["procedural:mug"])[1], SMOKE, tmp_path, tmp_path / "d")
    assert fingerprint(default, SMOKE.evaluation, tmp_path) != fingerprint(configs[1], SMOKE.evaluation, tmp_path)
    ablation = scripts["ablation"].plan(SMOKE, args_for(scripts["ablation"], "--adaptive-set", setting),
                                        ["procedural:mug"])
    assert [setting in r.overrides for r in ablation] == [False] + [True] * 4
    with pytest.raises(ConfigError, match="PATH=VALUE"):
        scripts["table1"].plan(SMOKE, args_for(scripts["table1"], "--adaptive-set", "shared_lr_scale"),
                               ["procedural:mug"])


def test_ablation_rows_are_cumulative_and_force_the_adaptive_phases(scripts, tmp_path):
    rows = scripts["ablation"].plan(SMOKE, args_for(scripts["ablation"]), ["procedural:mug"])
    assert [r.method for r in rows] == ["neus"] + ["va-neus"] * 4
    fields = [row_config(r, SMOKE, tmp_path, tmp_path / r.key).pipeline.model.field for r in rows[1:]]
    assert [(f.fusion, f.entropy_weight > 0, f.consistency_weight > 0) for f in fields] == [
        (False, False, False), (True, False, False), (True, True, False), (True, True, True)]
    assert all(f.branches and not f.skip_consistent_scenes for f in fields)
    assert rows[0].overrides == ()


def test_scene_names(tmp_path):
    assert expand_scene_names(["mug", "procedural:knot", "mug"], None) == ["procedural:mug", "procedural:knot"]
    assert len(expand_scene_names(["procedural"], None)) >= 6
    with pytest.raises(ConfigError):
        expand_scene_names(["gso:alarm"], None)
    with pytest.raises(VAError):
        expand_scene_names(["gso:alarm"], tmp_path)  # no GSO objects there
    assert expand_scene_names(["gso"], tmp_path) == []  # the group is just empty (with a note)
    with pytest.raises(ConfigError):
        expand_scene_names(["teapot-of-doom"], None)
    assert SceneSpec("gso:alarm", level=3).folder_name == "gso-alarm-l3-v4-r256-s42"
    fewer = SceneSpec("gso:alarm", level=3, kinds=("geometric", "pose"))
    assert fewer.name == "gso-alarm+geometric+pose" and fewer.folder_name == "gso-alarm+geometric+pose-l3-v4-r256-s42"
    assert SceneSpec("procedural:mug", kinds=()).name == "mug+none"


def test_input_error_is_the_mean_per_view_rmse(tmp_path):
    per_view = [{"view": 0, "perturbed": False, "psnr": 100.0},
                {"view": 4, "perturbed": True, "psnr": 20.0}, {"view": 8, "perturbed": True, "psnr": 40.0}]
    (tmp_path / "scene.json").write_text(json.dumps({"inconsistency": {"mean_psnr": 30.0, "per_view": per_view}}))
    error = input_error(tmp_path)
    assert error["input_psnr"] == 30.0
    assert error["input_rmse"] == pytest.approx((0.1 + 0.01) / 3, abs=1e-5)


# -- resume ----------------------------------------------------------------------------------------------------
def fake_result(row, config, scene_dir, evaluation, row_fingerprint, **_):
    return {"experiment": row.experiment, "key": row.key, "fingerprint": row_fingerprint, "scene": row.scene.name,
            "method": row.method, "backbone": row.backbone, "adaptive": row.adaptive, "psnr": 20.0, "ssim": 0.8,
            "lpips": 0.1, "cd": 0.02 if row.adaptive else 0.025, "iou": 0.6, "fscore": 0.5, "train_seconds": 1.0,
            "steps": config.max_steps, "variant": row.label, "level": row.scene.level, "views": row.scene.views,
            "seed": config.seed, "adaptive_ran": row.adaptive, "input_psnr": 25.0, "input_rmse": 0.04,
            "eval_seconds": 0.1, "curve": [{"step": config.max_steps, "train_seconds": 1.0, "cd": 0.02, "psnr": 20.0}]}


def test_an_interrupt_loses_only_the_row_in_flight(scripts, tiny_scene, tmp_path, monkeypatch):
    monkeypatch.setattr(experiment, "ensure_scene", lambda *args: tiny_scene)
    calls = []

    def interrupted_third(row, *args, **kwargs):
        calls.append(row.key)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return fake_result(row, *args, **kwargs)

    monkeypatch.setattr(experiment, "run_row", interrupted_third)
    argv = ["--preset", "smoke", "--out", str(tmp_path / "out")]
    assert scripts["table1"].main(argv) == experiment.EXIT_INTERRUPTED
    assert len((tmp_path / "out" / "rows.jsonl").read_text().splitlines()) == 2
    first = list(calls)

    calls.clear()
    monkeypatch.setattr(experiment, "run_row", lambda row, *a, **k: calls.append(row.key) or fake_result(row, *a, **k))
    assert scripts["table1"].main(argv + ["--resume"]) == 0
    assert len(calls) == 2 and calls[0] == first[2]  # the row in flight, then the one never started
    rows = json.loads((tmp_path / "out" / "table1.json").read_text())["rows"]
    assert [r["method"] for r in rows] == ["neus", "va-neus", "ngp", "va-ngp"]

    # changed settings make a stored row stale: it runs again
    calls.clear()
    assert scripts["table1"].main(argv + ["--resume", "--steps", "2"]) == 0
    assert len(calls) == 4


@pytest.mark.parametrize("jobs", ["0", "-2"])
def test_jobs_below_one_are_refused(jobs, scripts, tmp_path, capsys):
    assert scripts["table1"].main(["--preset", "smoke", "--out", str(tmp_path / "out"), "--jobs", jobs]) == 2
    assert capsys.readouterr().err.strip() == f"error: --jobs must be at least 1, got {jobs}"
    assert not (tmp_path / "out").exists()


def test_a_row_failing_in_a_worker_stops_the_benchmark_with_its_error(scripts, tmp_path, monkeypatch, capfd):
    import multiprocessing

    monkeypatch.setattr(experiment, "ensure_scene", lambda *args: tmp_path)  # no scene there: setup() raises
    argv = ["--preset", "smoke", "--out", str(tmp_path / "out"), "--device", "cpu", "--jobs", "2"]
    assert scripts["table1"].main(argv) == 2
    captured = capfd.readouterr()
    assert "NeuS: failed in its worker process; stopping the other rows" in captured.out
    assert captured.err.strip().splitlines()[-1].startswith(f"error: {tmp_path} holds neither transforms")
    assert not multiprocessing.active_children()


def test_store_ignores_a_line_cut_short(tmp_path):
    store = ResultStore(tmp_path, resume=False)
    store.add({"key": "a", "fingerprint": "f", "cd": float("nan")})
    with open(store.path, "a") as handle:
        handle.write('{"key": "b", "finger')
    again = ResultStore(tmp_path, resume=True)
    assert math.isnan(again.finished("a", "f")["cd"])
    assert again.finished("a", "other") is None and again.finished("b", "f") is None


def test_an_interrupted_row_continues_from_its_checkpoint(tiny_scene, tmp_path, monkeypatch):
    from va_plugin.engine.trainer import Trainer

    preset = get_preset("smoke")
    evaluation = dataclasses.replace(preset.evaluation, image_scale=1.5)  # LPIPS needs 31 px; tiny_scene has 24
    row = RowSpec("t", scene_of("procedural:mug", preset, 42), "neus", False)
    config = row_config(row, preset, tiny_scene, tmp_path / "run", device="cpu")
    config.max_steps, config.checkpoint_every = 2, 1
    digest = fingerprint(config, evaluation, tmp_path)
    real_step = Trainer._step

    def stop_after_first(self):
        if self.step == 1:
            raise KeyboardInterrupt
        return real_step(self)

    monkeypatch.setattr(Trainer, "_step", stop_after_first)
    saved = []
    with pytest.raises(KeyboardInterrupt):
        run_row(row, config, tiny_scene, evaluation, digest, on_interrupt=saved.append)
    assert saved and saved[0].name == "step-0000001.ckpt"
    monkeypatch.setattr(Trainer, "_step", real_step)
    result = run_row(row, config, tiny_scene, evaluation, digest)
    assert result["resumed_from_step"] == 1 and result["steps"] == 2
    assert [p["step"] for p in result["curve"]] == [1, 2]


# -- reports ---------------------------------------------------------------------------------------------------
def test_summary_and_delta_tables():
    rows = []
    for scene, (cd_o, cd_a) in {"a": (0.02, 0.015), "b": (0.04, 0.036)}.items():
        for adaptive, cd in ((False, cd_o), (True, cd_a)):
            rows.append({"scene": scene, "level": 2, "views": 4, "backbone": "neus", "adaptive": adaptive,
                         "variant": "VA" if adaptive else "Orig", "psnr": 20.0 + adaptive, "ssim": 0.8,
                         "lpips": float("nan"), "cd": cd, "iou": 0.5, "fscore": 0.4,
                         "train_seconds": 10.0 * (1 + 0.5 * adaptive)})
    summary = summary_table(rows)
    assert "| Orig | 20.00 ± 0.00 | 0.800 ± 0.000 | n/a | 0.0300 ± 0.0141 |" in summary
    deltas = delta_table(rows, {"neus": {"original": {"cd": 0.0168}, "adaptive": {"cd": 0.0122}}})
    assert "+1.00 ± 0.00 (2/2 better)" in deltas  # PSNR
    assert "-18% ± 11% (2/2 better)" in deltas     # CD: -25% and -10% (sd 10.6)
    assert "1.50x" in deltas and "-27%" in deltas
    assert metric_delta("cd", 0.02, float("nan")) != metric_delta("cd", 0.02, float("nan"))  # NaN


def test_sweep_verdict_on_synthetic_rows(scripts):
    rows = []
    for level, x in enumerate((0.0, 0.02, 0.04, 0.06)):
        for adaptive, slope in ((False, 0.5), (True, 0.2)):
            rows.append({"scene": "s", "level": level, "views": 4, "backbone": "neus", "adaptive": adaptive,
                         "variant": "VA" if adaptive else "Orig", "input_rmse": x, "input_psnr": 30.0,
                         "cd": 0.01 + slope * x, "psnr": 25.0 - 100 * slope * x, "steps": 3})
    table = scripts["sweep"].claims_table(rows)
    cd_line = next(line for line in table.splitlines() if "Chamfer" in line)
    assert "yes: slope 0.5000" in cd_line and "yes: ratio adaptive/original 0.40" in cd_line


@pytest.mark.parametrize("name", ["views", "ablation", "sweep"])
def test_every_script_writes_its_report(name, scripts, tiny_scene, tmp_path, monkeypatch):
    monkeypatch.setattr(experiment, "ensure_scene", lambda *args: tiny_scene)
    monkeypatch.setattr(experiment, "run_row", fake_result)
    out = tmp_path / name
    assert scripts[name].main(["--preset", "smoke", "--out", str(out)]) == 0
    data = json.loads((out / f"{name}.json").read_text())
    assert len(data["rows"]) == {"views": 8, "ablation": 5, "sweep": 8}[name]
    assert len((out / f"{name}.csv").read_text().splitlines()) == len(data["rows"]) + 1
    assert "## Per scene" in (out / f"{name}.md").read_text()
    assert any(p.suffix == ".png" and p.stat().st_size > 1000 for p in out.iterdir())


def test_result_store_skips_a_line_cut_short_by_a_crash(tmp_path):
    from va_plugin.bench.store import read_json_lines

    rows = tmp_path / "rows.jsonl"
    rows.write_text(json.dumps({"key": "a", "psnr": 20.0}) + "\n\n" + json.dumps({"key": "b", "psnr": 21.0})
                    + "\n" + '{"key": "c", "ps')
    records, skipped = read_json_lines(rows)
    assert [r["key"] for r in records] == ["a", "b"] and skipped == 1  # the blank line is not counted
    assert sorted(ResultStore(tmp_path, resume=True).rows) == ["a", "b"]


def test_a_scripts_row_file_resumes_by_its_key(tmp_path):
    """The JSON-lines files the one-off scripts append to: a later row replaces an earlier one with its key,
    NaN is written as null, and a missing file is no rows."""
    from va_plugin.bench.store import append_row, keyed_rows

    rows = tmp_path / "out" / "rows.jsonl"
    assert keyed_rows(rows, lambda row: row["run"]) == {}
    for row in ({"run": "a", "lpips": 0.1}, {"run": "b", "lpips": float("nan")}, {"run": "a", "lpips": 0.2}):
        append_row(rows, row)
    assert keyed_rows(rows, lambda row: row["run"]) == {"a": {"run": "a", "lpips": 0.2},
                                                        "b": {"run": "b", "lpips": None}}
