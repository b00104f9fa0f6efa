"""Mesh extraction helpers: enclosed cavities filled (and open ones left alone), the sphere bound, and
ngp's log-density smoothing against hand values."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from va_plugin.export.mesh import extract_mesh, fill_enclosed_cavities, sphere_distance_grid


def _shell(size=12, wall=2, open_top=False):
    """A cube's walls (inside -1) around an empty core (+1) in an empty grid (+1)."""
    values = np.ones((size, size, size), np.float32)
    values[2:-2, 2:-2, 2:-2] = -1.0
    values[2 + wall:-2 - wall, 2 + wall:-2 - wall, 2 + wall:-2 - wall] = 0.5
    if open_top:  # a cup: the core reaches the grid's border through a hole in the top wall
        values[2 + wall:-2 - wall, 2 + wall:-2 - wall, -2 - wall:] = 0.5
    return values


def test_an_enclosed_core_is_filled_and_an_open_one_is_not():
    closed = _shell()
    filled = fill_enclosed_cavities(closed)
    assert (filled[4:-4, 4:-4, 4:-4] < 0).all()  # the core became inside
    assert np.array_equal(filled[closed < 0], closed[closed < 0]) and (filled[0] == 1.0).all()  # rest untouched
    assert filled[6, 6, 6] == pytest.approx(-0.5 - 1e-6)
    cup = _shell(open_top=True)
    assert np.array_equal(fill_enclosed_cavities(cup), cup)
    assert np.array_equal(fill_enclosed_cavities(np.ones((4, 4, 4), np.float32)), np.ones((4, 4, 4)))


def test_sphere_distance_grid():
    grid = sphere_distance_grid(3, 1.0, 0.5)  # axis -1, 0, 1
    assert grid[1, 1, 1] == pytest.approx(-0.5) and grid[2, 1, 1] == pytest.approx(0.5)
    assert grid[0, 0, 0] == pytest.approx(math.sqrt(3) - 0.5)


class _DensityBall(torch.nn.Module):
    """A model whose density is 100 inside radius 0.4 and 0 outside, with ngp's mesh hooks."""

    def __init__(self, smoothing=0.0, fill=False):
        super().__init__()
        from types import SimpleNamespace

        from va_plugin.models.ngp import NGPModel, NGPModelConfig

        self.anchor = torch.nn.Parameter(torch.zeros(1))
        self.config = NGPModelConfig(density_threshold=10.0, mesh_smoothing=smoothing)
        self.scene = SimpleNamespace(scene_radius=1.0)
        self.fill_mesh_cavities = fill
        self.mesh_field_lipschitz = None  # a density, not a signed distance
        self.prepare_mesh_grid = NGPModel.prepare_mesh_grid.__get__(self)

    def mesh_field(self, points):
        density = torch.where(points.norm(dim=-1) < 0.4, 100.0, 0.0)
        return self.config.density_threshold - density


def test_ngp_log_density_smoothing_hand_values_and_mesh():
    from va_plugin.models.ngp import LOG_DENSITY_FLOOR

    model = _DensityBall(smoothing=0.0)
    grid = np.full((5, 5, 5), 10.0 - 100.0, np.float32)
    assert np.array_equal(model.prepare_mesh_grid(grid, 0.1), grid)  # off: unchanged
    model = _DensityBall(smoothing=0.1)
    out = model.prepare_mesh_grid(grid, 0.1)  # a constant density stays constant under smoothing
    assert np.allclose(out, -math.tanh(0.5 * math.log((100.0 + LOG_DENSITY_FLOOR) / 10.0)), atol=1e-5)
    empty = model.prepare_mesh_grid(np.full((5, 5, 5), 10.0, np.float32), 0.1)
    assert np.allclose(empty, -math.tanh(0.5 * math.log(LOG_DENSITY_FLOOR / 10.0)), atol=1e-5)  # > 0: outside
    at_threshold = model.prepare_mesh_grid(np.zeros((5, 5, 5), np.float32), 0.1)
    assert np.allclose(at_threshold, -math.tanh(0.5 * math.log1p(LOG_DENSITY_FLOOR / 10.0)), atol=1e-6)
    # the smoothed ball keeps its radius (the level set of a symmetric step moves little)
    for smoothing in (0.0, 0.05):
        mesh = extract_mesh(_DensityBall(smoothing=smoothing), resolution=48, with_color=False)
        radius = np.linalg.norm(np.asarray(mesh.vertices), axis=-1)
        assert abs(float(radius.mean()) - 0.4) < 0.015, smoothing


