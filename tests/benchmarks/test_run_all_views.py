"""benchmarks/run_all_views.py's table, figure and option checks (training is the trainer's, tested elsewhere;
a real row takes minutes on ../shared/data)."""

import pytest

from bench_scripts import load_script


@pytest.fixture(scope="module")
def allviews():
    return load_script("run_all_views")


def row(name, views, variant, cd, psnr, wall):
    return {"key": f"{name}-{views}-{variant}", "object": name, "views": views, "level": 2, "variant": variant,
            "cd": cd, "iou": 0.5, "psnr": psnr, "ssim": 0.9, "lpips": 0.1, "wall_seconds": wall,
            "train_seconds": wall - 10}


def test_pairs_each_configuration_with_the_first_and_names_the_worst_object(allviews):
    rows = [row("a", 16, "", 0.010, 24.0, 110), row("b", 16, "", 0.020, 22.0, 110),
            row("a", 16, "half", 0.011, 23.5, 60), row("b", 16, "half", 0.019, 22.2, 60),
            row("c", 16, "half", 0.050, 20.0, 60)]  # c has no default row: left out of the pairing
    text = allviews.table(rows, [(16, ""), (16, "half")])
    assert "16 views half against 16 views, paired over 2 objects" in text
    assert "CD x1.000 (lower on 1/2; worst x1.100)" in text
    assert "PSNR -0.15 dB (worst -0.50)" in text
    assert "wall x0.545" in text
    assert "mean of 16 views half over 3 objects" in text
    assert "| c | - | 0.05 / 0.5 / 20 / 0.1 / 60 |" in text


def test_refuses_overrides_without_a_variant_name_and_a_mistyped_key(allviews, tmp_path, capsys):
    with pytest.raises(SystemExit, match="--set needs --variant"):
        allviews.main(["--set", "max_steps=10", "--out", str(tmp_path), "--objects", "x"])
    with pytest.raises(SystemExit, match="rays_per_batch"):
        allviews.main(["--set", "pipeline.datamanager.rayz=3", "--variant", "v", "--out", str(tmp_path),
                       "--objects", "x"])


def test_figure_plots_the_objects_every_configuration_has(allviews, tmp_path):
    pytest.importorskip("matplotlib")
    rows = [row("a", 16, "", 0.01, 24.0, 110), row("a", 16, "half", 0.011, 23.5, 60)]
    path = allviews.time_figure(rows, [(16, ""), (16, "half")], tmp_path / "t.png")
    assert path is not None and path.stat().st_size > 1000
    assert allviews.time_figure(rows[:1], [(16, ""), (16, "half")], tmp_path / "u.png") is None


def test_stop_decision_replays_the_rule_from_the_log_and_the_table_scores_it(allviews, tmp_path):
    from va_plugin.engine.metrics_log import append_record

    for step, change in ((500, None), (600, 0.02), (700, 0.004), (800, 0.02), (900, 0.003), (1000, 0.002)):
        append_record(tmp_path, {"step": step, "stop_change": change, "stop_settled": 0})
    assert allviews.stop_decision(tmp_path, 0.01, 2, 2000) == 1000
    assert allviews.stop_decision(tmp_path, 0.01, 1, 2000) == 700
    assert allviews.stop_decision(tmp_path, 0.01, 2, 1000) is None  # the budget's end: nothing saved
    rows = [{**row("a", 16, "r", 0.010, 24.0, 110), "steps": 2000,
             "stop": {"tolerance": 0.01, "patience": 2, "step": 1000, "psnr": 23.9, "cd": 0.0104,
                      "train_seconds": 50.0}},
            {**row("b", 16, "r", 0.020, 22.0, 110), "steps": 2000,
             "stop": {"tolerance": 0.01, "patience": 2, "step": 1200, "psnr": 21.5, "cd": 0.02,
                      "train_seconds": 60.0}}]
    text = "\n".join(allviews.stop_lines(rows, "16 views r"))
    assert "| a | 1000 | 50 (100) | -0.10 dB | x1.040 | yes |" in text
    assert "| b | 1200 | 60 (100) | -0.50 dB | x1.000 | no |" in text
    assert "Right on 1/2" in text and "saved: 90 of 200 s (45%)" in text
