"""``va-export mesh --texture`` and ``va-eval --texture`` on a tiny trained run; bad texture options."""

import json

import numpy as np
import pytest
import trimesh
from conftest import tiny_trained_run

from va_plugin.cli import eval as eval_cli
from va_plugin.cli import export as export_cli


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return tiny_trained_run(tmp_path_factory, with_mesh=False)


def one_line_error(capsys, code, message):
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], err


@pytest.mark.parametrize("suffix, files", [(".glb", ["m.glb"]), (".obj", ["m.obj", "m.mtl", "m.png"])])
def test_export_writes_a_textured_mesh_that_loads(run, tmp_path, suffix, files, capsys):
    out = tmp_path / f"m{suffix}"
    code = export_cli.main(["mesh", "--load-dir", str(run), "--texture", "--texture-size", "64", "--resolution", "24",
                            "--output", str(out), "--device", "cpu"])
    assert code == 0, capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(files + ["m_bake.json", "m_bake.png", "m_frame.json"])
    loaded = trimesh.load(out, force="mesh")
    assert isinstance(loaded.visual, trimesh.visual.TextureVisuals) and len(loaded.faces) > 0
    record = json.loads((tmp_path / "m_bake.json").read_text())
    assert record["texture_size"] == 64 and len(record["view_texels"]) == 4 and record["texels_seen"] > 0
    assert record["faces_textured"] == len(loaded.faces) <= record["faces_extracted"]


@pytest.mark.parametrize("flag", ["--faces", "--max-faces"])  # --max-faces: its old name
def test_export_simplifies_the_mesh_to_faces(run, tmp_path, flag, capsys):
    out = tmp_path / "m.glb"
    code = export_cli.main(["mesh", "--load-dir", str(run), "--texture", "--texture-size", "32", "--resolution", "24",
                            flag, "200", "--output", str(out), "--device", "cpu"])
    printed = capsys.readouterr().out
    assert code == 0
    record = json.loads((tmp_path / "m_bake.json").read_text())
    assert record["faces_textured"] == 200 < record["faces_extracted"], record
    assert "simplified from" in printed and len(trimesh.load(out, force="mesh").faces) == record["faces_textured"]


def test_faces_without_texture_is_refused(run, tmp_path, capsys):
    code = export_cli.main(["mesh", "--load-dir", str(run), "--faces", "100", "--output", str(tmp_path / "m.ply")])
    one_line_error(capsys, code, "needs --texture")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, message", [
    (["--texture-size", "100"], "power of two"),
    (["--texture-size", "65536"], "power of two"),
    (["--output", "{tmp}/m.ply"], "not '.ply'"),
    (["--faces", "-1"], "--faces must be 0"),
    (["--faces", "3"], "--faces must be 0"),
])
def test_bad_texture_options_are_refused_before_any_work(run, tmp_path, argv, message, capsys):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    if "--output" not in argv:
        argv += ["--output", str(tmp_path / "m.glb")]
    code = export_cli.main(["mesh", "--load-dir", str(run), "--texture", "--resolution", "24", *argv])
    one_line_error(capsys, code, message)
    assert list(tmp_path.iterdir()) == []


def test_eval_scores_field_and_textured_mesh_side_by_side(run, tmp_path, capsys):
    code = eval_cli.main(["--load-dir", str(run), "--texture", "--texture-size", "32", "--mesh-resolution", "24",
                          "--max-views", "1", "--output", str(tmp_path / "eval.json"), "--no-progress",
                          "--device", "cpu"])
    assert code == 0, capsys.readouterr().err
    result = json.loads((tmp_path / "eval.json").read_text())
    for key in ("psnr", "mesh_psnr", "mesh_ssim", "mesh_lpips"):
        assert np.isfinite(result[key])
    assert result["texture_params"]["size"] == 32
    assert result["texture_params"]["supersample"] == 1  # one ray through each pixel centre, as the field
    out = capsys.readouterr().out
    assert "textured mesh" in out and "field" in out
    # 2x2 rays a pixel: the same bake scored with anti-aliased edges, so other scores
    code = eval_cli.main(["--load-dir", str(run), "--texture", "--texture-size", "32", "--mesh-resolution", "24",
                          "--max-views", "1", "--output", str(tmp_path / "eval2.json"), "--no-progress",
                          "--device", "cpu", "--texture-supersample", "2"])
    assert code == 0, capsys.readouterr().err
    blended = json.loads((tmp_path / "eval2.json").read_text())
    assert blended["texture_params"]["supersample"] == 2 and blended["psnr"] == result["psnr"]
    assert blended["mesh_psnr"] != result["mesh_psnr"]