def _sdf_scene(points):
    """A sphere (r 0.35 at x = -0.3), a plate 0.04 thick (thinner than three cells of a 48^3 grid) and a
    box reaching out of the unit sphere: what the banded grid must keep."""
    ball = (points - torch.tensor([-0.3, 0.0, 0.0])).norm(dim=-1) - 0.35
    q = (points - torch.tensor([0.35, 0.1, 0.0])).abs() - torch.tensor([0.25, 0.02, 0.3])
    plate = q.clamp_min(0).norm(dim=-1) + q.max(-1).values.clamp_max(0)
    q = (points - torch.tensor([0.0, -0.75, 0.0])).abs() - torch.tensor([0.2, 0.5, 0.2])
    box = q.clamp_min(0).norm(dim=-1) + q.max(-1).values.clamp_max(0)
    return torch.minimum(torch.minimum(ball, plate), box)


@pytest.mark.parametrize("resolution", [48, 61])
def test_the_banded_distance_grid_gives_the_full_grids_mesh(resolution):
    from skimage.measure import marching_cubes

    from va_plugin.export.mesh import sample_distance_grid, sample_grid

    evaluated = []

    def fn(points):
        evaluated.append(len(points))
        return _sdf_scene(points)

    cpu = torch.device("cpu")
    full = sample_grid(_sdf_scene, resolution, 1.0, cpu)
    band = sample_distance_grid(fn, resolution, 1.0, 1.0, cpu, lipschitz=1.5)
    assert sum(evaluated) < 0.6 * resolution**3  # most of the grid is skipped
    sphere = sphere_distance_grid(resolution, 1.0, 1.0)
    a, b = np.maximum(full, sphere), np.maximum(band, sphere)  # as extract_mesh sees them
    assert np.array_equal(a < 0, b < 0)  # every sign kept
    # every value marching cubes reads (the corners of cells where the sign changes) is the field's own
    mixed = np.zeros_like(a, bool)
    for i in (0, 1):
        for j in (0, 1):
            for k in (0, 1):
                cell = a[i:resolution - 1 + i, j:resolution - 1 + j, k:resolution - 1 + k] < 0
                mixed[:-1, :-1, :-1] |= cell
    inside = np.minimum.reduce([a[i:resolution - 1 + i, j:resolution - 1 + j, k:resolution - 1 + k] < 0
                                for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    crossing = mixed[:-1, :-1, :-1] & ~inside
    corners = np.zeros_like(a, bool)
    for i in (0, 1):
        for j in (0, 1):
            for k in (0, 1):
                corners[i:resolution - 1 + i, j:resolution - 1 + j, k:resolution - 1 + k] |= crossing
    assert corners.sum() > 100
    np.testing.assert_allclose(a[corners], b[corners], rtol=0, atol=1e-6)  # batches round differently
    va, fa, _, _ = marching_cubes(a, 0.0)
    vb, fb, _, _ = marching_cubes(b, 0.0)
    assert np.array_equal(fa, fb)
    np.testing.assert_allclose(va, vb, rtol=0, atol=1e-4)


def test_the_bound_is_what_keeps_a_ball_between_block_corners():
    # a ball smaller than a block, around the grid point at a block's centre: only the fine pass finds it,
    # and it runs there only when the claimed bound lets the ball's field dip below zero between corners
    from va_plugin.export.mesh import BLOCK, sample_distance_grid, sample_grid

    cpu = torch.device("cpu")
    n = 49
    centre = -1.0 + (12 * BLOCK + BLOCK // 2) * 2.0 / (n - 1)
    ball = lambda p: (p - centre).norm(dim=-1) - 0.03
    full = sample_grid(ball, n, 1.0, cpu)
    assert (full < 0).sum() == 1
    assert np.array_equal(sample_distance_grid(ball, n, 1.0, 1.0, cpu, lipschitz=1.0) < 0, full < 0)
    assert not (sample_distance_grid(ball, n, 1.0, 1.0, cpu, lipschitz=0.1) < 0).any()  # a false bound loses it
