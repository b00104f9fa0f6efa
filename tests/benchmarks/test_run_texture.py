"""benchmarks/run_texture.py end to end on a tiny run: one JSON line per run (field, robust and mean
scores, bake counts, a timed bake from more views), resumable, and the summary table."""

import json

import pytest
from bench_scripts import load_script
from conftest import tiny_trained_run


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return tiny_trained_run(tmp_path_factory)


def test_scores_field_and_both_fusions_and_resumes(run, tmp_path, capsys):
    script = load_script("run_texture")
    out = tmp_path / "texture.jsonl"
    argv = ["--runs", str(run), "--out", str(out), "--texture-size", "32", "--max-views", "1", "--timing-views", "6",
            "--bakes", "robust-plain"]
    assert script.main(argv) == 0
    record = json.loads(out.read_text())
    for part in ("field", "robust", "mean", "robust-plain"):
        assert set(record[part]) >= {"psnr", "ssim", "lpips"}
    assert "mean-harmonised" not in record
    assert record["robust"]["texels_seen"] > 0 and "bake" in record["bake_6_views_seconds"]
    assert "view_color_gain" in record["robust"] and "view_color_gain" not in record["robust-plain"]
    assert (run / "texture_bake.png").exists()
    table = capsys.readouterr().out
    assert "| median |" in table and run.name in table
    assert script.main(argv) == 0  # a finished run is not redone
    assert len(out.read_text().splitlines()) == 1
    # the same run on another mesh grid is another measurement: scored and appended, not skipped as done
    assert script.main(argv + ["--mesh-resolution", "32"]) == 0
    records = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r.get("mesh_resolution") for r in records] == [128, 32]
    assert [r["supersample"] for r in records] == [1, 1]
    # 2x2 rays a pixel is another measurement too; a record without the key was scored with 2x2 rays
    assert script.main(argv + ["--supersample", "2"]) == 0
    records = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r["supersample"] for r in records] == [1, 1, 2]
    assert records[2]["field"] == records[0]["field"] and records[2]["robust"]["psnr"] != records[0]["robust"]["psnr"]
    assert (script.resume_key({k: v for k, v in records[2].items() if k != "supersample"})
            == script.resume_key(records[2]))
    assert script.main(argv + ["--supersample", "0"]) == 2
    assert script.main(argv[:-7] + ["100", "--max-views", "1"]) == 2  # not a power of two: one line, exit 2
    assert script.main(argv[:-2] + ["--bakes", "median"]) == 2  # an unknown bake: one line, exit 2


def test_field_scores_can_come_from_the_benchmark_row(run, tmp_path):
    """--reuse-field-scores reads RUN/bench_row.json (every held-out view) instead of rendering the field
    again; with --max-views the field is rendered here as before."""
    import shutil

    script = load_script("run_texture")
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    row = {"psnr": 1.5, "ssim": 0.25, "lpips": 0.75, "evaluation": {"image_params": {"views": 3}}}
    (copy / "bench_row.json").write_text(json.dumps(row))
    out = tmp_path / "a.jsonl"
    base = ["--runs", str(copy), "--texture-size", "32", "--timing-views", "0", "--reuse-field-scores",
            "--mesh-resolution", "32"]
    assert script.main(base + ["--out", str(out)]) == 0
    record = json.loads(out.read_text())
    assert record["field"] == {"psnr": 1.5, "ssim": 0.25, "lpips": 0.75} and record["views"] == 3
    assert record["field_from"].endswith("bench_row.json")
    out = tmp_path / "b.jsonl"
    assert script.main(base + ["--out", str(out), "--max-views", "1"]) == 0
    record = json.loads(out.read_text())
    assert record["field"]["psnr"] != 1.5 and "field_from" not in record


def test_field_scores_come_from_the_results_folders_rows_when_the_marker_holds_none(run, tmp_path, capsys):
    """run_backbone's marker (RUN/bench_row.json) holds only the row's key; its scores are in the rows.jsonl
    of the results folder above the run, found by the row's run_dir. Without either the field is rendered,
    and the script says so."""
    import shutil

    script = load_script("run_texture")
    results = tmp_path / "results"
    copy = results / "runs" / "scene" / "neus"
    shutil.copytree(run, copy)
    (copy / "bench_row.json").write_text(json.dumps({"key": "scene/neus", "fingerprint": "abc"}))
    other = {"key": "other/neus", "run_dir": str(tmp_path / "elsewhere"), "psnr": 9.0, "ssim": 0.5, "lpips": 0.5,
             "evaluation": {"image_params": {"views": 3}}}
    mine = {**other, "key": "scene/neus", "run_dir": str(copy), "psnr": 1.5, "ssim": 0.25, "lpips": 0.75}
    (results / "rows.jsonl").write_text(json.dumps(other) + "\n" + json.dumps(mine) + "\n")
    base = ["--runs", str(copy), "--texture-size", "32", "--timing-views", "0", "--reuse-field-scores",
            "--mesh-resolution", "32"]
    assert script.main(base + ["--out", str(tmp_path / "a.jsonl")]) == 0
    record = json.loads((tmp_path / "a.jsonl").read_text())
    assert record["field"] == {"psnr": 1.5, "ssim": 0.25, "lpips": 0.75} and record["views"] == 3
    assert record["field_from"] == str(results / "rows.jsonl")
    (results / "rows.jsonl").write_text(json.dumps(other) + "\n")
    capsys.readouterr()
    assert script.main(base + ["--out", str(tmp_path / "b.jsonl"), "--mesh-resolution", "24"]) == 0
    assert "no benchmark row with its scores found" in capsys.readouterr().out
    assert "field_from" not in json.loads((tmp_path / "b.jsonl").read_text())


def test_the_ground_truth_mesh_or_a_finer_grid_can_be_textured(run, tmp_path):
    """--mesh truth textures the scene's ground-truth mesh (how much of the score is the geometry's);
    --mesh-resolution sets the extracted mesh's grid; a resolution out of range is one line, exit 2."""
    script = load_script("run_texture")
    base = ["--runs", str(run), "--texture-size", "32", "--max-views", "1", "--timing-views", "0"]
    out = tmp_path / "truth.jsonl"
    assert script.main(base + ["--out", str(out), "--mesh", "truth"]) == 0
    truth = json.loads(out.read_text())
    out = tmp_path / "fine.jsonl"
    assert script.main(base + ["--out", str(out), "--mesh-resolution", "48"]) == 0
    fine = json.loads(out.read_text())
    assert truth["mesh"] == "truth" and "mesh_resolution" not in truth
    assert fine["mesh"] == "extracted" and fine["mesh_resolution"] == 48
    assert truth["faces"] != fine["faces"] and truth["robust"]["texels_seen"] > 0
    assert script.main(base + ["--out", str(tmp_path / "bad.jsonl"), "--mesh-resolution", "4"]) == 2
    assert fine["max_faces"] == 40000 and fine["faces_textured"] <= fine["faces"]
    assert script.main(base + ["--out", str(tmp_path / "bad.jsonl"), "--max-faces", "2"]) == 2


def test_the_ground_truth_mesh_of_a_scene_without_one_is_one_error_line(run, tmp_path, monkeypatch, capsys):
    script = load_script("run_texture")
    monkeypatch.setattr(script, "ground_truth_mesh_path", lambda pipeline: None)
    out = tmp_path / "none.jsonl"
    assert script.main(["--runs", str(run), "--out", str(out), "--mesh", "truth", "--texture-size", "32",
                        "--max-views", "1", "--timing-views", "0"]) == 2
    assert capsys.readouterr().err.startswith("error: --mesh truth") and not out.exists()
