"""The start from the masks: the hull's signed distance, its trilinear lookup, the fit, and where it runs."""

import math

import pytest
import torch
from conftest import ball_masks, tiny_config

from va_plugin.data import rigs
from va_plugin.engine.callbacks import BEFORE_STEP, TrainingCallback
from va_plugin.errors import ConfigError
from va_plugin.fields.hash_sdf_field import HashSDFFieldConfig
from va_plugin.model_components.hull_start import fit_field_to_volume, hull_sdf_volume, sample_volume
from va_plugin.models.base import SceneInfo
from va_plugin.models.neus import NeuSModel, NeuSModelConfig


def test_sample_volume_returns_the_centres_values_and_interpolates_between_them():
    volume = torch.arange(4 * 4 * 4, dtype=torch.float32).reshape(4, 4, 4)  # v[i, j, k] = 16 i + 4 j + k
    radius, voxel = 1.0, 0.5
    centre = lambda i: -radius + voxel * (i + 0.5)
    points = torch.tensor([[centre(1), centre(2), centre(3)], [centre(3), centre(0), centre(1)],
                           [centre(1) + 0.25 * voxel, centre(2), centre(3) - 0.5 * voxel]])
    values = sample_volume(volume, radius, points)
    # x moves the first index (16 per cell), z the last (1 per cell)
    assert values.tolist() == pytest.approx([16 + 8 + 3, 48 + 0 + 1, 16 + 4 + 8 + 3 - 0.5], abs=1e-4)


def test_a_balls_hull_has_the_balls_signed_distance_sideways():
    cameras = rigs.syncdreamer_rig(64, pixel_offset=0.5)
    centre, radius = torch.tensor([0.1, -0.05, 0.0]), 0.3
    masks = ball_masks(cameras, centre, radius)
    volume = hull_sdf_volume(cameras, masks, 1.0, 48)
    voxel = 2.0 / 48
    assert volume.shape == (48, 48, 48)
    # the rig's ring carves the sides exactly, so along x and y the distance is the ball's, to about a voxel
    for offset in ([0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, -0.45, 0.0], [0.2, 0.0, 0.0]):
        point = centre + torch.tensor(offset)
        truth = float(point.sub(centre).norm()) - radius
        assert float(sample_volume(volume, 1.0, point[None])) == pytest.approx(truth, abs=1.5 * voxel)
    # the hull holds the ball: no point of the ball is outside it by more than a voxel
    ball = centre + 0.95 * radius * torch.nn.functional.normalize(torch.randn(200, 3), dim=-1) * torch.rand(200, 1)
    assert float(sample_volume(volume, 1.0, ball).max()) < voxel


def test_no_hull_gives_none():
    cameras = rigs.syncdreamer_rig(32, pixel_offset=0.5)
    empty = torch.zeros(16, 32, 32, dtype=torch.bool)
    assert hull_sdf_volume(cameras, empty, 1.0, 16) is None
    assert hull_sdf_volume(cameras, torch.ones(16, 32, 32, dtype=torch.bool), 0.2, 16) is None  # all inside


def _sphere_volume(radius: float, resolution: int, scene_radius: float = 1.0) -> torch.Tensor:
    voxel = 2.0 * scene_radius / resolution
    axis = -scene_radius + voxel * (torch.arange(resolution) + 0.5)
    points = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1)
    return points.norm(dim=-1) - radius


def test_the_fit_moves_the_fields_sphere_to_the_target():
    torch.manual_seed(0)
    field = HashSDFFieldConfig(n_levels=4, log2_hashmap_size=12, init_radius=0.5).setup()
    field.update_step(0, 100)
    target = _sphere_volume(0.25, 32)
    probe = torch.tensor([[0.0, 0.0, 0.0], [0.38, 0.0, 0.0], [0.0, -0.6, 0.0]])
    before = field.geometry(probe)[0][:, 0].detach()
    assert float(before[1]) < 0  # inside the starting sphere of radius 0.5, outside the target
    error = fit_field_to_volume(field, target, 1.0, steps=60, points_per_step=2048)
    after = field.geometry(probe)[0][:, 0].detach()
    assert math.isfinite(error) and error < 0.03
    assert float(after[0]) < -0.15 and float(after[1]) > 0.05 and float(after[2]) > 0.25
    assert all(torch.isfinite(p).all() for p in field.parameters())


def test_the_hull_start_runs_once_before_the_first_step_and_a_resume_continues_bitwise(tiny_scene, tmp_path):
    def config(out, steps, hull):
        return tiny_config("neus", tiny_scene, out, steps=steps, checkpoint_every=2,
                           **{"pipeline.model.hull_start_steps": hull, "pipeline.model.hull_resolution": 16})

    plain, started = config(tmp_path / "plain", 1, 0).setup(), config(tmp_path / "hull", 1, 5).setup()
    assert torch.equal(plain.model.field.sdf_net.out.bias, started.model.field.sdf_net.out.bias)
    calls = []
    original = started.model.start_training
    started.model.start_training = lambda: (calls.append(started.step), original())[1]
    started.train()
    plain.train()
    assert calls == [0] and started.model.hull_start_error is not None and plain.model.hull_start_error is None
    assert not torch.equal(plain.model.field.sdf_net.out.bias, started.model.field.sdf_net.out.bias)

    full = config(tmp_path / "full", 4, 5).setup()
    full.train()
    first = config(tmp_path / "cut", 4, 5).setup()

    def interrupt(step, trainer):
        if step == 2:
            raise KeyboardInterrupt

    first.callbacks.append(TrainingCallback(interrupt, BEFORE_STEP))
    with pytest.raises(KeyboardInterrupt):
        first.train()
    second = config(tmp_path / "cut", 4, 5).setup()
    assert second.resume() and second.step == 2
    second.model.start_training = lambda: pytest.fail("a resumed run fitted the hull again")
    second.train()
    a, b = full.model.state_dict(), second.model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a), "the resumed run differs from the uninterrupted one"


def test_bad_hull_options_are_refused():
    scene = SceneInfo(num_train_views=4, scene_radius=1.0)
    with pytest.raises(ConfigError, match="hull_start_steps"):
        NeuSModel(NeuSModelConfig(field=HashSDFFieldConfig(), hull_start_steps=-1), scene)
    with pytest.raises(ConfigError, match="hull_resolution"):
        NeuSModel(NeuSModelConfig(field=HashSDFFieldConfig(), hull_resolution=4), scene)
