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


def _two_objects(cd_a: float) -> list[dict]:
    """Objects a (seeds 1.0 dB and 16.7% CD apart; the variant -0.5 dB and CD ``cd_a``) and b (seeds 0.2 dB
    apart; the variant -0.6 dB)."""
    return [
        {"object": "a", "variant": "s42", "psnr": 25.0, "lpips": 0.10, "cd": 0.010},
        {"object": "a", "variant": "s43", "psnr": 24.0, "lpips": 0.12, "cd": 0.012},
        {"object": "a", "variant": "new", "psnr": 24.0, "lpips": 0.10, "cd": cd_a},
        {"object": "b", "variant": "s42", "psnr": 30.0, "lpips": 0.05, "cd": 0.020},
        {"object": "b", "variant": "s43", "psnr": 30.2, "lpips": 0.05, "cd": 0.020},
        {"object": "b", "variant": "new", "psnr": 29.5, "lpips": 0.06, "cd": 0.020},
    ]


def test_changes_against_the_two_seed_mean_and_the_rule(compare, tmp_path, capsys):
    rows = _rows(tmp_path / "rows.jsonl", _two_objects(cd_a=0.0121) + [  # a: CD +10%; b: -0.6 dB > 2 x 0.2
        {"object": "c", "variant": "s42", "psnr": 20.0, "lpips": 0.2, "cd": 0.03},  # no variant row: left out
    ])
    assert compare.main(["new", "--seeds", "s42,s43", "--rows", str(rows), "--rule", "own"]) == 0
    lines = capsys.readouterr().out.splitlines()
    a, b, mean = lines[2], lines[3], lines[4]
    assert a.startswith("| a | -0.50 dB | -0.0100 | +10.0% | -1.00 dB, +21.0% | 1.00 dB, 16.7% |")
    assert b.startswith("| b | -0.60 dB | +0.0100 | +0.0% |") and b.endswith("0.20 dB, 0.0% **outside twice** |")
    assert mean.startswith("| **mean (2)** | 26.75 (-0.55) |")
    assert lines[-1] == "Rule: twice each object's own seed difference."


def test_the_pooled_rule_holds_every_object_to_the_seeds_mean_difference(compare, tmp_path, capsys):
    """Five objects' seeds lie 0.48 dB and 3.3% CD apart on average: -0.6 dB and CD +2.7% pass, -1.3 dB and
    CD +21% do not. The spread counts every object with both seeds, with or without a variant row."""
    rows = _rows(tmp_path / "rows.jsonl", _two_objects(cd_a=0.0113) + [  # a: CD +2.7%; b: -0.6 dB, inside 0.96
        {"object": "c", "variant": "s42", "psnr": 20.0, "lpips": 0.2, "cd": 0.03},
        {"object": "c", "variant": "s43", "psnr": 20.6, "lpips": 0.2, "cd": 0.03},
        {"object": "c", "variant": "new", "psnr": 19.0, "lpips": 0.2, "cd": 0.03},  # -1.3 dB
        {"object": "d", "variant": "s42", "psnr": 20.0, "lpips": 0.2, "cd": 0.03},  # no variant row: still a seed
        {"object": "d", "variant": "s43", "psnr": 20.6, "lpips": 0.2, "cd": 0.03},
        {"object": "e", "variant": "s42", "psnr": 20.0, "lpips": 0.2, "cd": 0.010},
        {"object": "e", "variant": "s43", "psnr": 20.0, "lpips": 0.2, "cd": 0.010},
        {"object": "e", "variant": "new", "psnr": 20.0, "lpips": 0.2, "cd": 0.0121},  # CD +21%
    ])
    assert compare.main(["new", "--seeds", "s42,s43", "--rows", str(rows)]) == 0
    lines = capsys.readouterr().out.splitlines()
    marked = {line.split(" | ")[0][2:] for line in lines if line.endswith("**outside twice** |")}
    assert marked == {"c", "e"}
    # seeds: a 1.0 dB / 16.7%, b 0.2 / 0, c 0.6 / 0, d 0.6 / 0, e 0 / 0 -> 0.48 dB, 3.3%
    assert lines[-1] == "Rule: twice the seeds' difference averaged over 5 objects (0.48 dB, 3.3% CD)."


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


def test_three_seeds_give_their_mean_and_their_pairs_mean_difference(compare, tmp_path, capsys):
    rows = _rows(tmp_path / "rows.jsonl", [
        {"object": "a", "variant": "s42", "psnr": 25.0, "lpips": 0.10, "cd": 0.010},
        {"object": "a", "variant": "s43", "psnr": 24.0, "lpips": 0.12, "cd": 0.010},
        {"object": "a", "variant": "s44", "psnr": 24.5, "lpips": 0.11, "cd": 0.010},
        {"object": "a", "variant": "new", "psnr": 24.0, "lpips": 0.11, "cd": 0.011},
    ])
    assert compare.main(["new", "--seeds", "s42,s43,s44", "--rows", str(rows)]) == 0
    lines = capsys.readouterr().out.splitlines()
    # mean 24.5 dB; pairs 1.0, 0.5, 0.5 -> 0.67 dB; CD +10% against 0% spread: outside
    assert lines[2] == "| a | -0.50 dB | +0.0000 | +10.0% | -1.00 dB, +10.0% | 0.67 dB, 0.0% **outside twice** |"
    assert lines[-1] == "Rule: twice the seeds' difference averaged over 1 object (0.67 dB, 0.0% CD)."
    assert compare.main(["new", "--seeds", "s42", "--rows", str(rows)]) == 2
