"""run_backbone.py with the smoke preset: variants with presets, levels and budgets become rows with the
right methods and step budgets; the report holds a table per level and the budget check; bad flags are
one-line errors."""

from __future__ import annotations

import csv
import json

import pytest
from bench_scripts import load_script


@pytest.fixture(scope="module")
def backbone():
    return load_script("run_backbone")


@pytest.fixture(scope="module")
def smoke_out(backbone, tmp_path_factory):
    out = tmp_path_factory.mktemp("backbone") / "smoke"
    argv = ["--preset", "smoke", "--out", str(out), "--device", "cpu", "--variants", "neus,neus:mlp",
            "--levels", "0", "--budgets", "1,2"]
    assert backbone.main(argv) == 0
    return out


def test_rows_cover_variants_and_budgets(smoke_out):
    rows = list(csv.DictReader((smoke_out / "backbone.csv").open()))
    assert sorted(r["variant"] for r in rows) == ["neus", "neus x2", "neus:mlp", "neus:mlp x2"]
    steps = {r["variant"]: int(r["steps"]) for r in rows}
    assert steps["neus x2"] == 2 * steps["neus"] and steps["neus:mlp x2"] == 2 * steps["neus:mlp"]
    stored = json.loads((smoke_out / "backbone.json").read_text())
    assert len(stored["rows"]) == 4 and all(r["curve"] for r in stored["rows"])


def test_the_mlp_preset_reaches_its_row(smoke_out):
    kinds = {}
    for config in (smoke_out / "runs").rglob("config.json"):
        text = config.read_text()
        kinds[config.parent.name] = "HashSDFField" in text
    assert sorted(kinds.values()) == [False, False, True, True]


def test_report_has_level_tables_and_budget_check(smoke_out):
    text = (smoke_out / "backbone.md").read_text()
    assert "## Level 0: mean ± sd over 1 object(s)" in text
    assert "## More compute: change from budget x1, paired by object" in text
    assert "neus:mlp x2" in text


@pytest.mark.parametrize("flags, message", [
    (["--variants", "nope"], "unknown method"),
    (["--variants", "neus:nope"], "has no preset"),
    (["--budgets", "0"], "positive"),
    (["--kinds", "appearance;color"], "unknown inconsistency kind"),
    (["--variants", "neus@crossings_weight"], "KEY=VALUE"),
])
def test_bad_flags(backbone, tmp_path, flags, message, capsys):
    assert backbone.main(["--preset", "smoke", "--out", str(tmp_path / "o"), *flags]) == 2
    assert message in capsys.readouterr().err


def test_variant_overrides_reach_their_row_only(backbone):
    variants = backbone.parse_variants("neus,neus:fast@pipeline.model.crossings_weight=0.1@max_steps=7")
    assert variants == [("neus", "", ()),
                        ("neus", "fast", ("pipeline.model.crossings_weight=0.1", "max_steps=7"))]


def test_kind_sets_become_scenes_of_their_own(backbone, tmp_path):
    """``--kinds 'appearance;geometric,pose'``: every object once per set, each scene built with just
    those kinds (its scene.json says which), and the rows named apart."""
    out = tmp_path / "kinds"
    argv = ["--preset", "smoke", "--out", str(out), "--device", "cpu", "--variants", "neus", "--levels", "2",
            "--kinds", "appearance;pose,geometric"]
    assert backbone.main(argv) == 0
    scenes = sorted(r["scene"] for r in csv.DictReader((out / "backbone.csv").open()))
    assert len(scenes) == 2 and scenes[0].endswith("+appearance") and scenes[1].endswith("+geometric+pose")
    built = {p.parent.name: json.loads(p.read_text())["inconsistency"]["kinds"]
             for p in (out / "scenes").glob("*/scene.json")}
    assert sorted(map(tuple, built.values())) == [("appearance",), ("geometric", "pose")]
