"""Benchmark scenes: determinism, level 0 = clean, what each inconsistency kind touches, monotone levels,
watertight procedural meshes, GSO alignment, the textured-mesh source, the CLI and the default scene."""

import hashlib
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from va_plugin.bench.scenes import build_scene, ensure_default_scene, gso
from va_plugin.bench.scenes.builder import SCENE_VERSION, on_white
from va_plugin.bench.scenes.inconsistency import InconsistencySpec, draw_perturbation
from va_plugin.bench.scenes.meshfile import load_textured_mesh
from va_plugin.bench.scenes.rig import benchmark_cameras, syncdreamer_rig
from va_plugin.bench.scenes.shapes import OBJECTS, object_mesh
from va_plugin.bench.scenes.sources import ImageSource, load_source
from va_plugin.data.dataparsers.transforms import TransformsDataParserConfig
from va_plugin.errors import ConfigError, DataError
from va_plugin.eval import psnr
from va_plugin.raycast import MeshRenderer

REPO = Path(__file__).resolve().parents[2]
SHARED_DATA = REPO.parent / "shared" / "data"
GSO_ROOT = SHARED_DATA / "gso"
SPOT = SHARED_DATA / "meshes" / "spot" / "spot_triangulated_good.obj"
needs_gso = pytest.mark.skipif(not (GSO_ROOT / "alignment.json").is_file(), reason=f"GSO data absent: {GSO_ROOT}")
needs_spot = pytest.mark.skipif(not SPOT.is_file(), reason=f"Spot mesh absent: {SPOT}")

MESH_RES = 64  # coarse marching cubes keep these builds fast; the scene logic is the same
PERTURBED = (4, 8, 12)  # inputs of a 4-view scene; view 0 stays clean


def build(path, **kw):
    args = dict(source="procedural:mug", n_views=4, level=2, resolution=24, mesh_resolution=MESH_RES)
    args.update(kw)
    return build_scene(path, **args)


def file_hashes(root: Path):
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def png(path: Path) -> np.ndarray:
    """The exact stored pixels, uint8 ``[H, W, 4]`` (BGRA order is fine for comparisons)."""
    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED)


def scene_info(root: Path):
    return json.loads((root / "scene.json").read_text())


@pytest.fixture(scope="module")
def level2(tmp_path_factory):
    return build(tmp_path_factory.mktemp("l2"))


@pytest.fixture(scope="module")
def level0(tmp_path_factory):
    return build(tmp_path_factory.mktemp("l0"), level=0)


def test_same_seed_same_bytes_and_other_seed_other_inputs(level2, tmp_path):
    again = build(tmp_path / "again")
    assert file_hashes(again) == file_hashes(level2)
    other = build(tmp_path / "other", seed=7)
    for i in PERTURBED:
        assert not np.array_equal(png(other / f"images/train_{i:03d}.png"), png(level2 / f"images/train_{i:03d}.png"))
    for name in ("images/train_000.png", "images/test_001.png", "mesh.ply", "transforms_train.json"):
        assert (other / name).read_bytes() == (level2 / name).read_bytes()


def test_level0_is_the_clean_render_byte_for_byte(level0, level2):
    for i in (0, *PERTURBED):
        clean = (level2 / f"images/clean_{i:03d}.png").read_bytes()
        assert (level0 / f"images/train_{i:03d}.png").read_bytes() == clean
    info = scene_info(level0)["inconsistency"]
    assert info["level"] == 0 and all(v["psnr"] == 100.0 and v["lpips"] is None for v in info["per_view"])
    # view 0 stays clean at every level; held-out views never change
    assert (level2 / "images/train_000.png").read_bytes() == (level2 / "images/clean_000.png").read_bytes()
    unperturbed = {k: v for k, v in file_hashes(level2 / "images").items() if not k.startswith("train_")}
    assert unperturbed == {k: v for k, v in file_hashes(level0 / "images").items() if not k.startswith("train_")}


def test_scene_reads_back_with_rgba_inputs_and_the_measured_errors(level2):
    out = TransformsDataParserConfig(data=level2).setup().get_outputs("train")
    assert out.images.shape == (4, 24, 24, 3) and out.masks is not None
    test = TransformsDataParserConfig(data=level2).setup().get_outputs("test")
    assert len(test.cameras) == 12 + 8  # the other rig views, plus 8 off-orbit views
    info = scene_info(level2)
    assert info["test_views_off_rig"] == list(range(16, 24)) and len(info["test_views_on_rig"]) == 12
    assert info["version"] == SCENE_VERSION and info["seed"] == 42 and info["source"] == "procedural:mug"
    inc = info["inconsistency"]
    assert inc["kinds"] == ["geometric", "appearance", "pose"] and inc["level"] == 2
    assert [v["view"] for v in inc["per_view"] if v["perturbed"]] == list(PERTURBED)
    assert inc["mean_psnr"] < 40 and inc["means_over"] == "perturbed input views"


