"""The command-line entry points: happy path on a tiny scene, one clear line on bad input."""

import json

import pytest

from va_plugin.cli import export as export_cli
from va_plugin.cli import train as train_cli

TINY = ["--no-progress", "--set", "pipeline.datamanager.rays_per_batch=32", "--set", "pipeline.model.n_samples=8",
        "--set", "pipeline.model.n_importance=8", "--device", "cpu"]


def test_help_lists_methods(capsys):
    with pytest.raises(SystemExit):
        train_cli.main(["--help"])
    out = capsys.readouterr().out
    assert "neus" in out and "NeuS surface reconstruction" in out


def test_train_export_mesh_and_render(tiny_scene, tmp_path, capsys):
    run = tmp_path / "run"
    assert train_cli.main(["neus", "--data", str(tiny_scene), "--output-dir", str(run), "--steps", "2", *TINY,
                           "--quiet"]) == 0
    printed = capsys.readouterr()  # --quiet: the summary line alone (no "next:" hint, no events)
    assert printed.err == "" and len(printed.out.splitlines()) == 1 and printed.out.startswith("trained neus for 2")
    assert export_cli.main(["mesh", "--load-dir", str(run), "--resolution", "32",
                            "--output", str(run / "m.obj")]) in (0, 2)
    out = capsys.readouterr()
    # an untrained field may legitimately have no surface; then the message must say so in one line
    assert (run / "m.obj").exists() or "no surface" in out.err
    assert export_cli.main(["render", "--load-dir", str(run), "--max-views", "1", "--frames", "2",
                            "--turntable-resolution", "16", "--quiet"]) == 0
    printed = capsys.readouterr()  # no progress lines (stderr is no terminal here, so they would be plain lines)
    assert printed.err == "" and printed.out.splitlines() == [printed.out.strip()] and "wrote 1" in printed.out
    assert (run / "renders" / "turntable" / "turntable.mp4").exists()
    assert (run / "renders" / "test_views" / "view_000.png").exists()
    config = json.loads((run / "config.json").read_text())
    assert config["method_name"] == "neus"


def test_existing_run_needs_resume(tiny_scene, tmp_path, capsys):
    run = tmp_path / "run"
    args = ["neus", "--data", str(tiny_scene), "--output-dir", str(run), "--steps", "1", *TINY]
    assert train_cli.main(args) == 0
    assert train_cli.main(args) == 2
    assert "--resume" in capsys.readouterr().err
    assert train_cli.main(args[:6] + ["2"] + args[7:] + ["--resume"]) == 0


@pytest.mark.parametrize("argv, message", [
    (["nope"], "unknown method"),
    (["neus", "--data", "/definitely/not/here"], "not found"),
    (["neus", "--preset", "turbo"], "unknown preset"),
    (["neus", "--set", "pipeline.model.no_such_option=1"], "unknown option"),
    (["neus", "--set", "max_steps=lots"], "takes an integer"),
    (["neus", "--data-format", "strange"], "unknown data format"),
    (["neus", "--device", "cuda:7"], "CUDA is not available"),
])
def test_train_bad_input_one_line(argv, message, tiny_scene, tmp_path, capsys):
    if "--data" not in argv:
        argv = argv + ["--data", str(tiny_scene)]
    code = train_cli.main(argv + ["--output-dir", str(tmp_path / "r"), "--steps", "1", "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_export_without_checkpoint(tmp_path, capsys):
    (tmp_path / "run").mkdir()
    assert export_cli.main(["mesh", "--load-dir", str(tmp_path / "run")]) == 2
    assert "holds no checkpoint" in capsys.readouterr().err


def test_demo_trains_neus_with_its_own_budget_unless_told_otherwise():
    from va_plugin.cli import demo
    from va_plugin.registry import discover_methods

    methods = discover_methods()

    def config(*argv):
        return demo.demo_config(demo.build_parser().parse_args(list(argv)), resolve_data=False)

    default = config()
    assert default.max_steps == demo.DEMO_STEPS.get("neus", methods["neus"].make_config().max_steps)
    assert default.progress and not config("--quiet").progress  # --quiet: no bars, no events
    assert default.pipeline.model.skip_far_samples
    assert config("--steps", "7").max_steps == 7 and config("--steps", "7").pipeline.model.skip_far_samples
    fast = config("--preset", "fast")  # a preset is taken as it is
    assert fast.max_steps == methods["neus"].make_config("fast").max_steps
    ngp = config("--method", "ngp")
    assert ngp.max_steps == methods["ngp"].make_config().max_steps
