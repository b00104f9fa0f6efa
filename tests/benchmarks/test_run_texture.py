"""benchmarks/run_texture.py end to end on a tiny run: one JSON line per run (field, robust and mean
scores, bake counts, a timed bake from more views), resumable, and the summary table."""

import json

import pytest
from conftest import tiny_config

from bench_scripts import load_script


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from va_plugin.data.scenes.builder import build_procedural_scene

    scene = build_procedural_scene(tmp_path_factory.mktemp("scene32"), "mug", n_views=4, resolution=32)
    out = tmp_path_factory.mktemp("run")
    tiny_config("neus", scene, out, steps=2).setup().train()
    return out


def test_scores_field_and_both_fusions_and_resumes(run, tmp_path, capsys):
    script = load_script("run_texture")
    out = tmp_path / "texture.jsonl"
    argv = ["--runs", str(run), "--out", str(out), "--texture-size", "32", "--max-views", "1", "--timing-views", "6"]
    assert script.main(argv) == 0
    record = json.loads(out.read_text())
    for part in ("field", "robust", "mean"):
        assert set(record[part]) >= {"psnr", "ssim", "lpips"}
    assert record["robust"]["texels_seen"] > 0 and "bake" in record["bake_6_views_seconds"]
    assert (run / "texture_bake.png").exists()
    table = capsys.readouterr().out
    assert "| median |" in table and run.name in table
    assert script.main(argv) == 0  # a finished run is not redone
    assert len(out.read_text().splitlines()) == 1
    assert script.main(argv[:-5] + ["100", "--max-views", "1"]) == 2  # not a power of two: one line, exit 2