def _kind_scene(tmp_path, kind):
    return build(tmp_path / kind, kinds=kind)


def test_appearance_changes_color_only(tmp_path, level0):
    scene = _kind_scene(tmp_path, "appearance")
    for i in PERTURBED:
        a, b = png(scene / f"images/train_{i:03d}.png"), png(scene / f"images/clean_{i:03d}.png")
        assert np.array_equal(a[..., 3], b[..., 3])
        assert not np.array_equal(a[..., :3], b[..., :3])
    assert (scene / "transforms_train.json").read_bytes() == (level0 / "transforms_train.json").read_bytes()


def test_pose_writes_the_nominal_camera_but_renders_another(tmp_path, level0):
    scene = _kind_scene(tmp_path, "pose")
    assert (scene / "transforms_train.json").read_bytes() == (level0 / "transforms_train.json").read_bytes()
    frames = json.loads((scene / "transforms_train.json").read_text())["frames"]
    nominal = benchmark_cameras(24)
    for frame, i in zip(frames, (0, *PERTURBED)):
        c2w_gl = np.asarray(frame["transform_matrix"])[:3]
        assert np.allclose(c2w_gl[:, 3], nominal.c2w[i, :, 3].numpy(), atol=1e-6)
    errors = {v["view"]: v for v in scene_info(scene)["inconsistency"]["per_view"]}
    for i in PERTURBED:
        assert not np.array_equal(png(scene / f"images/train_{i:03d}.png"), png(scene / f"images/clean_{i:03d}.png"))
        assert max(abs(e) for e in errors[i]["pose_error_deg"].values()) > 0


def test_geometric_moves_the_silhouette(tmp_path, level0):
    scene = _kind_scene(tmp_path, "geometric")
    for i in PERTURBED:
        a, b = png(scene / f"images/train_{i:03d}.png"), png(scene / f"images/clean_{i:03d}.png")
        assert not np.array_equal(a[..., 3], b[..., 3])
    assert (scene / "transforms_train.json").read_bytes() == (level0 / "transforms_train.json").read_bytes()
    assert (scene / "mesh.ply").read_bytes() == (level0 / "mesh.ply").read_bytes()  # ground truth stays clean


def test_error_grows_with_level(tmp_path):
    means = []
    for level in (0, 1, 2, 3):
        inc = scene_info(build(tmp_path / f"l{level}", level=level, resolution=32))["inconsistency"]
        means.append((inc["mean_psnr"], inc["mean_lpips"]))
    psnrs, lpipses = zip(*means)
    assert psnrs[0] == 100.0 and list(psnrs) == sorted(psnrs, reverse=True) and len(set(psnrs)) == 4
    if lpipses[1] is not None:  # LPIPS weights installed
        assert lpipses[0] == 0.0 and list(lpipses) == sorted(lpipses) and len(set(lpipses)) == 4


@pytest.mark.parametrize("name", sorted(OBJECTS))
def test_procedural_meshes_are_closed_outward_and_inside_the_unit_box(name):
    mesh = object_mesh(name, 96)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # outward normals
    assert np.all(np.abs(mesh.bounds) <= 0.5)


