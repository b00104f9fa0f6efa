"""Meshes in the conventions of 3D tools: GLB and OBJ +Y up, standing on y = 0, centred on the vertical axis,
the front (+x, the generator's input view) towards +Z; PLY left in the training frame; the transform recorded."""

import json

import numpy as np
import pytest
import trimesh
from texture_cases import SIX_SIDES, TEXTURE, cube_views, smooth_color

from va_plugin.errors import VAError
from va_plugin.export.atlas import simplify_for_texture
from va_plugin.export.frame import UPRIGHT_ROTATION, check_frame, frame_record_path, frame_transform
from va_plugin.export.mesh import write_mesh
from va_plugin.export.texture import bake_texture
from va_plugin.export.writing import write_textured_mesh

TALL, WIDE, DEEP = 0.9, 0.5, 0.3
"""Extents of the test shape in the training frame: along z (up), y and x."""


def asymmetric_shape() -> trimesh.Trimesh:
    """A tall box off the origin with a bump on its +x side (the side the input view sees), z up."""
    body = trimesh.creation.box(extents=(DEEP, WIDE, TALL))
    bump = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    bump.apply_translation((DEEP / 2 + 0.05, 0.1, 0.2))
    shape = trimesh.util.concatenate([body, bump])
    shape.apply_translation((0.07, -0.11, 0.05))
    shape.visual.vertex_colors = np.tile([200, 30, 30, 255], (len(shape.vertices), 1)).astype(np.uint8)
    return shape


def load(path) -> trimesh.Trimesh:
    return trimesh.load(path, force="mesh", process=False)


def check_upright(loaded: trimesh.Trimesh, tall: float, wide: float, deep: float):
    low, high = loaded.bounds
    assert abs(low[1]) < 1e-6, "the lowest vertex sits at y = 0"
    assert np.allclose((low + high)[[0, 2]] / 2, 0.0, atol=1e-6), "the bounding box is centred on the y axis"
    assert np.allclose(high - low, [wide, tall, deep], atol=1e-5), "up (training z) is y; training x is z"


def test_the_upright_transform_is_a_proper_rotation_and_a_shift():
    assert np.isclose(np.linalg.det(UPRIGHT_ROTATION), 1.0)
    transform = frame_transform(asymmetric_shape().vertices)
    assert np.allclose(transform[:3, :3] @ [0, 0, 1], [0, 1, 0])  # +Z up -> +Y up
    assert np.allclose(transform[:3, :3] @ [1, 0, 0], [0, 0, 1])  # the input view's side -> glTF's front, +Z
    assert np.allclose(frame_transform(asymmetric_shape().vertices, "training"), np.eye(4))
    with pytest.raises(VAError, match="--frame must be one of upright, training"):
        check_frame("z-up")


@pytest.mark.parametrize("suffix", [".glb", ".obj"])
def test_glb_and_obj_stand_upright_and_ply_keeps_the_training_frame(tmp_path, suffix):
    shape = asymmetric_shape()
    path = write_mesh(shape, tmp_path / f"shape{suffix}")
    ply = write_mesh(shape, tmp_path / "trained.ply")
    loaded = load(path)
    check_upright(loaded, TALL, WIDE, DEEP + 0.1)
    # the bump on training +x ends on the front, +Z
    assert loaded.vertices[:, 2].max() - loaded.vertices[:, 2].min() > DEEP + 0.05
    front = loaded.vertices[:, 2] > loaded.bounds[1][2] - 1e-6
    assert front.sum() == 4 and np.ptp(loaded.vertices[front, 0]) < 0.11
    # outward normals: the winding survived (a mirror would turn the volume negative)
    assert loaded.volume > 0 and np.isclose(loaded.volume, shape.volume, rtol=1e-4)
    record = json.loads(frame_record_path(path).read_text())
    assert record["frame"] == "upright" and record["up"] == "+y"
    to_file, to_training = np.array(record["training_to_file"]), np.array(record["file_to_training"])
    assert np.allclose(shape.vertices @ to_file[:3, :3].T + to_file[:3, 3], loaded.vertices, atol=1e-6)
    assert np.allclose(loaded.vertices @ to_training[:3, :3].T + to_training[:3, 3], shape.vertices, atol=1e-6)
    assert np.array_equal(load(ply).vertices, shape.vertices.astype(np.float32)), "PLY stays as trained"
    assert not frame_record_path(ply).exists()


def test_the_training_frame_keeps_the_vertices(tmp_path):
    shape = asymmetric_shape()
    path = write_mesh(shape, tmp_path / "shape.glb", frame="training")
    assert np.allclose(load(path).vertices, shape.vertices, atol=1e-6)
    record = json.loads(frame_record_path(path).read_text())
    assert record["up"] == "+z" and np.allclose(record["training_to_file"], np.eye(4))


@pytest.fixture(scope="module")
def baked():
    box = trimesh.creation.box(extents=(0.35, 0.45, 0.7))
    box.apply_translation((0.02, 0.03, -0.04))
    views = cube_views(box, SIX_SIDES["azimuths"], SIX_SIDES["elevations"])
    return bake_texture(box, views, size=TEXTURE)[0]


def texture_error(loaded: trimesh.Trimesh, to_training: np.ndarray) -> float:
    """Mean color error at face centroids: the texture at the centroid's UV against the known color of the
    centroid's training-frame position."""
    image = loaded.visual.material
    image = np.asarray(image.to_simple().image if hasattr(image, "to_simple") else image.image, np.float32)
    image = image[..., :3] / 255
    uv = loaded.visual.uv[loaded.faces].mean(1)
    centres = loaded.vertices[loaded.faces].mean(1) @ to_training[:3, :3].T + to_training[:3, 3]
    size = image.shape[0]
    cols = np.clip((uv[:, 0] * size).astype(int), 0, size - 1)
    rows = np.clip(((1 - uv[:, 1]) * size).astype(int), 0, size - 1)
    return float(np.abs(image[rows, cols] - smooth_color(centres)).mean())


@pytest.mark.parametrize("suffix", [".glb", ".obj"])
def test_the_textured_mesh_stands_upright_and_its_texture_still_maps(tmp_path, baked, suffix):
    write_textured_mesh(baked, tmp_path / f"box{suffix}")
    loaded = load(tmp_path / f"box{suffix}")
    check_upright(loaded, 0.7, 0.45, 0.35)
    to_training = np.array(json.loads((tmp_path / "box_frame.json").read_text())["file_to_training"])
    error = texture_error(loaded, to_training)
    assert error < 0.05, error
    # the same check with the transform forgotten fails, so it would catch a texture that no longer maps
    assert texture_error(loaded, np.eye(4)) > 2 * error + 0.05
    assert len(loaded.faces) == len(baked.faces)


def test_decimation_reaches_the_asked_face_count():
    sphere = trimesh.creation.icosphere(subdivisions=5)  # 20480 faces
    sphere.vertices += np.random.default_rng(0).normal(0.0, 0.002, sphere.vertices.shape)
    for target in (2000, 5000):
        assert abs(len(simplify_for_texture(sphere, target).faces) - target) <= 0.01 * target
    assert simplify_for_texture(sphere, 10 ** 6) is sphere and simplify_for_texture(sphere, 0) is sphere
    with pytest.raises(VAError, match="--faces must be 0"):
        simplify_for_texture(sphere, 3)
