"""``~``, symbolic links and ``..`` in the paths of every command: one resolution at the boundary, so a
run is never split between ``~/x`` and a literal ``./~/x``; nothing is written outside the resolved
folder, no user file is replaced without ``--overwrite``, and a run is resumed only when asked."""

import json
import os
import shutil
from pathlib import Path

import pytest
from conftest import CLI_TINY, one_line_error, write_syncdreamer_strip

import va_plugin.api as api
from va_plugin.cli import eval as eval_cli
from va_plugin.cli import export as export_cli
from va_plugin.cli import recon
from va_plugin.cli import train as train_cli

TINY = ["--set", "pipeline.datamanager.rays_per_batch=16", "--set", "pipeline.model.n_samples=4",
        "--set", "pipeline.model.n_importance=4", "--device", "cpu", "--no-texture", "--mesh-resolution", "16",
        "--steps", "1", "--quiet"]


@pytest.fixture(scope="module")
def strips(tmp_path_factory):
    folder = tmp_path_factory.mktemp("strips")
    return (write_syncdreamer_strip(folder / "chicken.png", tile=32),
            write_syncdreamer_strip(folder / "sofa.png", tile=32, alpha=True))


@pytest.fixture
def home(tmp_path, monkeypatch):
    """``~`` is ``tmp/home``; the commands run in the empty folder ``tmp/work``."""
    home, work = tmp_path / "home", tmp_path / "work"
    home.mkdir()
    work.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(work)
    return home


def _written_outside(home: Path) -> list[Path]:
    """What the commands wrote in their working folder (a literal ``~`` folder, say)."""
    return sorted((home.parent / "work").rglob("*"))


def test_a_user_file_under_a_tilde_out_is_not_replaced(strips, home, capsys):
    (home / "userx").mkdir()
    (home / "userx" / "mesh.ply").write_text("MINE")
    one_line_error(capsys, recon.main([str(strips[0]), "--out", "~/userx", *TINY]),
                   f"--out {home / 'userx'} is not empty and holds no run (found mesh.ply)")
    assert (home / "userx" / "mesh.ply").read_text() == "MINE"
    assert sorted(p.name for p in (home / "userx").iterdir()) == ["mesh.ply"] and _written_outside(home) == []


def test_a_run_under_a_tilde_out_is_one_folder_resumed_only_when_asked(strips, home, capsys):
    chicken, sofa = strips
    assert recon.main([str(chicken), "--out", "~/run", *TINY]) == 0
    run = home / "run"
    assert {"mesh.ply", "summary.json", "va-run.json", "checkpoints"} <= {p.name for p in run.iterdir()}
    assert capsys.readouterr().out.splitlines()[-1].endswith(str(run / "summary.json"))
    assert _written_outside(home) == []
    kept = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    # another input: refused with or without --resume, the chicken's files untouched
    one_line_error(capsys, recon.main([str(sofa), "--out", "~/run", *TINY]), f"holds a run on {chicken}")
    one_line_error(capsys, recon.main([str(sofa), "--out", "~/run", "--resume", *TINY]), "--resume")
    # the same input again: no silent resume
    one_line_error(capsys, recon.main([str(chicken), "--out", "~/run", *TINY]), "pass --resume to continue")
    # the checkpoints gone, the manifest still names the chicken: the sofa may not take its place
    for checkpoint in (run / "checkpoints").iterdir():
        checkpoint.unlink()
        kept.pop(checkpoint)
    one_line_error(capsys, recon.main([str(sofa), "--out", "~/run", *TINY]), "pass --overwrite to replace")
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == kept
    assert _written_outside(home) == []


def test_train_export_and_eval_take_tilde_paths(tiny_scene, home, capsys):
    scene = home / "scene"  # without its true mesh: the held-out views are scored, not a 100k-point Chamfer
    shutil.copytree(tiny_scene, scene)
    info = json.loads((scene / "scene.json").read_text())
    info.pop("mesh")
    (scene / "scene.json").write_text(json.dumps(info))
    assert train_cli.main(["neus", "--data", "~/scene", "--output-dir", "~/x", *CLI_TINY, "--quiet"]) == 0
    assert (home / "x" / "va-run.json").is_file() and (home / "x" / "checkpoints").is_dir()
    assert export_cli.main(["mesh", "--load-dir", "~/x", "--output", "~/meshes/m.ply", "--resolution", "16",
                            "--quiet"]) == 0
    assert (home / "meshes" / "m.ply").is_file()
    capsys.readouterr()
    assert eval_cli.main(["--load-dir", "~/x/../x", "--output", "~/e.json", "--mesh-resolution", "16",
                          "--max-views", "1", "--no-progress"]) == 0
    scores = json.loads((home / "e.json").read_text())  # 24 px views: too small for LPIPS, scored without it
    assert "psnr" in scores and "ssim" in scores and "lpips" not in scores
    assert _written_outside(home) == []


def test_the_api_resolves_its_paths_once(tiny_scene, home):
    config = api.build_config("neus", "~/../home/../home/../" + os.path.relpath(tiny_scene, home.parent),
                              out="~/api-run", steps=1, device="cpu",
                              overrides={"pipeline.datamanager.rays_per_batch": 16, "pipeline.model.n_samples": 4,
                                         "pipeline.model.n_importance": 4})
    assert config.output_dir == home / "api-run" and config.pipeline.datamanager.dataparser.data == tiny_scene
    config.output_dir = Path("~/hand-set")  # a config edited by hand: resolved by train()
    assert api.train(config) == home / "hand-set"
    assert (home / "hand-set" / "checkpoints").is_dir() and _written_outside(home) == []


def test_a_symbolic_link_loop_as_out_is_one_line(strips, home, capsys):
    os.symlink(home / "b", home / "a")
    os.symlink(home / "a", home / "b")
    for command in (lambda: recon.main([str(strips[0]), "--out", str(home / "a"), *TINY]),
                    lambda: train_cli.main(["neus", "--output-dir", "~/a/run", *CLI_TINY])):
        with pytest.raises(SystemExit) as exited:
            command()
        one_line_error(capsys, exited.value.code, "loop of symbolic links")
