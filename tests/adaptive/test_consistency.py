"""The silhouette support test: a sphere's exact masks are supported everywhere; a view whose mask is
shifted (a generator's pose drift) or grown (shape drift) is not; too few views give no verdict."""

import torch

from va_plugin.adaptive.consistency import silhouette_support
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

    from va_plugin.adaptive.phases import input_silhouette_support

    cameras = orbit_cameras([0, 90, 180, 270], 30.0, resolution=64)
    masks = _sphere_masks(cameras)
    shifted = masks.clone()
    shifted[3] = torch.roll(masks[3], shifts=5, dims=0)
    manager = SimpleNamespace(cameras=cameras, masks=shifted[..., None].float(), scene_radius=1.0)
    assert not input_silhouette_support(manager).consistent
    assert input_silhouette_support(SimpleNamespace(cameras=cameras, masks=None, scene_radius=1.0)) is None
