"""Benchmark scenes in each generator's layout: the object rendered on the rig, written with the generator's
file name, size, background and tile order, and read back by the format's reader; a perfect mesh scores
CD 0 and IoU 1 once brought into the training frame."""

import json

import numpy as np
import pytest
import trimesh

from va_plugin.bench.scenes.generator_scene import (
    build_generator_scene,
    clean_view_ids,
    input_name,
    object_scale,
    score_generator_run,
)
from va_plugin.data.dataparsers import resolve_dataparser
from va_plugin.data.images import read_image
from va_plugin.data.rigfile import builtin_rigs, normal_files
from va_plugin.raycast import MeshRenderer

TILE = 24


def read(path, fmt):
    return resolve_dataparser(path, fmt).setup().get_outputs("train")


@pytest.mark.parametrize("fmt, level", [("hunyuan3d-std", 0), ("crm", 2), ("mvadapter", 2), ("era3d", 0)])
def test_scenes_are_written_as_the_generator_writes_them(fmt, level, tmp_path):
    spec = builtin_rigs()[fmt]
    path = build_generator_scene(tmp_path, fmt, "procedural:blocks", level=level, tile=TILE,
                                 mesh_resolution=48)
    assert path.name == input_name(spec) and (tmp_path / "mesh.ply").is_file()
    info = json.loads((tmp_path / "scene.json").read_text())
    assert info["rig"] == fmt and info["level"] == level and info["tile"] == TILE
    if spec.layout != "folder":
        image = read_image(path)
        rows, columns = (spec.rows, spec.columns) if spec.layout == "grid" else (1, spec.count)
        assert image.shape[:2] == (rows * TILE, columns * TILE)
        corner = image[0, 0, :3]
        assert np.allclose(corner, spec.background, atol=0.02)  # the generator's background
    train = read(path, fmt)
    assert len(train) == spec.count
    assert np.mean(train.metadata["silhouette_iou"]) > (0.8 if level == 0 else 0.7)


def test_objects_shrink_to_fit_narrow_views_and_the_input_view_stays_clean():
    rigs = builtin_rigs()
    assert object_scale(rigs["hunyuan3d-std"]) == 1.0
    assert object_scale(rigs["era3d"]) == pytest.approx(1.0 / 1.2)
    assert clean_view_ids(rigs["crm"]) == (5, 1, 4)  # front, then the bottom and top views
    assert clean_view_ids(rigs["sv3d"]) == (20,)  # the last frame is the input
    assert clean_view_ids(rigs["hunyuan3d-std"]) == (0,)


def test_a_perfect_mesh_scores_zero_chamfer(tmp_path):
    path = build_generator_scene(tmp_path, "four-view-grid", "procedural:blocks", tile=TILE, mesh_resolution=48)
    meta = read(path, "four-view-grid").metadata
    truth = trimesh.load(tmp_path / "mesh.ply", process=False)
    move = meta["rig_to_training"]
    truth.apply_translation(-np.asarray(move["centre"]))
    truth.apply_scale(move["scale"])
    truth.export(tmp_path / "pred.ply")
    scores = score_generator_run(tmp_path / "pred.ply", tmp_path, move, n_samples=5000, resolution=32)
    assert scores["cd"] < 0.02 and scores["iou"] > 0.95  # sampling noise of 5000 points
    shifted = truth.copy()
    shifted.apply_translation((0.3, 0.0, 0.0))
    shifted.export(tmp_path / "off.ply")
    off = score_generator_run(tmp_path / "off.ply", tmp_path, move, n_samples=5000, resolution=32)
    assert off["iou"] < 0.8 and off["cd"] > 3 * scores["cd"]


@pytest.mark.parametrize("fmt, level", [("era3d", 0), ("wonder3dpp-ortho", 2)])
def test_normal_maps_are_written_in_the_generators_frame_and_read_back_as_the_surfaces(fmt, level, tmp_path):
    path = build_generator_scene(tmp_path, fmt, "procedural:blocks", level=level, tile=TILE, mesh_resolution=48)
    assert json.loads((tmp_path / "scene.json").read_text())["normal_maps"]
    train = read(path, fmt)
    normals = train.metadata["normals"].numpy()  # world axes, zero off the object
    truth = trimesh.load(tmp_path / "mesh.ply", process=False)
    move = train.metadata["rig_to_training"]
    truth.apply_translation(-np.asarray(move["centre"]))
    truth.apply_scale(move["scale"])
    renderer = MeshRenderer(truth, lambda hits: np.zeros((len(hits.points), 3), np.float32))
    spec = builtin_rigs()[fmt]
    cosines = {}
    for k in range(spec.count):
        expected = renderer.normals(train.cameras, k)
        both = (expected[..., 3] > 0) & (np.abs(normals[k]).sum(-1) > 0)
        assert both.mean() > 0.1
        cosines[k] = float(np.median((expected[..., :3] * normals[k]).sum(-1)[both]))
    clean = clean_view_ids(spec)
    assert min(cosines[k] for k in clean) > 0.99  # only the 8-bit encoding between them
    assert all(c > 0.9 for c in cosines.values())  # level 2: views from a slightly wrong pose
    if level == 0:
        assert min(cosines.values()) > 0.99
    # stored in the front camera's axes: read as the side view's own axes, a side view's normals are wrong
    side = max(range(spec.count), key=lambda k: abs(np.sin(np.radians(spec.azimuths[k]))))
    stored = read_image(normal_files(spec, path)[side])
    as_own = (stored[..., :3] * 2.0 - 1.0) * np.array([1.0, -1.0, -1.0]) @ train.cameras.c2w[side, :, :3].numpy().T
    expected = renderer.normals(train.cameras, side)
    both = (expected[..., 3] > 0) & (stored[..., 3] > 0.5)
    assert np.median((expected[..., :3] * as_own).sum(-1)[both]) < 0.5
