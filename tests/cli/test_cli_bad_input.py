"""Bad input at every entry point (va-train, va-eval, va-export, va-demo): one line ``error: ...`` on
stderr, exit status 2, and no output left behind that looks valid."""

import json
import shutil

import numpy as np
import pytest
import torch
from conftest import CLI_TINY as TINY
from conftest import one_line_error

from va_plugin.cli import demo as demo_cli
from va_plugin.cli import eval as eval_cli
from va_plugin.cli import export as export_cli
from va_plugin.cli import train as train_cli
from va_plugin.data.images import write_image
from va_plugin.engine.trainer import list_checkpoints


def image(root, k=1):
    meta = json.loads((root / "transforms_train.json").read_text())
    return root / meta["frames"][k]["file_path"]


def set_pose(meta, k, matrix):
    meta["frames"][k]["transform_matrix"] = matrix


def mutate(root, meta, breakage):
    """Break a copy of the tiny scene (its training split) in one way."""
    pose = meta["frames"][1]["transform_matrix"]
    if breakage == "truncated-image":
        data = image(root).read_bytes()
        image(root).write_bytes(data[: len(data) // 2])
    elif breakage == "corrupt-image":
        image(root).write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(200))
    elif breakage == "text-file-as-image":
        image(root).write_text("not an image at all")
    elif breakage == "json-as-image":
        meta["frames"][1]["file_path"] = "scene.json"
    elif breakage == "missing-image":
        image(root).unlink()
    elif breakage == "sizes-differ":
        write_image(image(root), np.zeros((10, 12, 4), np.float32))
        meta.pop("w"), meta.pop("h")
    elif breakage == "nan-pose":
        pose[0][3] = float("nan")
    elif breakage == "inf-pose":
        pose[1][1] = float("inf")
    elif breakage == "singular-pose":
        set_pose(meta, 1, [[0, 0, 0, 1], [0, 0, 0, 1], [0, 0, 0, 1], [0, 0, 0, 1]])
    elif breakage == "scaled-pose":
        set_pose(meta, 1, [[2 * v for v in row[:3]] + row[3:] for row in pose[:3]] + [pose[3]])
    elif breakage == "sheared-pose":
        pose[0][1] += 0.3
    elif breakage == "reflected-pose":
        set_pose(meta, 1, [[-row[0]] + row[1:] for row in pose[:3]] + [pose[3]])
    elif breakage == "projective-pose":
        pose[3] = [0.1, 0.0, 0.0, 1.0]
    elif breakage == "negative-focal":
        meta["frames"][1]["fl_x"] = -20.0
    elif breakage.startswith("angle="):  # Blender intrinsics: the field of view instead of focal lengths
        for frame in meta["frames"]:
            for key in ("fl_x", "fl_y", "cx", "cy"):
                frame.pop(key, None)
        meta["camera_angle_x"] = json.loads(breakage[len("angle="):])
    elif "=" in breakage:  # a camera value of frame 1 (fl_x=...) or of the file (w=...)
        key, value = breakage.split("=", 1)
        (meta if key in ("w", "h") else meta["frames"][1])[key] = json.loads(value)
    elif breakage == "same-pose-everywhere":
        for frame in meta["frames"]:
            frame["transform_matrix"] = meta["frames"][0]["transform_matrix"]
    elif breakage == "empty-masks":
        for k in range(len(meta["frames"])):
            write_image(image(root, k), np.zeros((24, 24, 4), np.float32))
    elif breakage == "object-outside-bound":
        meta["scene_radius"] = 0.1
    elif breakage == "no-frames":
        meta["frames"] = []
    elif breakage == "not-json":
        return "{ this is not json"
    return json.dumps(meta)


@pytest.mark.parametrize("breakage, message", [
    ("truncated-image", "cannot decode image"),
    ("corrupt-image", "cannot decode image"),
    ("text-file-as-image", "cannot decode image"),
    ("json-as-image", "cannot decode image"),
    ("missing-image", "image not found"),
    ("sizes-differ", "images differ in size"),
    ("nan-pose", "NaN or infinite"),
    ("inf-pose", "NaN or infinite"),
    ("singular-pose", "not orthonormal"),
    ("scaled-pose", "not orthonormal"),
    ("sheared-pose", "not orthonormal"),
    ("reflected-pose", "reflection"),
    ("projective-pose", "not a rigid transform"),
    ("negative-focal", "positive focal lengths"),
    # intrinsics checked as they are read: never a ZeroDivisionError, a ValueError or a run that fails at the bake
    ("angle=0", "camera_angle_x is the horizontal field of view in radians, between 0 and pi; got 0"),
    ('angle="abc"', "camera_angle_x must be a finite number, got 'abc'"),
    ("angle=3.1416", "between 0 and pi"),
    ("angle=3.1", "a field of view of 177.6 degrees"),
    ("angle=null", "no intrinsics (need camera_angle_x or fl_x"),
    ('fl_x="abc"', "fl_x must be a finite number, got 'abc'"),
    ("fl_x=0.01", "is beyond the 170 a perspective camera can have"),
    ("fl_y=0", "positive focal lengths"),
    ("cx=-1", "the principal point (cx -1, cy 12) must lie inside the 24x24 image"),
    ('cy="12"', "cy must be a finite number, got '12'"),
    ('w="abc"', "w must be a finite number, got 'abc'"),
    ("h=0", "h must be a positive whole number of pixels, got 0"),
    ("same-pose-everywhere", "all 4 training views have the same camera pose"),
    ("empty-masks", "masks are empty"),
    ("object-outside-bound", "does not fit in the bounding sphere"),
    ("no-frames", "has no frames"),
    ("not-json", "not valid JSON"),
])
def test_va_train_refuses_a_broken_scene(breakage, message, tiny_scene, tmp_path, capsys):
    root = tmp_path / "scene"
    shutil.copytree(tiny_scene, root)
    meta = json.loads((root / "transforms_train.json").read_text())
    (root / "transforms_train.json").write_text(mutate(root, meta, breakage))
    run = tmp_path / "run"
    code = train_cli.main(["neus", "--data", str(root), "--output-dir", str(run), *TINY])
    one_line_error(capsys, code, message)  # (libpng's own complaint about the truncated file is silenced)
    assert not run.exists()


@pytest.mark.parametrize("argv, message", [
    (["va-neus", "--set", "pipeline.model.field.branches=false"], "fusion needs the per-view branches"),
    (["va-neus", "--set", "pipeline.model.field.pretrain_fraction=0.8"], "sum to at most 1"),
    (["neus", "--views", "8"], "--views applies to syncdreamer inputs only"),
    (["neus", "--set", "optimizers.fields.lr=nan"], "takes a finite number"),
    (["neus", "--set", "optimizers.nope.lr=1"], "unknown option 'optimizers.nope'"),
    (["neus", "--set", "pipeline.datamanager.dataparser.scene_radius=2"], "contradictory scene radius"),
    (["neus", "--set", "pipeline.datamanager.rays_per_batch=0"], "rays_per_batch must be positive"),
    (["neus", "--set", "health.lr_backoff=2"], "lr_backoff"),
    (["neus", "--steps", "0"], "--steps must be at least 1, got 0"),
    # values out of range: refused before any work, never a traceback or a run that trains backwards
    (["neus", "--set", "optimizers.fields.lr=-1"], "optimizers.fields.lr must be >= 0"),
    (["neus", "--set", "optimizers.variance.eps=0"], "eps must be a finite number > 0"),
    (["neus", "--set", "scheduler.final_fraction=2"], "must be in [0, 1]"),
    (["neus", "--set", "pipeline.model.eikonal_weight=-1"], "eikonal_weight must be >= 0"),
    (["neus", "--set", "pipeline.model.cos_anneal_fraction=3"], "cos_anneal_fraction must be in [0, 1]"),
    (["neus", "--set", "pipeline.model.n_samples=0"], "n_samples must be positive"),
    (["neus", "--set", "pipeline.model.up_sample_steps=-1"], "up_sample_steps must be >= 0"),
    (["neus", "--set", "pipeline.model.field.sdf_width=0"], "sdf_width must be positive"),
    (["neus", "--set", "pipeline.model.field.max_resolution=4"], "base_resolution <= max_resolution"),
    (["neus", "--set", "pipeline.model.field.log2_hashmap_size=40"], "log2_hashmap_size must be in [1, 32]"),
    (["neus", "--set", "pipeline.model.field.init_radius=5"], "init_radius must be in (0, bound"),
    (["neus", "--set", "pipeline.model.field.direction_frequencies=-2"], "direction_frequencies must be -1"),
    (["neus", "--set", "pipeline.datamanager.dataparser.image_scale=0"], "image_scale must be positive"),
    (["ngp", "--set", "pipeline.model.occupancy_grid.decay=1.5"], "decay must be in [0, 1]"),
    (["va-neus", "--set", "pipeline.model.field.branch_layers=0"], "branch_layers must be positive"),
    # lists, groups, devices and seeds: checked as --set and the flags are read
    (["neus", "--set", "pipeline.datamanager.dataparser.background=[1,1]"],
     "background takes 3 values (like 1.0,1.0,1.0 or [1.0,1.0,1.0]), got 2 in '[1,1]'"),
    (["neus", "--set", "pipeline.datamanager.dataparser.background=1,1,1,1"], "background takes 3 values"),
    (["neus", "--set", "pipeline.datamanager.dataparser.background=[2,2,2]"],
     "background must be in [0, 1], got (2.0, 2.0, 2.0)"),
    (["neus", "--set", "pipeline.datamanager.dataparser.background=[a,b,c]"], "background takes numbers"),
    (["neus", "--set", "pipeline.model=5"], "option pipeline.model is a group of options, not a value"),
    (["neus", "--set", "optimizers.fields=3"], "e.g. optimizers.fields.lr=VALUE"),
    (["neus", "--set", "pipeline.model._target=x"], "unknown option 'pipeline.model._target'"),
    (["neus", "--set", "pipeline.datamanager.seed=-1"], "pipeline.datamanager.seed must be an integer from 0"),
    (["neus", "--seed", "99999999999999999999999"], "option seed must be an integer from 0 to 4294967295"),
    (["neus", "--seed", "-1"], "option seed must be an integer from 0 to 4294967295 (2**32 - 1), got -1"),
    (["neus", "--device", "mps"], "device 'mps' is not supported; use auto, cpu or cuda[:N]"),
    (["neus", "--device", "meta"], "device 'meta' is not supported"),
    (["neus", "--device", "cpu:3"], "there is one CPU device"),
    (["neus", "--device", "cuda:7"], "device 'cuda:7' was asked for but"),
    (["neus", "--device", "gpu"], "unknown device 'gpu'"),
])
def test_va_train_refuses_contradictory_options(argv, message, tiny_scene, tmp_path, capsys):
    run = tmp_path / "run"
    device = [] if "--device" in argv else ["--device", "cpu"]
    code = train_cli.main(argv + ["--data", str(tiny_scene), "--output-dir", str(run), "--no-progress", *device]
                          + (["--steps", "1"] if "--steps" not in argv else []))
    one_line_error(capsys, code, message)
    assert not run.exists()


@pytest.fixture(scope="module")
def trained(tiny_scene, tmp_path_factory):
    run = tmp_path_factory.mktemp("trained") / "run"
    assert train_cli.main(["neus", "--data", str(tiny_scene), "--output-dir", str(run), *TINY]) == 0
    return run


def broken_run(trained, tmp_path, how):
    run = tmp_path / how
    shutil.copytree(trained, run)
    path = list_checkpoints(run)[-1]
    if how == "corrupt-checkpoint":
        path.write_bytes(b"PK\x03\x04" + bytes(64))
    elif how == "truncated-checkpoint":
        path.write_bytes(path.read_bytes()[:1000])
    elif how == "foreign-checkpoint":
        torch.save({"weights": torch.zeros(3)}, path)
    elif how == "nan-checkpoint":
        state = torch.load(path, weights_only=False)
        state["model"]["field.sdf_net.out.bias"] = torch.full_like(state["model"]["field.sdf_net.out.bias"],
                                                                    float("nan"))
        torch.save(state, path)
    elif how == "no-checkpoint":
        path.unlink()
    return run


CHECKPOINT_CASES = [("corrupt-checkpoint", "no readable checkpoint"),
                    ("truncated-checkpoint", "no readable checkpoint"),
                    ("foreign-checkpoint", "not a va-plugin checkpoint"), ("nan-checkpoint", "NaN or infinite values"),
                    ("no-checkpoint", "holds no checkpoint")]


@pytest.mark.parametrize("how, message", CHECKPOINT_CASES)
def test_va_export_and_va_eval_refuse_a_bad_checkpoint(how, message, trained, tmp_path, capsys):
    run = broken_run(trained, tmp_path, how)
    one_line_error(capsys, export_cli.main(["mesh", "--load-dir", str(run), "--resolution", "16"]), message)
    one_line_error(capsys, eval_cli.main(["--load-dir", str(run), "--no-progress"]), message)
    assert not (run / "mesh.ply").exists() and not (run / "eval.json").exists()


@pytest.mark.parametrize("how, message", CHECKPOINT_CASES[:3])
def test_va_train_resume_refuses_a_bad_checkpoint(how, message, trained, tiny_scene, tmp_path, capsys):
    run = broken_run(trained, tmp_path, how)
    code = train_cli.main(["neus", "--data", str(tiny_scene), "--output-dir", str(run), "--resume", *TINY])
    one_line_error(capsys, code, message)


def test_va_train_resume_refuses_a_checkpoint_of_another_method(trained, tiny_scene, tmp_path, capsys):
    run = broken_run(trained, tmp_path, "other-method")
    code = train_cli.main(["ngp", "--data", str(tiny_scene), "--output-dir", str(run), "--resume", *TINY[:5]])
    one_line_error(capsys, code, "was trained with method neus, not ngp")  # the run's manifest says so
    (run / "va-run.json").unlink()  # a run from before manifests: its checkpoint says so
    code = train_cli.main(["ngp", "--data", str(tiny_scene), "--output-dir", str(run), "--resume", *TINY[:5]])
    one_line_error(capsys, code, "is of method 'neus', not 'ngp'")


def test_va_export_refuses_an_unknown_format_before_any_work(trained, capsys):
    output = trained / "mesh.stl"
    one_line_error(capsys, export_cli.main(["mesh", "--load-dir", str(trained), "--output", str(output)]),
                   "unknown mesh format '.stl'")
    assert not list(trained.glob("mesh*"))


def shifted_sdf_run(trained, run, shift):
    """A copy of the trained run whose SDF is shifted by ``shift`` everywhere."""
    shutil.copytree(trained, run)
    path = list_checkpoints(run)[-1]
    state = torch.load(path, weights_only=False)
    state["model"]["field.sdf_net.out.bias"] += shift
    torch.save(state, path)
    return run


def test_va_export_mesh_of_a_field_without_surface_writes_nothing(trained, tmp_path, capsys):
    run = shifted_sdf_run(trained, tmp_path / "empty", 10.0)  # positive everywhere: nothing inside
    one_line_error(capsys, export_cli.main(["mesh", "--load-dir", str(run), "--resolution", "16"]), "no surface")
    assert not list(run.glob("mesh*"))


def test_va_export_says_when_the_mesh_is_the_bounding_sphere(trained, tmp_path, capsys):
    # negative everywhere, as after the 100x learning-rate run on the mug: marching cubes finds only
    # the clip at the bounding sphere, which is no object
    run = shifted_sdf_run(trained, tmp_path / "full", -10.0)
    assert export_cli.main(["mesh", "--load-dir", str(run), "--resolution", "16"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["warning: the field is inside the object over 100% of the bounding sphere, so most of the mesh "
                   "is the sphere itself, not an object: the run diverged (or the scene radius is too small)"]


@pytest.mark.parametrize("argv, message", [
    (["--method", "nope"], "unknown method 'nope'"),
    (["--resolution", "0"], "at least 8 pixels"),
    (["--steps", "0", "--resolution", "24"], "--steps must be at least 1, got 0"),
    (["--preset", "turbo", "--resolution", "24"], "unknown preset 'turbo'"),
])
def test_va_demo_bad_options(argv, message, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("VA_PLUGIN_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "demo"
    one_line_error(capsys, demo_cli.main(argv + ["--output-dir", str(out), "--no-progress", "--device", "cpu"]),
                   message)
    assert not out.exists()
