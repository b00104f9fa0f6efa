"""``--render-sharpness`` of ``va-eval`` and ``va-export render`` on a tiny trained ``neus`` run."""

import json

import pytest
from conftest import tiny_config, tiny_trained_run

from va_plugin.cli import eval as eval_cli
from va_plugin.cli import export as export_cli


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return tiny_trained_run(tmp_path_factory, with_mesh=False)


def _eval(run, out, *extra):
    return eval_cli.main(["--load-dir", str(run), "--max-views", "1", "--output", str(out), "--no-progress",
                          "--device", "cpu", *extra])


def test_eval_renders_with_the_given_sharpness_and_records_it(run, tmp_path, capsys):
    assert _eval(run, tmp_path / "plain.json") == 0
    assert _eval(run, tmp_path / "sharp.json", "--render-sharpness", "4") == 0
    plain, sharp = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("plain", "sharp"))
    assert plain["render_sharpness"] == 1.0 and sharp["render_sharpness"] == 4.0
    assert sharp["psnr"] != plain["psnr"]


@pytest.mark.parametrize("cli, argv", [
    (eval_cli, ["--render-sharpness", "0"]),
    (export_cli, ["render", "--render-sharpness", "-1"]),
])
def test_a_sharpness_that_is_not_positive_is_one_line(cli, argv, run, tmp_path, capsys):
    if cli is eval_cli:
        argv = argv + ["--load-dir", str(run), "--output", str(tmp_path / "e.json")]
    else:
        argv = argv[:1] + ["--load-dir", str(run), "--output-dir", str(tmp_path / "r")] + argv[1:]
    code = cli.main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--render-sharpness must be positive" in err[0], err
    assert list(tmp_path.iterdir()) == []


def test_a_model_without_inv_s_refuses_it(tiny_scene, tmp_path, capsys):
    out = tmp_path / "ngp"
    tiny_config("ngp", tiny_scene, out, steps=2).setup().train()
    code = eval_cli.main(["--load-dir", str(out), "--render-sharpness", "2", "--max-views", "1",
                          "--output", str(tmp_path / "e.json"), "--device", "cpu"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and "option of SDF (neus) models" in err[-1], err
    assert not (tmp_path / "e.json").exists()
