"""benchmarks/run_generated.py's bookkeeping: finding generator outputs, reading a run's log and maps,
the table. (Training itself is the CLI's, tested elsewhere; a real run on ../shared/data takes minutes.)"""

import json

import pytest
from bench_scripts import load_script

from va_plugin.bench.catalog import generator_outputs
from va_plugin.errors import ConfigError


@pytest.fixture(scope="module")
def gen():
    return load_script("run_generated")


def test_finds_pngs_and_folders_sorted_and_refuses_a_missing_root(gen, tmp_path):
    (tmp_path / "zero123pp").mkdir()
    (tmp_path / "syncdreamer").mkdir()
    for path in ("syncdreamer/b.png", "syncdreamer/a.png", "zero123pp/fox.png", "syncdreamer/notes.txt"):
        (tmp_path / path).write_bytes(b"")
    (tmp_path / "zero123pp" / "wonder_like").mkdir()
    names = [name for name, _ in generator_outputs(tmp_path)]
    assert names == ["a", "b", "fox", "wonder_like"]
    assert [name for name, _ in generator_outputs(tmp_path, folders=False)] == ["a", "b", "fox"]
    with pytest.raises(ConfigError, match="no generator outputs"):
        generator_outputs(tmp_path / "absent")


def test_reads_the_last_training_record_and_the_adaptive_decision(gen, tmp_path):
    rows = [{"loss": 1.0, "psnr": 12.0, "step": 10},
            {"step": 167, "event": "inputs disagree (...)", "residual_spread_db": 1.5},
            {"loss": 0.5, "psnr": 17.5, "step": 500}]
    (tmp_path / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\nnot json\n")
    got = gen.last_metrics(tmp_path)
    assert got == {"train_psnr": 17.5, "steps": 500, "adaptive_phases": "ran", "residual_spread_db": 1.5}
    (tmp_path / "metrics.jsonl").write_text(json.dumps({"step": 167, "event": "x", "skipped_adaptive": True}))
    assert gen.last_metrics(tmp_path)["adaptive_phases"].startswith("skipped")
    assert gen.last_metrics(tmp_path / "nothing") == {}


def test_inconsistency_summary_keeps_small_values_and_the_table_shows_them(gen, tmp_path):
    assert gen.inconsistency_summary(tmp_path) is None
    maps = {"views": [{"view": 0, "mean_abs_difference": 2.8680e-05}, {"view": 1, "mean_abs_difference": 0.0123456}]}
    (tmp_path / "inconsistency.json").write_text(json.dumps(maps))
    summary = gen.inconsistency_summary(tmp_path)
    assert summary == [2.87e-05, 0.0123]
    rows = [{"input": "syncdreamer/a.png", "method": "va-neus", "wall_seconds": 12.3, "steps": 500,
             "train_psnr": 17.0, "silhouette_iou_mean": 0.9, "silhouette_iou_min": 0.85,
             "adaptive_phases": "ran", "residual_spread_db": 1.2, "inconsistency": summary}]
    gen.write_tables(rows, tmp_path)
    table = (tmp_path / "generated.md").read_text().splitlines()
    assert len(table) == 3 and table[0].count("|") == table[2].count("|")
    assert "2.9e-05" in table[2] and "0.900 / 0.850" in table[2] and "| 1.2 |" in table[2]
    assert json.loads((tmp_path / "generated.json").read_text()) == rows


def test_shared_path_psnr_renders_the_training_views_and_caches(gen, tiny_scene, tmp_path):
    from conftest import tiny_config

    assert gen.shared_path_psnr(tmp_path) is None  # no checkpoint: nothing to render
    run = tmp_path / "run"
    tiny_config("va-neus", tiny_scene, run, steps=2).setup().train()
    value = gen.shared_path_psnr(run)
    cached = json.loads((run / "train_views_psnr.json").read_text())
    assert 0.0 < value < 60.0 and cached["mean_psnr"] == value and len(cached["per_view_psnr"]) == 4
    cached["mean_psnr"] = 99.0  # a second call reads the cache instead of rendering again
    (run / "train_views_psnr.json").write_text(json.dumps(cached))
    assert gen.shared_path_psnr(run) == 99.0


def test_a_variant_made_with_set_needs_a_label_and_reaches_the_run(gen, tmp_path, monkeypatch):
    data = tmp_path / "data" / "syncdreamer"
    data.mkdir(parents=True)
    (data / "a.png").write_bytes(b"")
    with pytest.raises(SystemExit):  # argparse's error: one line, exit 2
        gen.main(["--data-root", str(tmp_path / "data"), "--out", str(tmp_path / "out"),
                  "--set", "pipeline.model.field.shared_color_weight=1"])
    with pytest.raises(SystemExit):
        gen.main(["--data-root", str(tmp_path / "data"), "--out", str(tmp_path / "out"), "--label", "a b"])
    seen = []

    def fake_run(method, source, run_dir, args):  # what run_one would train: its arguments and folder
        seen.append((method, run_dir.name, list(args.set)))
        raise SystemExit(0)

    monkeypatch.setattr(gen, "run_one", fake_run)
    with pytest.raises(SystemExit):
        gen.main(["--data-root", str(tmp_path / "data"), "--out", str(tmp_path / "out"), "--methods", "va-neus",
                  "--set", "pipeline.model.field.shared_color_weight=1", "--label", "shared"])
    assert seen == [("va-neus", "a-va-neus-shared", ["pipeline.model.field.shared_color_weight=1"])]


def test_the_mesh_figure_keeps_a_column_for_a_run_without_a_mesh(gen, tiny_scene, tmp_path):
    import trimesh

    from va_plugin.data.images import read_image

    (tmp_path / "runs" / "one-neus").mkdir(parents=True)
    trimesh.creation.icosphere(subdivisions=2, radius=0.4).export(tmp_path / "runs" / "one-neus" / "mesh.ply")
    inputs = [("one", tiny_scene), ("two", tiny_scene)]  # "two" has no mesh at all: no row
    path = gen.summary_figure(inputs, ["neus", "va-neus"], tmp_path, frames=2, resolution=24)
    image = read_image(path)
    assert image.shape[:2] == (24, 24 * (1 + 2 * 2))
    neus, missing = image[:, 24:72], image[:, 72:]
    assert neus.min() < 0.9 and missing.min() > 0.99  # the sphere is drawn; the absent run is white
    assert gen.summary_figure([("two", tiny_scene)], ["neus"], tmp_path) is None
