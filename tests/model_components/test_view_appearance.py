"""Per-view appearance correction: the colour transform, its exactness on a composited ray, training."""

import json

import pytest
import torch

from conftest import tiny_config
from per_view_checks import assert_one_step_trains_unfrozen_views
from va_plugin.errors import ConfigError
from va_plugin.model_components import renderers
from va_plugin.model_components.view_appearance import MAX_CHANGE, ViewAppearanceConfig


def _module(mode="affine", views=3, **kw):
    return ViewAppearanceConfig(mode=mode, **kw).setup(num_views=views)


def test_hand_computed_gain_and_offset_touch_only_the_object():
    module = _module("gain", views=2)
    with torch.no_grad():
        module.correction[1, 0] = 0.5   # red gain 1.5
        module.correction[1, 9:] = torch.tensor([0.0, 0.1, 0.0])  # green offset
    background = torch.ones(3)
    # half-opaque ray: object colour (0.2, 0.4, 0.6) at weight 0.5 over a white background
    rgb = torch.tensor([[0.1 + 0.5, 0.2 + 0.5, 0.3 + 0.5]])
    acc = torch.tensor([[0.5]])
    out = module.apply(rgb, acc, background, torch.tensor([1]))
    # foreground 0.5 * (0.2, 0.4, 0.6) -> (1.5 * 0.1, 0.2 + 0.5 * 0.1, 0.3), plus 0.5 white
    assert torch.allclose(out, torch.tensor([[0.65, 0.75, 0.8]]), atol=1e-6)
    # the frozen view 0, a novel view (-1) and an unknown view are unchanged; an empty ray stays background
    same = module.apply(rgb.expand(3, 3), acc.expand(3, 1), background, torch.tensor([0, -1, 7]))
    assert torch.equal(same, rgb.expand(3, 3))
    empty = module.apply(background[None], torch.zeros(1, 1), background, torch.tensor([1]))
    assert torch.allclose(empty, background[None])


def test_correcting_the_ray_equals_correcting_every_sample():
    torch.manual_seed(0)
    module = _module("affine", views=3)
    with torch.no_grad():
        module.correction.normal_(0.0, 0.1)
    weights = torch.rand(5, 8) * 0.2
    colours = torch.rand(5, 8, 3)
    background = torch.tensor([0.9, 0.8, 1.0])
    views = torch.tensor([0, 1, 2, 1, -1])
    out = module.apply(renderers.render_rgb(weights, colours, background), weights.sum(-1, keepdim=True),
                       background, views)
    matrices, offsets = module.transforms()
    for ray, view in enumerate(views.tolist()):
        per_sample = colours[ray] if view < 0 else colours[ray] @ matrices[view].T + offsets[view]
        expected = renderers.render_rgb(weights[ray:ray + 1], per_sample[None], background)
        assert torch.allclose(out[ray], expected[0], atol=1e-6)


def test_gain_mode_trains_no_cross_channel_entry_and_changes_are_clamped():
    module = _module("gain", views=2)
    with torch.no_grad():
        module.correction.fill_(3.0)
    matrices, offsets = module.transforms()
    assert torch.allclose(matrices[1], torch.eye(3) * (1 + MAX_CHANGE))
    assert torch.allclose(offsets[1], torch.full((3,), MAX_CHANGE))
    assert torch.equal(matrices[0], torch.eye(3)) and torch.equal(offsets[0], torch.zeros(3))
    # the penalty: mean square over the trained entries (6 of view 1)
    assert module.loss().item() == pytest.approx(1e-2 * 9.0)


def test_bad_options_are_config_errors():
    with pytest.raises(ConfigError, match="view_appearance.mode"):
        _module("tint")
    with pytest.raises(ConfigError, match="penalty_weight"):
        _module("affine", penalty_weight=-1.0)


@pytest.mark.parametrize("method", ["neus", "ngp"])
def test_training_moves_the_corrections_of_unfrozen_views(method, tiny_scene, tmp_path):
    torch.manual_seed(0)
    config = tiny_config(method, tiny_scene, tmp_path / "run", steps=3,
                         **{"pipeline.model.view_appearance.mode": "affine"})
    trainer = config.setup()
    model = trainer.model
    assert "view_appearance" in model.get_param_groups()
    assert_one_step_trains_unfrozen_views(trainer, "view_appearance", model.view_appearance.correction)
    record = trainer.train()
    assert record["appearance_max"] > 0.0
    written = json.loads((tmp_path / "run" / "view_appearance.json").read_text())
    assert written["offset"][0] == [0.0, 0.0, 0.0] and len(written["matrix"]) == 4
    # novel views render the shared colour: the same with and without the correction
    rays, _ = trainer.pipeline.datamanager.next_train(0)
    rays.camera_indices = torch.full_like(rays.camera_indices, -1)
    shared = model.render_rays(rays, keys=("rgb",))["rgb"]
    model.view_appearance = None
    assert torch.equal(shared, model.render_rays(rays, keys=("rgb",))["rgb"])
    # off (the default): no parameters, no state-dict entry, no loss term
    plain = tiny_config(method, tiny_scene, tmp_path / "plain").setup().model
    assert plain.view_appearance is None and not any("appearance" in k for k in plain.state_dict())
