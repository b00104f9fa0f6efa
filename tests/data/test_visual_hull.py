"""Visual hull: a ball's silhouettes give back the ball's box, a similarity transform keeps every view."""

import pytest
import torch

from va_plugin.data import rigs
from va_plugin.data.visual_hull import normalise_cameras, unit_box_transform, visual_hull


def ball_masks(cameras, centre, radius):
    """Exact silhouettes ``[n, H, W]`` of a ball: pixels whose ray passes within ``radius`` of ``centre``."""
    masks = []
    for k in range(len(cameras)):
        views, rows, cols = cameras.pixel_grid(k)
        origins, directions = cameras.generate_rays(views, rows, cols)
        to_centre = centre - origins
        along = (to_centre * directions).sum(-1, keepdim=True)
        distance = (to_centre - along * directions).norm(dim=-1)
        masks.append((distance < radius).reshape(cameras.height, cameras.width))
    return torch.stack(masks)


@pytest.mark.parametrize("cameras", [rigs.syncdreamer_rig(64, pixel_offset=0.5), rigs.wonder3d_rig(64)],
                         ids=["perspective", "orthographic"])
def test_ball_hull_box_and_unit_box_fit(cameras):
    centre, radius = torch.tensor([0.1, -0.05, 0.08]), 0.3
    masks = ball_masks(cameras, centre, radius)
    hull = visual_hull(cameras, masks, resolution=48)
    lower, upper = hull.bounds
    # carving from a ring of views is exact sideways; from the ring's own plane it cannot close top and bottom
    assert torch.allclose(lower[:2], centre[:2] - radius, atol=0.03)
    assert torch.allclose(upper[:2], centre[:2] + radius, atol=0.03)
    assert min(hull.silhouette_iou) > 0.9
    shift, scale = unit_box_transform(lower, upper)
    moved = normalise_cameras(cameras, shift, scale)
    points = torch.tensor([[0.2, 0.1, -0.1], [-0.3, 0.25, 0.05]])
    for k in range(len(cameras)):
        before, _ = cameras.project(points, k)
        after, _ = moved.project((points - shift) * scale, k)
        assert torch.allclose(before, after, atol=1e-3)
    moved_hull = hull.moved(shift, scale)
    new_lower, new_upper = moved_hull.bounds
    assert float((new_upper - new_lower).max()) == pytest.approx(1.0, abs=1e-5)


def test_silhouettes_that_exclude_each_other_give_an_empty_hull():
    cameras = rigs.syncdreamer_rig(32, pixel_offset=0.5)
    masks = torch.zeros(16, 32, 32, dtype=torch.bool)
    masks[0, :, :3] = True  # view 0 sees something only at its left edge
    masks[8, :, :3] = True  # the opposite view too: those rays never meet
    masks[1:8] = True
    masks[9:] = True
    assert visual_hull(cameras, masks, resolution=32).points.numel() == 0
