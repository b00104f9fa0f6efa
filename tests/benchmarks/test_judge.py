"""benchmarks/judge.py: arms, the paired statistics on hand-made rows, the stored rows' checks (training is
the trainer's, tested elsewhere; a real row takes minutes on ../shared/data)."""

import json

import numpy as np
import pytest
from bench_scripts import load_script


@pytest.fixture(scope="module")
def judge():
    return load_script("judge")


def row(arm, name, seed, psnr, cd, level=2, lpips=0.1, iou=0.7, method=None, overrides=()):
    return {"key": f"{arm}/{name}-l{level}-v16-seed{seed}", "arm": arm, "method": method or arm,
            "arm_overrides": list(overrides), "object": name, "level": level, "views": 16, "seed": seed,
            "psnr": psnr, "lpips": lpips, "cd": cd, "iou": iou}


def store(rows):
    return {r["key"]: r for r in rows}


def test_arms_parse_with_and_without_overrides(judge):
    assert judge.parse_arm("va-neus") == judge.Arm("va-neus", "va-neus", ())
    assert judge.parse_arm("ema=neus a.b=1 c=2") == judge.Arm("ema", "neus", ("a.b=1", "c=2"))
    for bad in ("=neus", "x=", "x=neus novalue"):
        with pytest.raises(ValueError):
            judge.parse_arm(bad)


def test_differences_ratios_and_sign_counts_match_hand_values(judge):
    rows = store([row("a", "o1", 42, 20.0, 0.010), row("a", "o1", 43, 22.0, 0.012),
                  row("b", "o1", 42, 21.0, 0.011), row("b", "o1", 43, 21.0, 0.011),   # o1: +0 dB, CD x1.0
                  row("a", "o2", 42, 25.0, 0.020), row("b", "o2", 42, 26.0, 0.015),   # o2: +1 dB, CD x0.75
                  row("b", "o3", 42, 30.0, 0.001)])                                   # o3: base missing
    result = judge.compare(rows, "a", "b", 2)
    assert result["objects"] == ["o1", "o2"]
    assert result["psnr"]["diff"] == pytest.approx(0.5)
    assert result["psnr"]["better"] == 1  # o1 ties: not counted as better
    assert result["cd"]["ratio"] == pytest.approx(-0.125)
    assert result["cd"]["diff"] == pytest.approx(((0.011 - 0.011) + (0.015 - 0.020)) / 2)
    assert result["cd"]["better"] == 1
    low, high = result["psnr"]["interval"]
    assert low <= 0.5 <= high and low >= -0.5 and high <= 1.0 + 1e-9
    # seed sd pooled over objects with two seeds: o1 of arm a only (sd of 20, 22 = sqrt(2))
    assert result["seed_sd"]["a"]["psnr_db"] == pytest.approx(np.sqrt(2))
    assert result["seed_sd"]["b"]["psnr_db"] == pytest.approx(0.0)
    assert result["seed_sd"]["a"]["cd_pct"] == pytest.approx(100 * np.std([10 / 11, 12 / 11], ddof=1))
    assert judge.compare(rows, "a", "b", 0) is None


def test_interval_excludes_zero_for_a_consistent_gain_and_is_reproducible(judge):
    rng = np.random.default_rng(1)
    base = [20 + rng.normal(0, 0.3, 3) for _ in range(10)]
    variant = [b.mean() + 1.0 + rng.normal(0, 0.3, 3) for b in base]
    low, high = judge.bootstrap_interval(base, variant, False, draws=2000)
    assert 0.5 < low < 1.0 < high < 1.5
    assert (low, high) == judge.bootstrap_interval(base, variant, False, draws=2000)


def test_report_prints_every_metric_with_its_interval(judge):
    rows = store([row("a", o, s, 20.0, 0.01) for o in ("o1", "o2") for s in (42, 43)] +
                 [row("b", o, s, 21.0, 0.009) for o in ("o1", "o2") for s in (42, 43)])
    text = judge.report(judge.compare(rows, "a", "b", 2), "a", "b")
    assert "Level 2, 16 views, 2 objects (seeds per object: a 2, b 2)" in text
    assert "| PSNR | 20.00 | 21.00 | +1.00 [+1.00, +1.00] | 2/2 |" in text
    assert "-10.0% [-10.0%, -10.0%]" in text
    assert "| IOU | 0.7000 | 0.7000 | +0.0000 [+0.0000, +0.0000] | 0/2 |" in text
    assert "Per-object seed sd (pooled): a 0.00 dB, CD 0.00%" in text


def test_a_stored_arm_is_refused_with_other_overrides_and_no_rows_is_one_line(judge, tmp_path, capsys):
    folder = tmp_path / "store"
    folder.mkdir()
    (folder / "rows.jsonl").write_text(json.dumps(row("ema", "o1", 42, 20.0, 0.01, method="neus",
                                                      overrides=("x=1",))) + "\n")
    assert judge.main(["--base", "neus", "--variant", "ema=neus x=2", "--store", str(folder),
                       "--report-only"]) == 2
    assert "arm 'ema' is stored as neus ['x=1']" in capsys.readouterr().err
    assert judge.main(["--base", "neus", "--variant", "ema=neus x=1", "--store", str(folder),
                       "--report-only"]) == 2
    assert "no object has rows of both 'neus' and 'ema'" in capsys.readouterr().err
    (folder / "rows.jsonl").write_text("{not json\n")
    assert judge.main(["--store", str(folder), "--report-only"]) == 2
    assert "line 1 is not a row" in capsys.readouterr().err


def test_an_arm_stored_under_other_defaults_is_refused_before_any_run(judge, tmp_path, capsys):
    assert judge.fingerprint(judge.parse_arm("neus")) == judge.fingerprint(judge.parse_arm("x=neus"))
    changed = judge.fingerprint(judge.parse_arm("x=neus average_fraction=0"))
    assert changed != judge.fingerprint(judge.parse_arm("neus"))
    folder = tmp_path / "store"
    folder.mkdir()
    stale = dict(row("neus", "o1", 42, 20.0, 0.01), trains=changed, commit="abc1234")
    (folder / "rows.jsonl").write_text(json.dumps(stale) + "\n")
    assert judge.main(["--base", "neus", "--variant", "ema=neus x.y=1", "--store", str(folder),
                       "--objects", "o1", "--data-root", str(tmp_path)]) == 2
    assert "arm 'neus' is stored with other defaults of neus (commit abc1234)" in capsys.readouterr().err
