"""va-recon: one command from a generator's output to a textured mesh, and the bad input it refuses
before any work (one line, exit 2, nothing written); the checks it shares with va-train and va-batch."""

import json

import numpy as np
import pytest
import trimesh
from conftest import tiny_config, write_syncdreamer_strip

from va_plugin.cli import recon, train
from va_plugin.data.dataparsers import resolve_dataparser
from va_plugin.engine.health import HealthConfig, UnusableModel, check_usable

TINY = ["--set", "pipeline.datamanager.rays_per_batch=32", "--set", "pipeline.model.n_samples=8",
        "--set", "pipeline.model.n_importance=8", "--set", "pipeline.model.crossings_samples=16",
        "--device", "cpu", "--texture-size", "64", "--turntable-frames", "4", "--mesh-resolution", "32"]


@pytest.fixture(scope="module")
def strip(tmp_path_factory):
    return write_syncdreamer_strip(tmp_path_factory.mktemp("sd") / "sample.png", tile=32)


def test_one_command_writes_a_textured_mesh_from_every_view(strip, tmp_path, capsys):
    out = tmp_path / "out"
    assert recon.main([str(strip), "--out", str(out), "--steps", "3", *TINY]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["views"] == 16 and summary["masks"] == "color key" and summary["steps"] == 3
    assert str(out / "mesh.glb") in printed and str(out / "turntable" / "turntable.mp4") in printed
    scene = trimesh.load(out / "mesh.glb")
    geometry = next(iter(scene.geometry.values()))
    assert geometry.visual.material.baseColorTexture is not None and len(geometry.visual.uv) == len(geometry.vertices)
    assert (out / "turntable" / "turntable.png").is_file() and (out / "mesh.ply").is_file()
    # mesh.glb and mesh.obj stand upright (+Y up, on y = 0); the frame is in summary.json
    assert summary["mesh_frame"]["up"] == "+y" and summary["textured_obj"] == str(out / "mesh.obj")
    for name in ("mesh.glb", "mesh.obj"):
        loaded = trimesh.load(out / name, force="mesh", process=False)
        assert abs(loaded.bounds[0][1]) < 1e-6 and len(loaded.faces) == summary["textured_faces"]
    # a second call without --resume refuses to overwrite the run; with it, it continues (nothing to train)
    assert recon.main([str(strip), "--out", str(out), "--steps", "3", *TINY]) == 2
    assert "--resume" in capsys.readouterr().err
    assert recon.main([str(strip), "--out", str(out), "--steps", "3", "--resume", "--quiet", *TINY]) == 0
    printed = capsys.readouterr()  # --quiet: the summary alone, no stage lines or progress
    assert printed.err == "" and printed.out.splitlines() == recon.summary_lines(
        json.loads((out / "summary.json").read_text()), out)


@pytest.mark.parametrize("extra, message", [
    (["--steps", "0"], "--steps must be at least 1, got 0"),
    (["--set", "pipeline.model.eikonal_weigth=0.1"], "did you mean pipeline.model.eikonal_weight"),
    (["--method", "nerf"], "unknown method 'nerf'"),
    (["--texture-size", "100"], "--texture-size must be a power of two"),
])
def test_bad_commands_are_one_line_and_write_nothing(extra, message, strip, tmp_path, capsys):
    out = tmp_path / "out"
    assert recon.main([str(strip), "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and err.startswith("error: ")
    assert not out.exists()


def test_output_folder_that_is_a_file_or_read_only(strip, tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for out, message in ((a_file, "is a file, not a folder"), (a_file / "run", "cannot be created")):
        assert recon.main([str(strip), "--out", str(out)]) == 2
        assert message in capsys.readouterr().err
        assert train.main(["neus", "--data", str(strip), "--output-dir", str(out)]) == 2
        assert "--output-dir" in capsys.readouterr().err


def test_views_takes_4_8_12_16_or_all(strip):
    parser = train.build_parser({})
    assert parser.parse_args(["neus", "--views", "all"]).views == "all"
    assert parser.parse_args(["neus", "--views", "8"]).views == 8
    with pytest.raises(SystemExit):
        parser.parse_args(["neus", "--views", "5"])
    config = resolve_dataparser(strip)
    assert config.num_views == 16  # every view SyncDreamer made, by default


def test_help_lists_presets_and_next_step():
    text = train.build_parser({"neus": __import__("va_plugin.registry", fromlist=["get_method"]).get_method("neus")}
                              ).format_help()
    assert "--preset fast" in text and "--preset accurate" in text


def test_opaque_alpha_falls_back_to_the_color_key(tmp_path):
    from va_plugin.data.images import read_image, write_image

    path = write_syncdreamer_strip(tmp_path / "rgb.png", tile=32)
    rgb = read_image(path)
    write_image(tmp_path / "rgba.png", np.concatenate([rgb, np.ones_like(rgb[..., :1])], -1))
    parser = resolve_dataparser(tmp_path / "rgba.png").setup()
    with pytest.warns(UserWarning, match="alpha channel is opaque everywhere"):
        train_views = parser.get_outputs("train")
    assert train_views.metadata["mask_source"] == "color key"
    assert 0.02 < float(train_views.masks.mean()) < 0.5  # the object, not the whole view


def test_a_model_that_renders_nothing_fails_the_run(tiny_scene, tmp_path):
    """The health check after training: the start sphere covers the object, a tiny one does not."""
    healthy = tiny_config("neus", tiny_scene, tmp_path / "a").setup().pipeline
    assert check_usable(healthy, HealthConfig(final_check_after=1), steps=1) > 0.5
    assert check_usable(healthy, HealthConfig(), steps=1) is None  # too young to judge
    empty = tiny_config("neus", tiny_scene, tmp_path / "b", **{"pipeline.model.field.init_radius": 0.02})
    with pytest.raises(UnusableModel, match="renders almost nothing"):
        check_usable(empty.setup().pipeline, HealthConfig(final_check_after=1), steps=1)


def test_export_mesh_help_says_defaults_and_the_textured_output(capsys):
    from va_plugin.cli import export

    with pytest.raises(SystemExit):
        export.build_parser().parse_args(["mesh", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "with --texture RUN/mesh.glb and RUN/mesh.obj" in text
    assert "(default 128)" in text and "(default 1024)" in text
    assert "--faces N" in text and "--frame {upright,training}" in text and "--quiet" in text
