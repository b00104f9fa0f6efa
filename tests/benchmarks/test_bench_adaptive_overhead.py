"""bench_adaptive_overhead: interleaved step timing of the adaptive phases, with overrides of their config."""

from bench_scripts import load_script
from conftest import tiny_config
from va_plugin.engine.trainer import load_checkpoint


def test_measure_times_every_variant_and_applies_the_adaptive_overrides(tiny_scene, tmp_path):
    bench = load_script("bench_adaptive_overhead")
    trainer = tiny_config("neus", tiny_scene, tmp_path / "run", steps=2).setup()
    trainer.train()
    state = load_checkpoint(tmp_path / "run")
    result = bench.measure(tiny_scene, "neus", state, tmp_path / "scratch", rounds=1, steps=1,
                           adaptive_set=("pipeline.model.field.branch_width=8",
                                         "pipeline.model.field.branch_layers=1"))
    assert set(result["median_step_s"]) == {"neus", "phase2", "phase3"}
    assert all(v > 0 for v in result["median_step_s"].values())
    assert result["adaptive_set"] == ["pipeline.model.field.branch_width=8", "pipeline.model.field.branch_layers=1"]
    assert result["predicted_run_ratio"] > 0 and result["samples"] == {"neus": 1, "phase2": 1, "phase3": 1}
