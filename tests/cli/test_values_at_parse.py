"""Values checked where they are read, through the real entry points in-process: one line ``error: ...``,
exit status 2 and nothing written; and the inputs that are right are taken in every documented form."""

import json
import shutil

import numpy as np
import pytest
import torch
from conftest import CLI_TINY as TINY
from conftest import one_line_error, write_syncdreamer_strip

from va_plugin.api import build_config
from va_plugin.cli import eval as eval_cli
from va_plugin.cli import export as export_cli
from va_plugin.cli import recon as recon_cli
from va_plugin.cli import train as train_cli
from va_plugin.data.datamanager import DataManager, DataManagerConfig
from va_plugin.data.dataparsers import detect_format
from va_plugin.data.dataparsers.transforms import TransformsDataParserConfig
from va_plugin.data.images import read_image, write_image
from va_plugin.data.rigs import WONDER3D_VIEWS
from va_plugin.engine.metrics_log import append_record
from va_plugin.errors import ConfigError
from va_plugin.utils.device import pick_device


@pytest.fixture
def strip_shape(tmp_path):
    """An image of SyncDreamer's shape (16 square tiles side by side): enough for the format and its options."""
    path = tmp_path / "strip.png"
    write_image(path, np.ones((16, 256, 3), np.float32))
    return path


def test_documented_list_forms_reach_the_config(tiny_scene, capsys):
    code = train_cli.main(["neus", "--data", str(tiny_scene), "--set",
                           "pipeline.datamanager.dataparser.background=0,0,0", "--help-config"])
    assert code == 0
    assert "pipeline.datamanager.dataparser.background = [0.0, 0.0, 0.0]" in capsys.readouterr().out


@pytest.mark.parametrize("elevation, shown", [("90", "90.0"), ("-90", "-90.0"), ("1000", "1000.0"), ("nan", "nan")])
def test_elevation_must_lie_between_the_poles(elevation, shown, strip_shape, tmp_path, capsys):
    run = tmp_path / "run"
    code = train_cli.main(["neus", "--data", str(strip_shape), "--elevation", elevation, "--output-dir", str(run),
                           *TINY])
    one_line_error(capsys, code, "elevation_deg (--elevation) must be between -90 and 90 degrees, exclusive "
                                 f"(SyncDreamer generates at 30), got {shown}")
    assert not run.exists()


def test_an_elevation_inside_the_range_is_taken(strip_shape):
    config = build_config("neus", strip_shape, elevation=-89.5)
    assert config.pipeline.datamanager.dataparser.elevation_deg == -89.5


def test_va_eval_with_nothing_to_score_writes_nothing(tiny_scene, tmp_path, capsys):
    scene = tmp_path / "scene"  # training views only: no held-out views, no ground-truth mesh
    shutil.copytree(tiny_scene, scene)
    (scene / "transforms_test.json").unlink()
    (scene / "scene.json").unlink()
    run = tmp_path / "run"
    assert train_cli.main(["neus", "--data", str(scene), "--output-dir", str(run), *TINY]) == 0
    capsys.readouterr()
    one_line_error(capsys, eval_cli.main(["--load-dir", str(run), "--no-progress", "--device", "cpu"]),
                   f"nothing to score in {run}: its data {scene} has no held-out views and no ground-truth mesh")
    one_line_error(capsys, eval_cli.main(["--load-dir", str(run), "--max-views", "0"]),
                   "--max-views must be at least 1, got 0")
    assert not (run / "eval.json").exists()


def test_an_empty_image_cannot_be_decoded(tmp_path, capsys):
    empty = tmp_path / "strip.png"
    empty.touch()
    run = tmp_path / "run"
    code = train_cli.main(["neus", "--data", str(empty), "--output-dir", str(run), *TINY])
    one_line_error(capsys, code, f"cannot decode image (empty, corrupt, truncated or not an image): {empty}")
    assert not run.exists()


def test_a_wonder3d_folder_missing_a_view_names_it(tmp_path, capsys):
    folder = tmp_path / "w3d"
    for view, _ in WONDER3D_VIEWS:
        if view != "back":
            write_image(folder / f"rgb_000_{view}.png", np.ones((16, 16, 3), np.float32))
    assert detect_format(folder) == "wonder3d"
    run = tmp_path / "run"
    code = train_cli.main(["neus", "--data", str(folder), "--output-dir", str(run), *TINY])
    one_line_error(capsys, code, f"{folder} is missing the wonder3d view file(s) rgb_000_back.png; expected a "
                                 "folder with rgb_000")
    assert not run.exists()


