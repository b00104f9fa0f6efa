"""Safe output folders: nothing of the user's overwritten, one writer at a time, resume of the same run only,
and memory checked before the work."""

import json
import os
import shutil
import subprocess
import sys
import time

import pytest

from tests.conftest import REPO, write_syncdreamer_strip
from va_plugin.cli import export as export_cli
from va_plugin.cli import recon as recon_cli
from va_plugin.cli import train as train_cli
from va_plugin.engine import run_folder
from va_plugin.engine.run_folder import LOCK_FILE, MANIFEST_FILE, data_fingerprint, folder_lock

TINY = ["--no-progress", "--device", "cpu", "--steps", "1", "--set", "pipeline.datamanager.rays_per_batch=16",
        "--set", "pipeline.model.n_samples=4", "--set", "pipeline.model.n_importance=4"]
RECON = TINY[1:] + ["--no-texture", "--turntable-frames", "0"]


def one_line_error(capsys, code, message):
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], err


def snapshot(folder):
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def train(scene, out, *extra):
    return train_cli.main(["neus", "--data", str(scene), "--output-dir", str(out), *TINY, *extra])


@pytest.fixture
def run(tiny_scene, tmp_path):
    out = tmp_path / "run"
    assert train(tiny_scene, out) == 0
    return out


def test_a_folder_of_other_files_is_refused_naming_one_and_overwrite_lets_it(tiny_scene, tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "config.json").write_text('{"my": "own"}')
    one_line_error(capsys, train(tiny_scene, out), "holds no run (found config.json)")
    assert snapshot(out) == {(out / "config.json").relative_to(out): b'{"my": "own"}'}
    assert train(tiny_scene, out, "--overwrite") == 0
    assert (out / MANIFEST_FILE).is_file() and not (out / LOCK_FILE).exists()


def test_an_empty_folder_and_a_run_of_its_own_are_written(tiny_scene, tmp_path, capsys):
    out = tmp_path / "empty"
    out.mkdir()
    assert train(tiny_scene, out) == 0
    manifest = json.loads((out / MANIFEST_FILE).read_text())
    assert manifest["method"] == "neus" and manifest["data_sha256"] == data_fingerprint([tiny_scene])
    assert train(tiny_scene, out, "--resume") == 0  # its own run: continued


def test_the_input_folder_is_never_the_output(tiny_scene, tmp_path, capsys):
    scene = tmp_path / "scene"
    shutil.copytree(tiny_scene, scene)
    (scene / "mesh.ply").write_text("ground truth")  # a benchmark scene's true mesh
    before = snapshot(scene)
    for extra in ([], ["--overwrite"]):
        one_line_error(capsys, train(scene, scene, *extra), "holds the input")
        one_line_error(capsys, recon_cli.main([str(scene), "--out", str(scene), *RECON, *extra]), "holds the input")
        one_line_error(capsys, recon_cli.main([str(scene / "transforms_train.json"), "--out", str(scene), *extra]),
                       "holds the input")
    assert snapshot(scene) == before


def test_va_recon_refuses_a_folder_holding_a_users_mesh(tmp_path, capsys):
    strip = write_syncdreamer_strip(tmp_path / "strip.png")
    out = tmp_path / "out"
    out.mkdir()
    (out / "mesh.ply").write_text("my mesh")
    one_line_error(capsys, recon_cli.main([str(strip), "--out", str(out), *RECON]), "found mesh.ply")
    assert (out / "mesh.ply").read_text() == "my mesh" and len(list(out.iterdir())) == 1


def test_resume_checks_it_continues_the_same_run(run, tiny_scene, tmp_path, capsys):
    before = snapshot(run)
    one_line_error(capsys, train(tiny_scene, run, "--resume", "--set", "pipeline.model.eikonal_weight=0.5"),
                   "was trained with pipeline.model.eikonal_weight=")
    one_line_error(capsys, train(tiny_scene, run, "--resume", "--preset", "fast"), "with preset default, not fast")
    other = tmp_path / "other"
    shutil.copytree(tiny_scene, other)
    (other / "transforms_train.json").write_text((other / "transforms_train.json").read_text() + " ")
    one_line_error(capsys, train(other, run, "--resume"), "their contents differ")
    one_line_error(capsys, train(tiny_scene, run), "already holds a run; pass --resume")
    assert snapshot(run) == before
    assert train(tiny_scene, run, "--resume", "--steps", "2") == 0  # a longer budget is the same run


def test_resume_of_an_empty_folder_says_it_starts_afresh(tiny_scene, tmp_path, capsys):
    assert train(tiny_scene, tmp_path / "new", "--resume") == 0
    assert "holds no run yet; starting a new one" in capsys.readouterr().err


