"""The silhouette support test: a sphere's exact masks are supported everywhere; a view whose mask is
shifted (a generator's pose drift) or grown (shape drift) is not; too few views give no verdict."""

import numpy as np
import pytest
import torch

from va_plugin.analysis.consistency import silhouette_support
from va_plugin.data.rigs import orbit_cameras
from va_plugin.rays import near_far_from_sphere


def _sphere_masks(cameras, radius=0.3, centre=(0.0, 0.0, 0.0)):
    masks = []
    for view in range(len(cameras)):
        index, rows, cols = cameras.pixel_grid(view)
        origins, directions = cameras.generate_rays(index, rows, cols)
        _, _, hits = near_far_from_sphere(origins - torch.tensor(centre), directions, radius)
        masks.append(hits.reshape(cameras.height, cameras.width))
    return torch.stack(masks)


def test_exact_masks_are_consistent_and_a_shifted_view_is_not():
    cameras = orbit_cameras([0, 90, 180, 270], 30.0, resolution=64)
    masks = _sphere_masks(cameras)
    result = silhouette_support(cameras, masks, scene_radius=1.0, tolerance_px=1)
    assert result is not None and result.consistent and result.worst == 0.0
    assert silhouette_support(cameras, masks, scene_radius=1.0).worst < 0.01  # no tolerance: rounding at the rim
    assert result.pixels == [int(m.sum()) for m in masks]  # small masks: every foreground pixel tested
    shifted = masks.clone()
    shifted[1] = torch.roll(masks[1], shifts=4, dims=1)  # view 1 seen 4 px to the side
    drifted = silhouette_support(cameras, shifted, scene_radius=1.0, tolerance_px=1)
    assert not drifted.consistent and drifted.unsupported[1] > 0.02
    summary = drifted.as_dict()
    assert summary["consistent"] is False and len(summary["views"]) == 4


def test_a_view_whose_shape_grew_is_caught():
    cameras = orbit_cameras([0, 90, 180, 270], 30.0, resolution=64)
    masks = _sphere_masks(cameras)
    masks[2] = _sphere_masks(cameras, radius=0.36)[2]  # view 2 drew the object 20% too large
    result = silhouette_support(cameras, masks, scene_radius=1.0, tolerance_px=1)
    assert not result.consistent and max(range(4), key=lambda k: result.unsupported[k]) == 2


