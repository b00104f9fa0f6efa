"""Per-view deformation grids: trilinear lookup against grid_sample, frozen and novel views untouched,
the clamp and the penalty, and neus training the unfrozen views' grids while its mesh stays shared."""

import pytest
import torch
import torch.nn.functional as F

from conftest import tiny_config
from per_view_checks import assert_one_step_trains_unfrozen_views
from va_plugin.errors import ConfigError
from va_plugin.model_components.view_deformation import MAX_DISPLACEMENT, ViewDeformationConfig


def test_lookup_matches_grid_sample():
    torch.manual_seed(0)
    deformation = ViewDeformationConfig(enabled=True, resolution=5, frozen_views=()).setup(num_views=3)
    with torch.no_grad():
        deformation.grid.normal_(0.0, 0.01)
    points = torch.rand(200, 3) * 1.8 - 0.9
    views = torch.randint(0, 3, (200,))
    got = deformation.displacement(points, views)
    for v in range(3):
        # grid_sample wants [N, C, D, H, W] with the last coordinate indexing W: our grid is [x, y, z, 3]
        volume = deformation.grid[v].permute(3, 2, 1, 0)[None]
        pick = views == v
        ref = F.grid_sample(volume, points[pick][None, None, None], align_corners=True)[0, :, 0, 0].t()
        assert torch.allclose(got[pick], ref, atol=1e-6)


def test_frozen_and_novel_views_are_not_moved_and_sizes_are_clamped():
    deformation = ViewDeformationConfig(enabled=True, resolution=3, penalty_weight=2.0).setup(num_views=2)
    with torch.no_grad():
        deformation.grid.fill_(1.0)
    points = torch.zeros(3, 3)
    moved = deformation.displacement(points, torch.tensor([0, 1, -1]))
    assert moved[0].abs().sum() == 0 and moved[2].abs().sum() == 0
    assert torch.allclose(moved[1], torch.full((3,), MAX_DISPLACEMENT))
    assert float(deformation.loss().detach()) == pytest.approx(2.0)  # view 1's grid only: mean of 1^2
    assert deformation.largest() == pytest.approx(3 ** 0.5)
    with pytest.raises(ConfigError, match="resolution"):
        ViewDeformationConfig(resolution=1).setup(num_views=2)


def test_neus_trains_unfrozen_grids_and_meshes_the_shared_field(tiny_scene, tmp_path):
    torch.manual_seed(0)
    trainer = tiny_config("neus", tiny_scene, tmp_path / "d",
                          **{"pipeline.model.view_deformation.enabled": True}).setup()
    model = trainer.model
    points = torch.rand(64, 3) - 0.5
    before = model.mesh_field(points)
    with torch.no_grad():
        model.view_deformation.grid.normal_(0.0, 0.02)
    assert torch.equal(model.mesh_field(points), before)  # the mesh reads the shared geometry
    assert_one_step_trains_unfrozen_views(trainer, "view_deformation", model.view_deformation.grid)
