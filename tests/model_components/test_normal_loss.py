"""The normal loss against hand-computed values."""

import torch

from va_plugin.model_components.losses import normal_loss


def test_normal_loss_hand_values():
    target = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    rendered = torch.tensor([[0.0, 0.0, 2.0],   # same direction, any length: 0
                             [1.0, 0.0, 0.0],   # perpendicular: 1
                             [0.0, 0.0, -0.5],  # opposite: 2
                             [1.0, 0.0, 0.0]])  # no target (background): ignored
    assert torch.isclose(normal_loss(rendered, target), torch.tensor(1.0))
    assert float(normal_loss(rendered[:1], target[:1])) == 0.0


def test_normal_loss_is_finite_for_zero_renders_and_empty_targets():
    rendered = torch.zeros(3, 3, requires_grad=True)
    target = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    loss = normal_loss(rendered, target)
    loss.backward()
    assert torch.isclose(loss, torch.tensor(1.0)) and bool(torch.isfinite(rendered.grad).all())
    assert float(normal_loss(torch.ones(2, 3), torch.zeros(2, 3))) == 0.0
