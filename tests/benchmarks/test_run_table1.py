"""run_table1.py end to end with the smoke preset, one row at a time and two at once (``--jobs 2``): well-formed
outputs with every field filled, the same rows and metrics either way; resume."""

from __future__ import annotations

import csv
import json
import math

import pytest
import torch
from bench_scripts import scripts  # noqa: F401  (fixture)

from va_plugin.bench import experiment, parallel
from va_plugin.bench.report import EXTRA_FIELDS, FIELDS

METHODS = {"neus", "va-neus", "ngp", "va-ngp"}
METRICS = ("psnr", "ssim", "lpips", "cd", "iou", "fscore")


def smoke_argv(out, jobs):
    # the workers get this process's thread count, so that both runs compute the same sums
    return ["--preset", "smoke", "--out", str(out), "--device", "cpu", "--jobs", str(jobs)] + (
        ["--threads", str(torch.get_num_threads())] if jobs > 1 else [])


@pytest.fixture(scope="module")
def smoke_runs(scripts, tmp_path_factory):
    """jobs -> the folder of a smoke run with that many rows at once (each run made once per module)."""
    runs = {}

    def run(jobs):
        if jobs not in runs:
            out = tmp_path_factory.mktemp(f"table1-jobs{jobs}") / "smoke"
            assert scripts["table1"].main(smoke_argv(out, jobs)) == 0
            runs[jobs] = out
        return runs[jobs]

    return run


@pytest.fixture(scope="module", params=[1, 2], ids=["jobs1", "jobs2"])
def smoke_run(request, smoke_runs):
    return smoke_runs(request.param)


def filled(value) -> bool:
    if value is None or value == "":
        return False
    if isinstance(value, float):
        return math.isfinite(value)
    return str(value).lower() not in ("nan", "none", "null", "n/a")


def test_csv_has_a_filled_row_per_scene_and_method(smoke_run):
    with open(smoke_run / "table1.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0]) == list(FIELDS + EXTRA_FIELDS)
    assert {r["method"] for r in rows} == METHODS and len(rows) == 4
    for row in rows:
        assert all(filled(row[k]) for k in FIELDS + EXTRA_FIELDS), row
        assert row["adaptive"] == ("true" if row["method"].startswith("va-") else "false")
        assert row["backbone"] == row["method"].removeprefix("va-")
        assert int(row["steps"]) == 3 and float(row["train_seconds"]) > 0
        assert 0 <= float(row["ssim"]) <= 1 and 0 <= float(row["iou"]) <= 1 and float(row["cd"]) > 0


def test_json_rows_match_csv_and_carry_time_curves(smoke_run):
    data = json.loads((smoke_run / "table1.json").read_text())
    assert data["meta"]["preset"] == "smoke" and data["meta"]["rows_done"] == 4
    for row in data["rows"]:
        assert all(filled(row[k]) for k in FIELDS), row
        curve = row["curve"]
        assert len(curve) >= 2 and curve[-1]["step"] == row["steps"]
        assert curve[-1]["cd"] == row["cd"] and curve[-1]["psnr"] == row["psnr"]
        seconds = [p["train_seconds"] for p in curve]
        assert seconds == sorted(seconds)
        assert row["evaluation"]["image_params"]["width"] == 32


def test_markdown_table_is_shaped_like_table1(smoke_run):
    text = (smoke_run / "table1.md").read_text()
    summary = text.split("## Mean ± sd")[1].split("##")[0]
    lines = [line for line in summary.splitlines() if line.startswith("| ")]
    assert lines[0].startswith("| Method | PSNR ↑ | SSIM ↑ | LPIPS ↓ | CD ↓ | IoU ↑")
    labels = [line.split("|")[1].strip() for line in lines[1:]]
    assert labels == ["Original NeuS", "View-adaptive NeuS", "Original InstantNGP", "View-adaptive InstantNGP"]
    assert "n/a" not in summary
    assert "NeuS, paper (Table 1)" in text and "-27%" in text
    assert (smoke_run / "table1_time.png").stat().st_size > 1000


def test_resume_skips_finished_rows(scripts, smoke_run, monkeypatch, capsys):
    before = (smoke_run / "table1.csv").read_text()
    jobs = json.loads((smoke_run / "table1.json").read_text())["meta"]["jobs"]

    def must_not_run(*args, **kwargs):
        raise AssertionError("a finished row was trained again")

    monkeypatch.setattr(experiment, "run_row", must_not_run)
    monkeypatch.setattr(parallel, "get_context", must_not_run)  # no worker process is started
    assert scripts["table1"].main(smoke_argv(smoke_run, jobs) + ["--resume"]) == 0
    assert "0 rows run, 4 skipped" in capsys.readouterr().out
    assert (smoke_run / "table1.csv").read_text() == before
    # without --resume an existing benchmark folder is refused, not overwritten
    assert scripts["table1"].main(["--preset", "smoke", "--out", str(smoke_run), "--device", "cpu"]) == 2


def test_rows_at_once_give_the_same_rows_and_metrics(smoke_runs):
    one, two = ({r["key"]: r for r in json.loads((smoke_runs(jobs) / "table1.json").read_text())["rows"]}
                for jobs in (1, 2))
    assert list(two) == list(one)  # plan order, whichever row finished first
    for key, row in two.items():
        assert {m: row[m] for m in METRICS} == {m: one[key][m] for m in METRICS}, key
        assert row["fingerprint"] == one[key]["fingerprint"] and row["steps"] == one[key]["steps"]
    meta = json.loads((smoke_runs(2) / "table1.json").read_text())["meta"]
    assert meta["jobs"] == 2 and meta["machine"]["torch_threads"] == torch.get_num_threads()
    assert "2 rows at a time" in (smoke_runs(2) / "table1.md").read_text()
    assert "rows at a time" not in (smoke_runs(1) / "table1.md").read_text()
