"""benchmarks/time_accuracy.py: arms of run_all_views rows at measured seconds, one table and one figure."""

import json
import sys

import pytest
from bench_scripts import load_script


def row(name, variant, psnr, cd, lpips):
    return {"key": f"{name}-{variant}", "object": name, "views": 16, "level": 2, "variant": variant,
            "cd": cd, "psnr": psnr, "lpips": lpips}


def test_means_over_the_objects_every_arm_has(tmp_path, monkeypatch, capsys):
    pytest.importorskip("matplotlib")
    script = load_script("time_accuracy")
    rows = [row("a", "", 24.0, 0.010, 0.10), row("a", "seed43", 25.0, 0.012, 0.12),
            row("b", "", 22.0, 0.020, 0.20), row("b", "seed43", 23.0, 0.018, 0.18),
            row("a", "fast", 23.0, 0.011, 0.11), row("b", "fast", 21.0, 0.021, 0.21),
            row("c", "", 30.0, 0.001, 0.01)]  # c lacks the other arms: left out
    path = tmp_path / "rows.jsonl"
    path.write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    out = tmp_path / "figure.png"
    monkeypatch.setattr(sys, "argv", ["time_accuracy.py", "--rows", str(path), "--arm", "old=,seed43@300",
                                      "--arm", "fast=fast@150", "--out", str(out)])
    assert script.main() == 0
    text = capsys.readouterr().out
    assert "| old | 300 | 23.5 | 0.15 | 0.015 | 2 |" in text
    assert "| fast | 150 | 22 | 0.16 | 0.016 | 1 |" in text
    assert out.stat().st_size > 0


def test_a_malformed_arm_is_a_one_line_error():
    script = load_script("time_accuracy")
    with pytest.raises(SystemExit, match="NAME=VARIANT"):
        script.parse_arm("no-seconds")
