"""benchmarks/bench_colour_cast.py: trains an input to a step of the default schedule and measures the
colour cast (with the residual spread), measures a run folder, and refuses bad options in one line."""

import json

from bench_scripts import load_script


def test_train_to_a_step_then_measure_and_measure_a_run(tiny_scene, tmp_path, capsys):
    script = load_script("bench_colour_cast")
    out = tmp_path / "cast.jsonl"
    runs = tmp_path / "runs"
    assert script.main(["--train-to", "2", "--runs-dir", str(runs), "--resolution", "16", "--out", str(out),
                        str(tiny_scene)]) == 0
    record = json.loads(out.read_text())
    assert record["step"] == 2 and record["test"] == "colour_cast" and "residual_spread_db" in record
    assert len(record["gains"]) >= 2 and "silhouette_unsupported" in record
    run = runs / tiny_scene.name
    assert list((run / "checkpoints").glob("*.ckpt"))
    capsys.readouterr()
    assert script.main(["--resolution", "16", str(run)]) == 0
    again = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert again["step"] == 2 and again["gains"] == record["gains"]  # the same state, the same fit


def test_bad_options_are_one_line_errors(tiny_scene, tmp_path, capsys):
    script = load_script("bench_colour_cast")
    assert script.main(["--resolution", "0", str(tmp_path)]) == 2
    assert script.main(["--train-to", "0", "--runs-dir", str(tmp_path), str(tiny_scene)]) == 2
    assert script.main([str(tmp_path / "missing")]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 3
