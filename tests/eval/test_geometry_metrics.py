"""Chamfer distance, F-score, volume IoU and surface sampling on meshes with known answers."""

import numpy as np
import pytest
import trimesh

from va_plugin.eval import chamfer_distance, f_score, geometry_metrics, sample_surface, volume_iou


@pytest.fixture(scope="module")
def sphere():
    """Sphere of diameter 1 (the project's unit bounding box), 5120 faces."""
    return trimesh.creation.icosphere(subdivisions=4, radius=0.5)


def _shifted(mesh, dx):
    out = mesh.copy()
    out.apply_translation([dx, 0.0, 0.0])
    return out


def _box(lo, hi):
    return trimesh.creation.box(bounds=[lo, hi])


def test_sample_surface_is_deterministic_and_on_the_surface():
    box = _box([0, 0, 0], [1, 2, 4])
    a, b = sample_surface(box, 2000, seed=7), sample_surface(box, 2000, seed=7)
    assert a.shape == (2000, 3)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, sample_surface(box, 2000, seed=8))
    on_face = np.isclose(a, 0.0, atol=1e-9) | np.isclose(a, [1, 2, 4], atol=1e-9)
    assert on_face.any(axis=1).all()


def test_sample_surface_is_area_weighted():
    # Box 1 x 2 x 4: the two x-faces (2*4 each) hold 16/28 of the area, z-faces 4/28.
    pts = sample_surface(_box([0, 0, 0], [1, 2, 4]), 40_000, seed=0)
    on_x = np.isclose(pts[:, 0], 0.0) | np.isclose(pts[:, 0], 1.0)
    on_z = np.isclose(pts[:, 2], 0.0) | np.isclose(pts[:, 2], 4.0)
    assert on_x.mean() == pytest.approx(16 / 28, abs=0.01)
    assert on_z.mean() == pytest.approx(4 / 28, abs=0.01)


def test_mesh_against_itself(sphere):
    m = geometry_metrics(sphere, sphere, n_samples=100_000, resolution=32)
    # Independent samplings of one surface sit ~0.5*sqrt(area/n) apart (2-d Poisson
    # nearest-neighbour mean): ~0.0028 here. Exactly 0 would mean shared samples.
    floor = 0.5 * np.sqrt(sphere.area / 100_000)
    assert 0.0 < m["chamfer_distance"] < 0.003
    assert m["chamfer_distance"] == pytest.approx(floor, rel=0.1)
    assert m["f_score"] > 0.999
    assert m["volume_iou"] == 1.0


def test_shifted_sphere(sphere):
    # Shifting a sphere by d moves a surface point at direction u by ~d*|u_x| off the
    # other sphere; |u_x| is uniform on [0, 1] over a sphere, so the Chamfer distance
    # (mean of one-way means) is ~d/2 and the share within t of the other is ~t/d.
    moved = _shifted(sphere, 0.05)
    assert chamfer_distance(sphere, moved, n_samples=50_000) == pytest.approx(0.025, rel=0.1)
    assert f_score(sphere, moved, threshold=0.02, n_samples=50_000) == pytest.approx(0.4, abs=0.03)


def test_half_overlapping_cubes_have_iou_one_third():
    a, b = _box([0, 0, 0], [1, 1, 1]), _box([0.5, 0, 0], [1.5, 1, 1])
    for res in (32, 64):
        assert volume_iou(a, b, resolution=res) == pytest.approx(1 / 3, abs=1.5 / res)
    assert volume_iou(a, b, resolution=48, bound=[[-1, -1, -1], [2, 2, 2]]) == pytest.approx(1 / 3, abs=3 / 48)
    assert volume_iou(a, b, resolution=48, bound=2.0) == pytest.approx(1 / 3, abs=4 / 48)


def test_disjoint_meshes_score_zero():
    a, b = _box([0, 0, 0], [1, 1, 1]), _box([2, 0, 0], [3, 1, 1])
    m = geometry_metrics(a, b, n_samples=5000, resolution=16)
    assert m["volume_iou"] == 0.0 and m["f_score"] == 0.0
    assert m["chamfer_distance"] > 1.0


def test_geometry_metrics_agree_with_the_single_functions(sphere):
    moved = _shifted(sphere, 0.03)
    m = geometry_metrics(sphere, moved, n_samples=10_000, seed=3, threshold=0.02, resolution=24, bound=1.0)
    assert m["chamfer_distance"] == chamfer_distance(sphere, moved, n_samples=10_000, seed=3)
    assert m["f_score"] == f_score(sphere, moved, threshold=0.02, n_samples=10_000, seed=3)
    assert m["volume_iou"] == volume_iou(sphere, moved, resolution=24, bound=1.0)
    assert m["params"] == {"n_samples": 10_000, "seed": 3, "threshold": 0.02, "resolution": 24, "bound": 1.0}


def test_empty_or_invalid_meshes_raise_clear_errors(sphere):
    empty = trimesh.Trimesh()
    for fn in (chamfer_distance, f_score, volume_iou):
        with pytest.raises(ValueError, match="pred_mesh is empty"):
            fn(empty, sphere)
        with pytest.raises(ValueError, match="gt_mesh is empty"):
            fn(sphere, empty)
    with pytest.raises(ValueError, match="empty"):
        sample_surface(empty, 10, seed=0)
    with pytest.raises(TypeError, match=r"trimesh\.Trimesh"):
        chamfer_distance(trimesh.Scene(), sphere)
    with pytest.raises(ValueError, match="bound"):
        volume_iou(sphere, sphere, bound=[[0, 0, 0], [0, 1, 1]])


def test_open_surfaces_warn_and_an_empty_grid_raises():
    square = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], faces=[[0, 1, 2], [0, 2, 3]])
    with pytest.warns(UserWarning, match="not watertight"):
        volume_iou(square, square, resolution=8, bound=1.0)
    cube = _box([0, 0, 0], [1, 1, 1])
    with pytest.raises(ValueError, match="any grid point"):
        volume_iou(cube, cube, resolution=8, bound=[[5, 5, 5], [6, 6, 6]])


def test_small_holes_barely_change_the_volume(sphere):
    # Parity ray casting with a 3-ray vote: ~1% of faces removed costs ~1% IoU.
    keep = np.ones(len(sphere.faces), dtype=bool)
    keep[::97] = False
    holed = sphere.copy()
    holed.update_faces(keep)
    with pytest.warns(UserWarning, match="not watertight"):
        assert volume_iou(holed, sphere, resolution=32) > 0.97
