"""benchmarks/bench_skipping.py: reading a finished run and the ratios it reports (no training here)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_skipping.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_skipping", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _fake_run(run_dir: Path, samples, seconds: float, cd: float) -> Path:
    run_dir.mkdir(parents=True)
    lines = [{"loss": 0.1, "samples_per_ray": s, "probed_per_ray": 2 * s, "step": 25 * (i + 1),
              "train_seconds": seconds * (i + 1) / len(samples)} for i, s in enumerate(samples)]
    lines.append({"step": 25 * len(samples), "eval_psnr": 20.0})  # a periodic-eval line has no loss
    (run_dir / "metrics.jsonl").write_text("\n".join(json.dumps(line) for line in lines) + "\n")
    (run_dir / "eval.json").write_text(json.dumps({"psnr": 20.0, "cd": cd, "iou": 0.3,
                                                   "image_params": {"width": 128}}))
    return run_dir


def test_summary_averages_the_logged_samples_and_reads_eval(bench, tmp_path):
    row = bench.summarise_run(_fake_run(tmp_path / "ngp", [96.0, 20.0, 10.0, 10.0], seconds=50.0, cd=0.03))
    assert row["steps"] == 100 and row["it_per_s_whole_run"] == 2.0
    assert row["samples_per_ray_mean"] == 34.0 and row["samples_per_ray_final"] == 10.0
    assert row["probed_per_ray_mean"] == 68.0
    assert row["cd"] == 0.03 and row["psnr"] == 20.0 and row["eval_image_params"] == {"width": 128}


def test_ratios_compare_each_variant_with_its_methods_default(bench):
    results = {"ngp": {"samples_per_ray_mean": 10.0, "timing": {"it_per_s": 8.0}},
               "ngp-no-skipping": {"samples_per_ray_mean": 96.0, "timing": {"it_per_s": 2.0}},
               "neus": {"samples_per_ray_mean": 40.0, "timing": {"it_per_s": 4.0}}}
    ratios = bench.ratios(results)
    assert ratios == {"ngp / ngp-no-skipping it/s": 4.0, "ngp-no-skipping / ngp samples per ray": 9.6,
                      "ngp / neus it/s": 2.0}


def test_rendered_ray_shares_count_rays_left_without_samples(bench, tiny_scene, tmp_path):
    from conftest import tiny_config

    small = {"pipeline.model.occupancy_grid.resolution": 8, "pipeline.model.field.n_levels": 4,
             "pipeline.model.field.log2_hashmap_size": 10, "pipeline.model.field.max_resolution": 32}
    trainer = tiny_config("ngp", tiny_scene, tmp_path / "ngp", **small).setup()
    assert bench.rendered_ray_shares(trainer, batches=1)["foreground_rays_rendered"] == 1.0
    trainer.model.occupancy_grid.binary.fill_(False)  # every sample skipped: nothing is rendered
    assert bench.rendered_ray_shares(trainer, batches=1) == {"background_rays_rendered": 0.0,
                                                             "foreground_rays_rendered": 0.0}
