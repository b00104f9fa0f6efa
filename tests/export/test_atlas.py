"""UV atlases: simplification before the unwrap, the unwrap and its texels, chart padding."""

import numpy as np
import pytest
import trimesh
from texture_cases import cube

from va_plugin.errors import VAError
from va_plugin.export.atlas import dilate, rasterize_uv, simplify_for_texture, unwrap


def test_the_unwrap_packs_every_face_into_one_atlas_whose_texels_lie_on_the_mesh():
    mesh = cube()
    vertices, faces, uv, source = unwrap(mesh, 64)
    assert len(faces) == len(mesh.faces) and uv.min() >= 0 and uv.max() <= 1
    np.testing.assert_array_equal(vertices, np.asarray(mesh.vertices, np.float32)[source])
    face, bary = rasterize_uv(uv, faces, 64)
    covered = face >= 0
    assert covered.mean() > 0.3 and face.max() < len(faces)
    assert np.allclose(bary[covered].sum(-1), 1.0, atol=1e-5) and bary[covered].min() > -1e-5
    with pytest.raises(VAError, match="no faces"):
        unwrap(trimesh.Trimesh(np.zeros((3, 3)), np.zeros((0, 3), int)), 64)


def test_a_dense_mesh_is_simplified_and_keeps_its_shape():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.35)  # 20480 faces
    simple = simplify_for_texture(sphere, 2000)
    assert 1000 < len(simple.faces) <= 2000
    radius = np.linalg.norm(simple.vertices, axis=-1)
    assert np.abs(radius - 0.35).max() < 0.01  # the shape is kept
    assert simplify_for_texture(sphere, 0) is sphere and simplify_for_texture(sphere, 10**6) is sphere
    with pytest.raises(VAError, match="--faces must be 0"):
        simplify_for_texture(sphere, 2)


def test_dilation_pads_charts_and_fills_the_rest():
    image = np.zeros((8, 8, 3), np.float32)
    filled = np.zeros((8, 8), bool)
    image[3, 3], filled[3, 3] = 0.7, True
    out = dilate(image, filled, iterations=2)
    assert np.allclose(out[1:6, 1:6], 0.7) and np.allclose(out, 0.7)
