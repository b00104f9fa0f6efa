import math

import torch

from va_plugin.adaptive.losses import attention_entropy, feature_consistency, weighted_mean


def test_entropy_against_hand_values():
    # one sample, one head, 2 views: rows (0.5, 0.5) and (1, 0)
    alpha = torch.tensor([[[[0.5, 0.5], [1.0, 0.0]]]])
    expected = 2 * 0.5 * math.log(0.5) + 0.0  # 1 log 1 = 0, 0 log 0 = 0
    torch.testing.assert_close(attention_entropy(alpha), torch.tensor([expected]))
    # two heads are averaged
    two = torch.cat([alpha, torch.tensor([[[[1.0, 0.0], [0.0, 1.0]]]])], dim=1)
    torch.testing.assert_close(attention_entropy(two), torch.tensor([expected / 2]))
    # uniform rows reach the minimum -n log n
    n = 4
    uniform = torch.full((1, 1, n, n), 1.0 / n)
    torch.testing.assert_close(attention_entropy(uniform), torch.tensor([-n * math.log(n)]))


def test_entropy_gradient_is_finite_at_zero_and_one():
    alpha = torch.tensor([[[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.2, 0.3, 0.5]]]], requires_grad=True)
    attention_entropy(alpha).sum().backward()
    assert torch.isfinite(alpha.grad).all()
    logits = torch.tensor([[[[200.0, -200.0], [0.0, 0.0]]]], requires_grad=True)
    attention_entropy(torch.softmax(logits, -1)).sum().backward()
    assert torch.isfinite(logits.grad).all()


def test_consistency_against_hand_values():
    # one sample, 2 views, D = 2: f1 = (1, 0), f2 = (3, 2); mean (2, 1); squared distances 2 + 2
    fused = torch.tensor([[[1.0, 0.0], [3.0, 2.0]]])
    torch.testing.assert_close(feature_consistency(fused), torch.tensor([4.0]))
    assert float(feature_consistency(torch.ones(1, 5, 3))) == 0.0


def test_weighted_mean_uses_weights_and_falls_back_to_plain_mean():
    values = torch.tensor([1.0, 3.0, 10.0])
    torch.testing.assert_close(weighted_mean(values, torch.tensor([1.0, 1.0, 0.0])), torch.tensor(2.0))
    torch.testing.assert_close(weighted_mean(values, torch.zeros(3)), values.mean())
    torch.testing.assert_close(weighted_mean(values, None), values.mean())
    assert float(weighted_mean(values[:0], torch.zeros(0))) == 0.0
