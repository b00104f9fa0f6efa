"""The hull-fill prior of the NeuS model: its points lie deep inside the masks' visual hull, it joins the
losses only when its weight is set, and it pulls the surface out to the hull."""

import math

import pytest
import torch
from conftest import tiny_config

from va_plugin.data.rigfile import builtin_rigs, rig_cameras
from va_plugin.errors import ConfigError
from va_plugin.models.neus import hull_core


def _sphere_masks(cameras, radius):
    """Masks ``[n, H, W, 1]`` of a sphere at the origin, from each pixel ray's distance to the centre."""
    masks = []
    for k in range(len(cameras)):
        _, rows, cols = cameras.pixel_grid(k)
        origins, directions = cameras.generate_rays(k, rows.float().reshape(-1), cols.float().reshape(-1))
        along = (-origins * directions).sum(-1, keepdim=True)
        miss = (origins + along * directions).norm(dim=-1)
        masks.append((miss < radius).float().reshape(cameras.height, cameras.width, 1))
    return torch.stack(masks)


def test_hull_core_lies_deep_inside_the_visual_hull():
    cameras = rig_cameras(builtin_rigs()["mvadapter"], 48)  # six orthographic views at elevation 0
    radius = 0.3
    core, voxel = hull_core(cameras, _sphere_masks(cameras, radius), depth=2.0)
    shallow, _ = hull_core(cameras, _sphere_masks(cameras, radius), depth=0.0)
    assert 0 < len(core) < len(shallow)
    # every view sees the sphere's disc, so the hull reaches z = +-r and 2 voxels in stay below it
    assert float(core[:, 2].abs().max()) <= radius - 1.5 * voxel
    assert float(shallow[:, 2].abs().max()) > radius - 1.5 * voxel
    # from the side the hull is a prism around the z axis that holds the sphere's equator
    assert float(core[:, :2].norm(dim=-1).max()) <= radius / math.cos(math.pi / 8) + voxel


def test_hull_fill_loss_hand_computed_and_pulls_the_surface_out(tiny_scene, tmp_path):
    torch.manual_seed(0)
    trainer = tiny_config("neus", tiny_scene, tmp_path / "run", **{"pipeline.model.hull_weight": 1.0,
                                                                    "pipeline.model.hull_points": 4096}).setup()
    model = trainer.model
    model.hull_core = torch.tensor([[0.2, 0.0, 0.0], [0.0, 0.4, 0.0]])
    model.hull_voxel = 0.0  # no jitter: the points themselves
    radius = torch.tensor(0.3, requires_grad=True)
    model.field.geometry = lambda p: ((p.norm(dim=-1, keepdim=True) - radius), None)  # a sphere's SDF
    loss = model._hull_fill(torch.device("cpu"))
    assert float(loss.detach()) == pytest.approx(0.05, abs=0.005)  # half the points are 0.1 outside, half inside
    loss.backward()
    assert float(radius.grad) == pytest.approx(-0.5, abs=0.05)  # descent grows the sphere toward the hull


def test_hull_fill_joins_the_losses_after_its_start(tiny_scene, tmp_path):
    def losses(name, **overrides):
        torch.manual_seed(0)
        trainer = tiny_config("neus", tiny_scene, tmp_path / name, **overrides).setup()
        rays, batch = trainer.pipeline.datamanager.next_train(0)
        return trainer.model.get_loss_dict(trainer.model.get_outputs(rays), batch)

    assert "hull" not in losses("off", **{"pipeline.model.crossings_start": 0.0})  # off by default
    loss = losses("on", **{"pipeline.model.hull_weight": 1.0, "pipeline.model.crossings_start": 0.0})["hull"]
    assert torch.isfinite(loss) and float(loss.detach()) >= 0.0
    assert "hull" not in losses("late", **{"pipeline.model.hull_weight": 1.0, "pipeline.model.crossings_start": 0.5})


@pytest.mark.parametrize("key, value", [("hull_weight", -1.0), ("hull_points", 0), ("hull_depth", -1.0)])
def test_bad_hull_fill_options_are_config_errors(key, value, tiny_scene, tmp_path):
    with pytest.raises(ConfigError, match=key):
        tiny_config("neus", tiny_scene, tmp_path / "run", **{f"pipeline.model.{key}": value}).setup()