def _plain_unsupported(cameras, masks, scene_radius, samples=192):
    """Per view the unsupported share of its foreground, every point projected into every other view."""
    n, height, width = masks.shape
    shares = []
    for view in range(n):
        inside = masks[view].reshape(-1).nonzero().squeeze(-1)
        origins, directions = cameras.generate_rays(view, (inside // width).float(), (inside % width).float())
        nears, fars, _ = near_far_from_sphere(origins, directions, scene_radius)
        depths = nears + (fars - nears) * torch.linspace(0.0, 1.0, samples)[None, :]
        points = (origins[:, None] + directions[:, None] * depths[..., None]).reshape(-1, 3)
        supported = torch.ones(points.shape[0], dtype=torch.bool)
        for other in range(n):
            if other != view:
                uv, depth = cameras.project(points, other)
                col, row = uv[:, 0].round().long(), uv[:, 1].round().long()
                in_frame = (col >= 0) & (col < width) & (row >= 0) & (row < height)
                seen = torch.ones_like(in_frame)
                seen[in_frame] = masks[other, row[in_frame], col[in_frame]]
                supported &= seen | (depth <= 0)
        ok = supported.reshape(-1, samples).any(-1) & (fars > nears)[:, 0]
        shares.append(1.0 - float(ok.float().mean()))
    return shares


def test_the_support_test_equals_projecting_every_point_into_every_view():
    """Points another view has ruled out are not projected again: the same shares, to the bit, on masks
    cut by the frame (points outside a frame stay supported) and with a drifted view."""
    cameras = orbit_cameras([0, 70, 150, 220, 300], 20.0, resolution=32)
    masks = _sphere_masks(cameras, radius=0.55, centre=(0.1, 0.0, 0.05))
    masks[3] = torch.roll(masks[3], shifts=3, dims=0)
    result = silhouette_support(cameras, masks, scene_radius=1.0)
    assert result.unsupported == _plain_unsupported(cameras, masks, 1.0)
    assert max(result.unsupported) > 0.0


def test_no_verdict_without_two_views_or_with_an_empty_mask():
    cameras = orbit_cameras([0, 90], 30.0, resolution=32)
    masks = _sphere_masks(cameras)
    one = orbit_cameras([0], 30.0, resolution=32)
    assert silhouette_support(one, masks[:1], 1.0) is None
    empty = masks.clone()
    empty[1] = False
    assert silhouette_support(cameras, empty, 1.0) is None


def test_the_phase_decision_reads_the_training_masks():
    from types import SimpleNamespace

    from va_plugin.analysis.consistency import input_silhouette_support

    cameras = orbit_cameras([0, 90, 180, 270], 30.0, resolution=64)
    masks = _sphere_masks(cameras)
    shifted = masks.clone()
    shifted[3] = torch.roll(masks[3], shifts=5, dims=0)
    manager = SimpleNamespace(cameras=cameras, masks=shifted[..., None].float(), scene_radius=1.0)
    assert not input_silhouette_support(manager).consistent
    assert input_silhouette_support(SimpleNamespace(cameras=cameras, masks=None, scene_radius=1.0)) is None


def test_color_cast_separates_a_white_balance_shift_from_brightness():
    """Hand-computed: a common gain is brightness, not a cast; a per-channel spread is."""
    from va_plugin.analysis.consistency import ColorCast

    bright = ColorCast(np.array([[1.0, 1.0, 1.0], [1.1, 1.1, 1.1]]), points=10, seconds=0.0)
    assert bright.worst == pytest.approx(0.0, abs=1e-9) and bright.brightness == pytest.approx(np.log(1.1))
    tinted = ColorCast(np.array([[1.0, 1.0, 1.0], [1.05, 1.0, 0.95]]), points=10, seconds=0.0)
    logs = np.log([1.05, 1.0, 0.95])
    assert tinted.worst == pytest.approx(np.max(np.abs(logs - logs.mean())))
    assert tinted.as_dict()["test"] == "color_cast" and len(tinted.as_dict()["gains"]) == 2
    # in color units: a dark channel's share counts for as little as it shows
    dim = ColorCast(np.array([[1.0, 1.0, 1.0], [1.05, 1.0, 0.95]]), 10, 0.0, np.array([[0.5, 0.5, 0.05]] * 2))
    assert dim.worst_shift == pytest.approx(max(abs(logs - logs.mean()) * [0.5, 0.5, 0.05]))


def test_color_cast_of_a_run_follows_a_tint_of_one_view(tmp_path_factory):
    """On a (tiny) trained run of 8 views: tinting view 2's object by (1.1, 1, 0.9) divides its fitted gains
    by the tint and leaves view 0 at 1 (the gains themselves are far from 1 here: the start sphere does not
    register the mug's views; what the test checks is that the fit reads the views' color ratios)."""
    from conftest import tiny_config

    from va_plugin.analysis.consistency import color_cast
    from va_plugin.api import load_run
    from va_plugin.bench.scenes.builder import build_procedural_scene
    from va_plugin.export.texture import run_views

    # after 2 steps the surface is still the start sphere: 8 views, so that neighbours share points of it
    scene = build_procedural_scene(tmp_path_factory.mktemp("scene"), "mug", n_views=8, resolution=64)
    run = tmp_path_factory.mktemp("run")
    tiny_config("neus", scene, run, steps=2).setup().train()
    pipeline, _ = load_run(run, "cpu").parts()
    views = run_views(pipeline)
    before = color_cast(pipeline.model, views.cameras, views.images, views.masks, resolution=32)
    tint = np.array([1.1, 1.0, 0.9], np.float32)
    images = views.images.copy()
    images[2] = np.where(views.masks[2][..., None], np.clip(images[2] * tint, 0, 1), images[2])
    after = color_cast(pipeline.model, views.cameras, images, views.masks, resolution=32)
    assert before.points > 0 and np.all(after.gains[0] == 1.0)
    np.testing.assert_allclose(after.gains[2], before.gains[2] / tint, rtol=0.03)


def test_dense_rigs_allow_a_pixel_at_the_rim_and_still_catch_drift():
    """With 16 views each ray meets 15 masks, so pixel rounding at a clean rim rules points out; the phase
    decision then dilates the other masks by a pixel, and a view drifted by 4 px is still caught."""
    from types import SimpleNamespace

    from va_plugin.analysis.consistency import DENSE_VIEWS, input_silhouette_support, silhouette_tolerance_px

    assert silhouette_tolerance_px(4) == 0 and silhouette_tolerance_px(DENSE_VIEWS) == 1
    cameras = orbit_cameras([22.5 * k for k in range(16)], 30.0, resolution=64)
    masks = _sphere_masks(cameras, centre=(0.05, 0.03, -0.02))
    assert not silhouette_support(cameras, masks, scene_radius=1.0).consistent  # rim rounding alone
    clean = input_silhouette_support(SimpleNamespace(cameras=cameras, masks=masks[..., None].float(),
                                                     scene_radius=1.0))
    assert clean.consistent and clean.as_dict()["tolerance_px"] == 1
    shifted = masks.clone()
    shifted[5] = torch.roll(masks[5], shifts=4, dims=1)
    drifted = input_silhouette_support(SimpleNamespace(cameras=cameras, masks=shifted[..., None].float(),
                                                       scene_radius=1.0))
    assert not drifted.consistent and drifted.unsupported[5] > 0.02
