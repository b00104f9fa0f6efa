"""benchmarks/run_formats.py: the ``RIG@N`` names and the comparison with a reference format on hand-made rows
(a real row trains for minutes on ../shared/data)."""

import json

import pytest
from bench_scripts import load_script


@pytest.fixture(scope="module")
def formats():
    return load_script("run_formats")


def row(fmt, name, cd, iou, views=6, tile=256):
    return {"format": fmt, "source": f"gso:{name}", "level": 0, "views": views, "tile": tile, "cd": cd, "iou": iou}


def test_a_view_count_after_the_rig_name(formats):
    assert formats.split_format("syncdreamer@4") == ("syncdreamer", 4)
    assert formats.split_format("crm") == ("crm", "all")


def test_comparison_with_the_reference_matches_hand_values(formats):
    rows = [row("ref", "a", 0.010, 0.8, views=4), row("ref", "b", 0.020, 0.4, views=4),
            row("new", "a", 0.012, 0.7), row("new", "b", 0.010, 0.3), row("new", "c", 0.5, 0.1)]
    lines = formats.compare_formats(rows, "ref", 0)
    new = next(line for line in lines if line.startswith("| new "))
    cells = [c.strip() for c in new.strip("|").split("|")]
    # objects a and b only (c has no reference row): CD ratios +20% and -50%, mean -15%
    assert cells[1:6] == ["6 x 256", "2", "42", "0.0110", "0.0150"]
    assert cells[6].startswith("-15.0% [")
    assert cells[7] == "1/2"
    assert cells[8:10] == ["0.500", "0.600"]
    assert cells[10] == "b (b)"


def test_an_object_with_several_seeds_counts_with_its_seed_mean(formats):
    rows = [row("ref", "a", 0.010, 0.8, views=4), row("ref", "b", 0.020, 0.4, views=4),
            {**row("new", "a", 0.010, 0.7), "seed": 1}, {**row("new", "a", 0.014, 0.5), "seed": 2},
            {**row("new", "b", 0.010, 0.3), "seed": 1}]
    new = next(line for line in formats.compare_formats(rows, "ref", 0) if line.startswith("| new "))
    cells = [c.strip() for c in new.strip("|").split("|")]
    # a: seed mean 0.012 (+20%), b: 0.010 (-50%); objects 2, seeds 1 and 2, mean IoU (0.6 + 0.3) / 2
    assert cells[2:6] == ["2", "1, 2", "0.0110", "0.0150"]
    assert cells[6].startswith("-15.0% [") and cells[8] == "0.450"


def test_resume_skips_the_rows_of_the_same_seed_and_overrides(formats, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    done = [{**row("crm", "a", 0.02, 0.9), "source": "procedural:mug"},  # no seed: written with the default
            {**row("crm", "a", 0.02, 0.9), "source": "procedural:mug", "seed": 7,
             "overrides": ["pipeline.model.crossings_weight=0"]}]
    (out / "formats.json").write_text(json.dumps(done))
    for extra in (["--seed", "42"], ["--seed", "7", "--set", "pipeline.model.crossings_weight=0"]):
        assert formats.main(["--formats", "crm", "--levels", "0", "--out", str(out), "--resume", *extra]) == 0
    assert json.loads((out / "formats.json").read_text()) == done  # nothing ran, nothing was rewritten


def test_report_reads_several_files_and_runs_nothing(formats, tmp_path, capsys):
    (tmp_path / "a.json").write_text(json.dumps([row("syncdreamer@4", "a", 0.01, 0.8, views=4)]))
    (tmp_path / "b.json").write_text(json.dumps([row("crm", "a", 0.02, 0.9)]))
    assert formats.main(["--report", str(tmp_path / "a.json"), str(tmp_path / "b.json")]) == 0
    out = capsys.readouterr().out
    assert "| crm | 6 x 256 | 1 | 42 | 0.0200 | 0.0100 | +100.0% [+100.0%, +100.0%] | 0/1 |" in out


@pytest.mark.parametrize("bad", ["crm@x", "crm@", "syncdreamer@0", "nosuchrig"])
def test_a_bad_format_name_is_one_line_and_exit_2(formats, bad, capsys):
    with pytest.raises(SystemExit) as stop:
        formats.main(["--formats", bad, "--out", "/nonexistent/never-made"])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert bad.split("@")[0] in err and "Traceback" not in err


@pytest.mark.parametrize("bad", ["pipeline.model.no_such_key=1", "pipeline.model.crossings_weight"])
def test_a_bad_override_is_one_line_and_exit_2_before_any_work(formats, bad, tmp_path, capsys):
    out = tmp_path / "never-made"
    with pytest.raises(SystemExit) as stop:
        formats.main(["--formats", "crm", "--set", bad, "--out", str(out)])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "Traceback" not in err and "error:" in err
    assert not out.exists()


def test_an_elevation_a_rig_cannot_take_is_one_line_and_exit_2_before_any_work(formats, tmp_path, capsys):
    out = tmp_path / "never-made"
    with pytest.raises(SystemExit) as stop:  # CRM's top and bottom views have their own elevations
        formats.main(["--formats", "four-view-grid,crm", "--elevation", "30", "--out", str(out)])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "Traceback" not in err and "crm" in err and "elevation" in err
    assert not out.exists()


def test_rows_at_another_elevation_are_reported_apart(formats):
    rows = [row("ref", "a", 0.010, 0.8, views=4), row("grid", "a", 0.012, 0.7, views=4),
            {**row("grid", "a", 0.009, 0.7, views=4), "elevation": 30.0}]
    lines = formats.compare_formats(rows, "ref", 0)
    assert any(line.startswith("| grid | 4 x 256 | 1 | 42 | 0.0120 |") for line in lines)
    assert any(line.startswith("| grid (elevation 30) | 4 x 256 | 1 | 42 | 0.0090 |") for line in lines)


def test_another_seed_or_elevation_gets_its_own_scene_folder(formats):
    from argparse import Namespace

    assert formats.run_name("gso:cream", 0, Namespace(seed=42, elevation=None)) == "cream-L0"
    assert formats.run_name("gso:cream", 2, Namespace(seed=7, elevation=30.0)) == "cream-L2-s7-e30"
