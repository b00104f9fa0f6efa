"""Trimmed losses: hand-computed values, the plain losses as their untrimmed reference, the dropped
rays getting no gradient, and the option reaching neus."""

import pytest
import torch

from conftest import tiny_config
from va_plugin.errors import ConfigError
from va_plugin.model_components import losses
from va_plugin.model_components.robust import per_ray_mask_error, per_ray_rgb_error, trimmed_mean


def test_trimmed_mean_hand_computed():
    values = torch.tensor([1.0, 9.0, 2.0, 3.0, 100.0], requires_grad=True)
    assert float(trimmed_mean(values, 0.4).detach()) == pytest.approx(2.0)  # drops 100 and 9
    trimmed_mean(values, 0.4).backward()
    assert values.grad.tolist() == pytest.approx([1 / 3, 0.0, 1 / 3, 1 / 3, 0.0])
    assert float(trimmed_mean(values, 0.0).detach()) == pytest.approx(23.0)
    assert float(trimmed_mean(values, 0.99).detach()) == pytest.approx(1.0)  # at least one ray is kept
    assert float(trimmed_mean(values[:1], 0.5).detach()) == pytest.approx(1.0)


@pytest.mark.parametrize("kind", ["l2", "l1"])
def test_per_ray_errors_average_to_the_plain_losses(kind):
    torch.manual_seed(0)
    pred, target = torch.rand(64, 3), torch.rand(64, 3)
    assert torch.allclose(per_ray_rgb_error(pred, target, kind).mean(), losses.rgb_loss(pred, target, kind))
    acc, mask = torch.rand(64, 1), (torch.rand(64, 1) > 0.5).float()
    assert torch.allclose(per_ray_mask_error(acc, mask).mean(), losses.mask_loss(acc, mask))
    assert torch.isfinite(per_ray_mask_error(torch.tensor([[0.0], [1.0]]), torch.tensor([[1.0], [0.0]]))).all()


def test_neus_trim_fraction_lowers_the_loss_and_is_checked(tiny_scene, tmp_path):
    torch.manual_seed(0)
    trainer = tiny_config("neus", tiny_scene, tmp_path / "t", **{"pipeline.model.trim_fraction": 0.25}).setup()
    model = trainer.model
    rays, batch = trainer.pipeline.datamanager.next_train(0)
    outputs = model.get_outputs(rays)
    trimmed = model.get_loss_dict(outputs, batch)
    model.config.trim_fraction = 0.0
    plain = model.get_loss_dict(outputs, batch)
    assert all(float(trimmed[k].detach()) < float(plain[k].detach()) for k in ("rgb", "mask"))
    with pytest.raises(ConfigError, match="trim_fraction"):
        tiny_config("neus", tiny_scene, tmp_path / "bad", **{"pipeline.model.trim_fraction": 1.0}).setup()