def test_objects_have_the_topology_they_are_meant_to_stress():
    genus = {name: (2 - object_mesh(name, 96).euler_number) // 2 for name in OBJECTS}
    assert genus == {"mug": 1, "knot": 1, "chair": 4, "bowl": 0, "blocks": 0, "lamp": 0, "robot": 0}


@needs_gso
@pytest.mark.parametrize("name", ["alarm", "lion"])
def test_gso_mesh_aligns_with_the_renders(name):
    cameras = syncdreamer_rig(128, pixel_offset=0.5)
    renders = gso.load_renders(GSO_ROOT, name, 128)
    iou = gso.silhouette_iou(gso.load_mesh(GSO_ROOT, name), cameras, renders[..., 3])
    assert min(iou) >= 0.9


@needs_gso
def test_gso_scene_uses_the_renders_and_warps_them(tmp_path):
    scene = build_scene(tmp_path / "alarm", "gso:alarm", level=2, resolution=32, data_root=GSO_ROOT)
    info = scene_info(scene)
    assert info["alignment_iou"]["min"] >= 0.9 and info["test_views"] == [1, 2, 3, 5, 6, 7, 9, 10, 11, 13, 14, 15]
    for i in PERTURBED:
        a, b = png(scene / f"images/train_{i:03d}.png"), png(scene / f"images/clean_{i:03d}.png")
        assert not np.array_equal(a[..., 3], b[..., 3])  # the alpha follows the warp
    assert (scene / "images/train_000.png").read_bytes() == (scene / "images/clean_000.png").read_bytes()
    every_view = build_scene(tmp_path / "all", "gso:alarm", n_views=16, level=1, resolution=24, data_root=GSO_ROOT)
    assert not (every_view / "transforms_test.json").exists()  # nothing held out


@needs_gso
def test_gso_scene_can_hold_out_views_off_the_rig(tmp_path):
    """With every rig view an input, the off-rig views (the mesh with a texture baked from the renders) are
    the held-out ones; the baked texture reproduces the rig's own renders closely."""
    from va_plugin.eval.image import psnr

    scene = build_scene(tmp_path / "off", "gso:alarm", n_views=16, level=0, resolution=32, data_root=GSO_ROOT,
                        gso_off_rig=True)
    info = scene_info(scene)
    assert info["test_views"] == info["test_views_off_rig"] == list(range(16, 24))
    alphas = [png(scene / f"images/test_{i:03d}.png")[..., 3] / 255.0 for i in info["test_views"]]
    assert all(0.05 < float(a.mean()) < 0.6 for a in alphas)  # the object, framed
    src = load_source("gso:alarm", 32, GSO_ROOT, gso_off_rig=True)
    rig = benchmark_cameras(32, extra=False)
    baked, real = src.baked_renderer(rig).render(rig, 3), src.images[3]
    assert psnr(baked[..., :3] * baked[..., 3:] + 1 - baked[..., 3:],
                real[..., :3] * real[..., 3:] + 1 - real[..., 3:]) > 24


def test_image_source_pose_error_matches_a_true_rerender():
    """The GSO pose path (reprojection of a fixed render through the mesh's depth), checked where the
    truth is known: a procedural object's rig renders reprojected vs. rendered from the moved camera."""
    src = load_source("procedural:mug", 64, mesh_resolution=MESH_RES)
    cameras = benchmark_cameras(64, extra=False)
    renders = ImageSource("mug-as-images", "", np.stack([src.clean(cameras, i) for i in range(16)]),
                          src.ground_truth)
    spec = InconsistencySpec("pose", 3, 42)
    gains = []
    for i in PERTURBED:
        p = draw_perturbation(spec, i)
        truth = on_white(src.perturbed(cameras, i, p))
        reprojected = on_white(renders.perturbed(cameras, i, p))
        gains.append(psnr(reprojected, truth) - psnr(on_white(renders.clean(cameras, i)), truth))
    assert min(gains) > 0 and np.mean(gains) > 1.5


def test_missing_gso_root_and_unknown_names_are_clear(tmp_path):
    with pytest.raises(DataError, match="GSO data root not found"):
        build_scene(tmp_path / "x", "gso:alarm", data_root=tmp_path / "nowhere", resolution=24)
    with pytest.raises(ConfigError, match="unknown procedural object"):
        build(tmp_path / "y", source="procedural:teapot")
    with pytest.raises(ConfigError, match="level"):
        build(tmp_path / "z", level=4)
    with pytest.raises(ConfigError, match="kind"):
        build(tmp_path / "z", kinds="geometric,lighting")


@needs_spot
def test_spot_loads_textured_and_renders():
    textured = load_textured_mesh(SPOT)
    gt = textured.ground_truth
    assert gt.is_watertight and np.isclose(np.ptp(gt.bounds, axis=0).max(), 1.0) and np.allclose(gt.bounds.sum(0), 0)
    rgba = MeshRenderer(textured.render_mesh, textured.albedo).render(benchmark_cameras(48), 4)
    on = rgba[..., 3] > 0.99
    assert 0.1 < on.mean() < 0.6
    luminance = rgba[..., :3].mean(-1)[on]
    assert luminance.min() < 0.2 and luminance.max() > 0.7  # black patches and white hide: the texture is used


def test_cli_builds_a_scene_with_a_figure_and_refuses_bad_input(tmp_path, capsys):
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        import build_scene as cli
    finally:
        sys.path.pop(0)
    figure = tmp_path / "fig.png"
    args = ["--out", str(tmp_path / "s"), "--resolution", "24", "--mesh-resolution", str(MESH_RES)]
    assert cli.main(args + ["--figure", str(figure)]) == 0
    assert png(figure).shape == (48, 96, 3)
    assert cli.main(["--list"]) == 0
    assert "knot" in capsys.readouterr().out
    for bad in (["--level", "9"], ["--kinds", "wobble"], ["--source", "procedural:nope"], ["--views", "x"]):
        assert cli.main(args + bad) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("error:") and "\n" not in err


def test_default_scene_is_the_mug_at_level_2_and_old_caches_are_rebuilt(tmp_path):
    cache = tmp_path / "default"
    cache.mkdir()
    (cache / "scene.json").write_text(json.dumps({"resolution": 24, "source": "procedural:mug"}))  # version 1
    ensure_default_scene(cache, resolution=24)
    info = scene_info(cache)
    assert info["version"] == SCENE_VERSION and info["inconsistency"]["level"] == 2
    assert info["inconsistency"]["kinds"] == ["geometric", "appearance", "pose"]
    stamp = (cache / "scene.json").stat().st_mtime_ns
    ensure_default_scene(cache, resolution=24)
    assert (cache / "scene.json").stat().st_mtime_ns == stamp  # a current cache is reused
