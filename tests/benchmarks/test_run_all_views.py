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


def test_a_variant_is_paired_with_the_default_at_its_own_view_count(allviews):
    rows = [row("a", 4, "", 0.02, 22.0, 100), row("a", 16, "", 0.010, 24.0, 100),
            row("a", 16, "half", 0.011, 23.0, 50)]
    text = allviews.table(rows, [(4, ""), (16, ""), (16, "half")])
    assert "16 views against 4 views, paired over 1 objects: CD x0.500" in text
    assert "16 views half against 16 views, paired over 1 objects: CD x1.100" in text


def test_a_worker_takes_sigint_even_when_its_main_process_runs_in_the_background(allviews):
    import os
    import signal

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)  # what `cmd &` hands a spawned worker
    try:
        allviews.start_worker(os.getppid())  # the watch stays asleep: this process's parent lives on
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)