def test_va_recon_bad_input_is_the_error_alone(tmp_path, capsys):
    white = tmp_path / "white.png"  # a strip with no object to key out
    write_image(white, np.ones((16, 256, 3), np.float32))
    out = tmp_path / "out"
    code = recon_cli.main([str(white), "--out", str(out), "--device", "cpu", "--steps", "1"])
    one_line_error(capsys, code, "no detectable foreground")
    assert not out.exists()


def test_views_sharing_a_pose_are_named_at_data_load(tiny_scene, tmp_path):
    scene = tmp_path / "scene"
    shutil.copytree(tiny_scene, scene)
    meta = json.loads((scene / "transforms_train.json").read_text())
    meta["frames"][2]["transform_matrix"] = meta["frames"][0]["transform_matrix"]
    (scene / "transforms_train.json").write_text(json.dumps(meta))
    with pytest.warns(UserWarning, match="training views with the same camera pose: 0, 2; a view repeated"):
        DataManager(DataManagerConfig(dataparser=TransformsDataParserConfig(data=scene)))


def test_a_single_view_scene_is_warned_about_at_data_load(tiny_scene, tmp_path):
    scene = tmp_path / "scene"
    shutil.copytree(tiny_scene, scene)
    meta = json.loads((scene / "transforms_train.json").read_text())
    meta["frames"] = meta["frames"][:1]
    (scene / "transforms_train.json").write_text(json.dumps(meta))
    with pytest.warns(UserWarning, match="only one training view: a single viewpoint gives no depth"):
        DataManager(DataManagerConfig(dataparser=TransformsDataParserConfig(data=scene)))


def test_a_data_warning_is_printed_once_though_the_input_is_read_twice(tmp_path, capsys):
    """va-recon reads its input for training and again for the mesh: the warning is said once."""
    rgb = read_image(write_syncdreamer_strip(tmp_path / "rgb.png", tile=32))
    write_image(tmp_path / "rgba.png", np.concatenate([rgb, np.ones_like(rgb[..., :1])], -1))
    assert recon_cli.main([str(tmp_path / "rgba.png"), "--out", str(tmp_path / "out"), "--steps", "1",
                           "--no-texture", "--mesh-resolution", "16", "--device", "cpu", "--quiet",
                           *(f"--set={k}=4" for k in ("pipeline.datamanager.rays_per_batch", "pipeline.model.n_samples",
                                                     "pipeline.model.n_importance"))]) == 0
    assert capsys.readouterr().err.count("alpha channel is opaque everywhere") == 1


def test_the_training_summary_leaves_out_what_the_log_lacks(tmp_path):
    append_record(tmp_path, {"step": 1, "loss": 0.25, "psnr": 12.5, "train_seconds": 0.5})
    assert train_cli.training_summary("neus", tmp_path) == "trained neus for 1 step in 0.5 s (loss 0.25, psnr 12.5)"
    append_record(tmp_path, {"step": 3, "loss": None, "train_seconds": 1.0})
    assert train_cli.training_summary("neus", tmp_path) == "trained neus for 3 steps in 1.0 s"


def test_a_cuda_index_the_machine_lacks_is_refused(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    assert pick_device("cuda:0") == torch.device("cuda:0")
    with pytest.raises(ConfigError, match=r"'cuda:7' was asked for but this machine has 1 CUDA device\(s\): cuda:0$"):
        pick_device("cuda:7")
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    with pytest.raises(ConfigError, match=r"has 2 CUDA device\(s\): cuda:0 to cuda:1"):
        pick_device("cuda:2")


@pytest.mark.parametrize("main, argv, message", [
    (train_cli.main, ["neus", "--views", "5"], "error: argument --views: '5' is not one of 4, 8, 12, 16 or all "
                                               "(see va-train --help)"),
    (train_cli.main, ["neus", "--seed", "abc"], "error: argument --seed: invalid int value: 'abc'"),
    (recon_cli.main, ["x.png", "--quality", "best"], "error: argument --quality: invalid choice: 'best'"),
    (eval_cli.main, [], "error: the following arguments are required: --load-dir (see va-eval --help)"),
    (export_cli.main, ["mesh", "--resolution", "many"], "error: argument --resolution: invalid int value"),
])
def test_options_argparse_refuses_are_one_line_too(main, argv, message, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 2 and len(err) == 1 and err[0].startswith(message), err
