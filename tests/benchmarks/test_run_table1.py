"""run_table1.py end to end with the smoke preset: well-formed outputs with every field filled; resume."""

from __future__ import annotations

import csv
import json
import math

import pytest
from bench_scripts import scripts  # noqa: F401  (fixture)

from va_plugin.bench import cli as bench_cli
from va_plugin.bench.report import EXTRA_FIELDS, FIELDS

METHODS = {"neus", "va-neus", "ngp", "va-ngp"}


@pytest.fixture(scope="module")
def smoke_run(scripts, tmp_path_factory):
    out = tmp_path_factory.mktemp("table1") / "smoke"
    assert scripts["table1"].main(["--preset", "smoke", "--out", str(out), "--device", "cpu"]) == 0
    return out


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

    def must_not_run(*args, **kwargs):
        raise AssertionError("a finished row was trained again")

    monkeypatch.setattr(bench_cli, "run_row", must_not_run)
    assert scripts["table1"].main(["--preset", "smoke", "--out", str(smoke_run), "--device", "cpu", "--resume"]) == 0
    assert "0 rows run, 4 skipped" in capsys.readouterr().out
    assert (smoke_run / "table1.csv").read_text() == before
    # without --resume an existing benchmark folder is refused, not overwritten
    assert scripts["table1"].main(["--preset", "smoke", "--out", str(smoke_run), "--device", "cpu"]) == 2
