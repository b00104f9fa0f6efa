"""compare_variant.py: a variant against the default's two seeds, by hand-made rows."""

from __future__ import annotations

import json

import pytest
from bench_scripts import load_script


@pytest.fixture(scope="module")
def compare():
    return load_script("compare_variant")


def _rows(path, rows):
    path.write_text("".join(json.dumps({"views": 16, **r}) + "\n" for r in rows))
    return path


def test_changes_against_the_two_seed_mean_and_the_rule(compare, tmp_path, capsys):
    rows = _rows(tmp_path / "rows.jsonl", [
        {"object": "a", "variant": "s42", "psnr": 25.0, "lpips": 0.10, "cd": 0.010},
        {"object": "a", "variant": "s43", "psnr": 24.0, "lpips": 0.12, "cd": 0.012},
        {"object": "a", "variant": "new", "psnr": 24.0, "lpips": 0.10, "cd": 0.0121},  # -0.5 dB, CD +10%
        {"object": "b", "variant": "s42", "psnr": 30.0, "lpips": 0.05, "cd": 0.020},
        {"object": "b", "variant": "s43", "psnr": 30.2, "lpips": 0.05, "cd": 0.020},
        {"object": "b", "variant": "new", "psnr": 29.5, "lpips": 0.06, "cd": 0.020},  # -0.6 dB > 2 x 0.2
        {"object": "c", "variant": "s42", "psnr": 20.0, "lpips": 0.2, "cd": 0.03},  # no variant row: left out
    ])
    assert compare.main(["new", "--seeds", "s42,s43", "--rows", str(rows)]) == 0
    lines = capsys.readouterr().out.splitlines()
    a, b, mean = lines[2], lines[3], lines[4]
    assert a.startswith("| a | -0.50 dB | -0.0100 | +10.0% | -1.00 dB, +21.0% | 1.00 dB, 16.7% |")
    assert b.startswith("| b | -0.60 dB | +0.0100 | +0.0% |") and b.endswith("0.20 dB, 0.0% **outside twice** |")
    assert mean.startswith("| **mean (2)** | 26.75 (-0.55) |")


def test_a_variant_without_rows_is_one_line(compare, tmp_path, capsys):
    rows = _rows(tmp_path / "rows.jsonl", [{"object": "a", "variant": "s42", "psnr": 25.0, "lpips": 0.1, "cd": 0.01}])
    assert compare.main(["new", "--seeds", "s42,s43", "--rows", str(rows)]) == 2
    assert compare.main(["new", "--rows", str(tmp_path / "missing.jsonl")]) == 2
    (tmp_path / "bad.jsonl").write_text('{"views": 16, "psnr": 1}\n')  # no object
    assert compare.main(["new", "--rows", str(tmp_path / "bad.jsonl")]) == 2
    (tmp_path / "bad.jsonl").write_text("not json\n")
    assert compare.main(["new", "--rows", str(tmp_path / "bad.jsonl")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(line.startswith("error: ") for line in err)
    assert "line 1 is not a row" in err[3]