@pytest.mark.parametrize("value", ["0", "9"])
def test_eval_refuses_a_bad_number_of_rays_a_pixel(run, tmp_path, value, capsys):
    code = eval_cli.main(["--load-dir", str(run), "--texture", "--texture-supersample", value,
                          "--output", str(tmp_path / "eval.json"), "--no-progress"])
    one_line_error(capsys, code, "--texture-supersample must be a whole number")
    assert list(tmp_path.iterdir()) == []


def test_eval_default_rays_a_pixel_is_the_scoring_default():
    # va-eval imports the texture code lazily, so its --texture-supersample default is written out; it must stay
    # the package's scoring default (one ray through each pixel centre, as the field's renders)
    from va_plugin.eval.mesh_render import SCORE_SUPERSAMPLE
    assert eval_cli.build_parser().parse_args(["--load-dir", "x"]).texture_supersample == SCORE_SUPERSAMPLE


def test_default_export_writes_glb_and_obj_upright_and_ply_as_trained(run, tmp_path, capsys):
    import shutil

    run = shutil.copytree(run, tmp_path / "run")
    assert export_cli.main(["mesh", "--load-dir", str(run), "--resolution", "24", "--device", "cpu", "--quiet"]) == 0
    assert export_cli.main(["mesh", "--load-dir", str(run), "--texture", "--texture-size", "32", "--resolution", "24",
                            "--device", "cpu", "--quiet"]) == 0
    printed = capsys.readouterr()
    assert printed.err == "" and len(printed.out.splitlines()) == 2, printed  # --quiet: the two summaries only
    assert "upright" in printed.out.splitlines()[1]
    for name in ("mesh.ply", "mesh.glb", "mesh.obj", "mesh.mtl", "mesh.png", "mesh_frame.json", "mesh_bake.json"):
        assert (run / name).is_file(), name
    record = json.loads((run / "mesh_frame.json").read_text())
    to_file = np.array(record["training_to_file"])
    trained = trimesh.load(run / "mesh.ply", process=False)  # as marching cubes left it: the training frame
    for name in ("mesh.glb", "mesh.obj"):
        loaded = trimesh.load(run / name, force="mesh", process=False)
        assert abs(loaded.bounds[0][1]) < 1e-6 and np.allclose(loaded.bounds.mean(0)[[0, 2]], 0, atol=1e-6)
        moved = trimesh.transform_points(trained.vertices, to_file)
        assert np.allclose(loaded.bounds, [moved.min(0), moved.max(0)], atol=1e-5), name
        assert loaded.volume > 0  # outward normals


def test_more_faces_than_the_grid_gives_come_from_a_finer_grid(run, tmp_path, capsys):
    code = export_cli.main(["mesh", "--load-dir", str(run), "--texture", "--texture-size", "16", "--resolution", "16",
                            "--output", str(tmp_path / "coarse.glb"), "--device", "cpu", "--quiet"])
    coarse = json.loads((tmp_path / "coarse_bake.json").read_text())["faces_extracted"]
    want = 2 * coarse
    code = export_cli.main(["mesh", "--load-dir", str(run), "--texture", "--texture-size", "16", "--resolution", "16",
                            "--faces", str(want), "--output", str(tmp_path / "m.glb"), "--device", "cpu", "--quiet"])
    printed = capsys.readouterr()
    assert code == 0 and printed.err == "", printed.err
    record = json.loads((tmp_path / "m_bake.json").read_text())
    assert record["mesh_resolution"] > 16 and record["faces_extracted"] > want
    assert abs(record["faces_textured"] - want) <= 0.01 * want and "grid" in printed.out


def test_more_faces_than_the_finest_grid_gives_keeps_the_mesh_with_a_note(run, tmp_path, capsys, monkeypatch):
    from va_plugin.export import mesh

    monkeypatch.setattr(mesh, "FACES_MAX_RESOLUTION", 20)  # the finest grid, small for the test
    code = export_cli.main(["mesh", "--load-dir", str(run), "--texture", "--texture-size", "16", "--resolution", "16",
                            "--faces", "1000000", "--output", str(tmp_path / "m.glb"), "--device", "cpu", "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 0 and len(err) == 1 and "--faces 1000000: the mesh has only" in err[0], err
    record = json.loads((tmp_path / "m_bake.json").read_text())
    assert record["faces_textured"] == record["faces_extracted"] < 1000000 and record["mesh_resolution"] == 20