def test_overwrite_starts_an_earlier_run_again(run, tiny_scene, capsys):
    assert train(tiny_scene, run, "--overwrite", "--set", "pipeline.model.eikonal_weight=0.5") == 0
    manifest = json.loads((run / MANIFEST_FILE).read_text())
    assert manifest["config"]["pipeline.model.eikonal_weight"] == 0.5


def test_a_live_lock_refuses_a_second_writer_and_a_stale_one_is_taken_over(run, tiny_scene, capsys):
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (run / LOCK_FILE).write_text(json.dumps({"pid": sleeper.pid, "host": os.uname().nodename,
                                                 "started": run_folder._process_start(sleeper.pid)}))
        one_line_error(capsys, train(tiny_scene, run, "--resume"), f"is in use by process {sleeper.pid}")
        one_line_error(capsys, export_cli.main(["mesh", "--load-dir", str(run), "--resolution", "16"]),
                       f"in use by process {sleeper.pid}")
    finally:
        sleeper.kill()
        sleeper.wait()
    assert train(tiny_scene, run, "--resume") == 0
    assert "taking over the lock of process" in capsys.readouterr().err
    assert not (run / LOCK_FILE).exists()


def test_the_lock_is_reentrant_in_one_process_and_released(tmp_path):
    with folder_lock(tmp_path), folder_lock(tmp_path):
        assert (tmp_path / LOCK_FILE).is_file()
    assert not (tmp_path / LOCK_FILE).exists()


def test_a_second_process_on_a_folder_in_use_is_refused(tiny_scene, tmp_path):
    out = tmp_path / "shared"
    command = [sys.executable, "-m", "va_plugin.cli.train", "neus", "--data", str(tiny_scene), "--output-dir",
               str(out), *TINY]
    with folder_lock(out):  # this process trains there, as far as the other one can tell
        second = subprocess.run(command, cwd=REPO, stderr=subprocess.PIPE, text=True)
    assert second.returncode == 2 and f"in use by process {os.getpid()}" in second.stderr, second.stderr
    assert second.stderr.count("\n") == 1 and not list(out.iterdir())


def test_export_refuses_to_replace_a_users_file(run, tmp_path, capsys):
    mine = tmp_path / "mine.ply"
    mine.write_text("my mesh")
    one_line_error(capsys, export_cli.main(["mesh", "--load-dir", str(run), "--resolution", "16",
                                            "--output", str(mine)]), "exists; pass --overwrite")
    assert mine.read_text() == "my mesh"
    assert export_cli.main(["mesh", "--load-dir", str(run), "--resolution", "16", "--output", str(mine),
                            "--overwrite"]) == 0
    assert mine.read_bytes().startswith(b"ply")


@pytest.mark.parametrize("option, message", [
    ("pipeline.datamanager.rays_per_batch=100000000", "the largest that fits is pipeline.datamanager.rays_per_batch"),
    ("pipeline.datamanager.dataparser.image_scale=1000", "the largest that fits is pipeline.datamanager.dataparser"),
])
def test_training_that_would_not_fit_in_memory_is_refused_at_once(option, message, tiny_scene, tmp_path, capsys):
    started = time.perf_counter()
    one_line_error(capsys, train(tiny_scene, tmp_path / "run", "--set", option), message)
    assert time.perf_counter() - started < 5 and not (tmp_path / "run").exists()


def test_va_recon_checks_the_mesh_grid_before_training(tmp_path, capsys):
    strip = write_syncdreamer_strip(tmp_path / "strip.png")
    one_line_error(capsys, recon_cli.main([str(strip), "--out", str(tmp_path / "run"), "--mesh-resolution",
                                           "100000", *RECON]), "the largest that fits is --mesh-resolution")
    assert not (tmp_path / "run").exists()


def test_the_data_fingerprint_follows_the_files(tiny_scene, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(tiny_scene, copy)
    assert data_fingerprint([copy]) == data_fingerprint([tiny_scene])
    (copy / ".hidden").write_text("ignored")
    assert data_fingerprint([copy]) == data_fingerprint([tiny_scene])
    (copy / "transforms_train.json").write_text((copy / "transforms_train.json").read_text() + "\n")
    assert data_fingerprint([copy]) != data_fingerprint([tiny_scene])


def test_export_to_a_read_only_place_is_refused_before_marching_cubes(run, tmp_path, capsys, monkeypatch):
    from va_plugin.export import files  # the module whose marching cubes must not run

    monkeypatch.setattr(files, "extract_mesh", lambda *a, **k: pytest.fail("marching cubes ran"))
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    monkeypatch.setattr(run_folder.tempfile, "TemporaryFile", lambda **k: (_ for _ in ()).throw(OSError("ro")))
    one_line_error(capsys, export_cli.main(["mesh", "--load-dir", str(run), "--resolution", "16", "--output",
                                            str(locked / "mesh.ply")]), "cannot be written")
