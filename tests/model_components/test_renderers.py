import math

import pytest
import torch

from va_plugin.model_components.losses import eikonal_loss, mask_loss
from va_plugin.model_components.neus import SingleVariance, neus_alpha, section_alpha
from va_plugin.model_components.renderers import alpha_from_density, render_depth, render_rgb, weights_from_alpha


def test_weights_hand_computed():
    alpha = torch.tensor([[0.5, 0.5, 1.0, 0.3]])
    w = weights_from_alpha(alpha)
    # 0.5, 0.5*0.5, 1*0.25, 0  (up to the 1e-7 transmittance guard)
    assert torch.allclose(w, torch.tensor([[0.5, 0.25, 0.25, 0.0]]), atol=1e-6)


def test_weights_alpha_extremes_have_finite_gradients():
    alpha = torch.tensor([[0.0, 1.0, 1.0, 0.0]], requires_grad=True)
    w = weights_from_alpha(alpha)
    w.sum().backward()
    assert torch.isfinite(alpha.grad).all()
    assert float(w.detach().sum()) <= 1.0 + 1e-6


def test_render_rgb_blends_background():
    w = torch.tensor([[0.25, 0.25]])
    rgb = torch.tensor([[[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    out = render_rgb(w, rgb, torch.tensor([0.0, 0.0, 1.0]))
    assert torch.allclose(out, torch.tensor([[0.5, 0.0, 0.5]]))
    assert torch.allclose(render_depth(w, torch.tensor([[1.0, 3.0]])), torch.tensor([[2.0]]))


def test_alpha_from_density():
    a = alpha_from_density(torch.tensor([[0.0, math.log(2.0), 1e9]]), torch.tensor([[1.0, 1.0, 1.0]]))
    assert torch.allclose(a, torch.tensor([[0.0, 0.5, 1.0]]), atol=1e-6)


def test_section_alpha_hand_computed():
    # sdf 0.1 -> -0.1 with inv_s = 10: Phi = sigmoid(1), sigmoid(-1)
    s1, s0 = torch.sigmoid(torch.tensor(1.0)), torch.sigmoid(torch.tensor(-1.0))
    expected = (s1 - s0 + 1e-5) / (s1 + 1e-5)
    got = section_alpha(torch.tensor([[0.1, -0.1]]), 10.0)
    assert torch.allclose(got, expected.reshape(1, 1), atol=1e-6)


def test_neus_alpha_matches_section_alpha_for_head_on_rays():
    # a ray hitting the surface head-on (cos = -1) with the annealing finished reproduces the section form
    sdf_mid, delta = torch.tensor([[0.0]]), torch.tensor([[0.2]])
    a = neus_alpha(sdf_mid, torch.tensor([[-1.0]]), delta, torch.tensor(10.0), cos_anneal_ratio=1.0)
    assert torch.allclose(a, section_alpha(torch.tensor([[0.1, -0.1]]), 10.0), atol=1e-6)


def test_neus_alpha_extremes_are_finite_and_in_range():
    sdf = torch.tensor([[1e6, -1e6, 0.0, 0.0]], requires_grad=True)
    cos = torch.tensor([[-1.0, 1.0, 0.0, -1.0]])
    for inv_s in (torch.tensor(1e-6), torch.tensor(1e6)):
        a = neus_alpha(sdf, cos, torch.full_like(cos, 0.1), inv_s, 0.5)
        a.sum().backward()
        assert ((a >= 0) & (a <= 1)).all() and torch.isfinite(sdf.grad).all()


def test_variance_clamps():
    v = SingleVariance(init=100.0)
    assert float(v.inv_s().detach()) == pytest.approx(1e6, rel=1e-5)
    v = SingleVariance(init=-100.0)
    assert float(v.inv_s().detach()) == pytest.approx(1e-6, rel=1e-5)


def test_eikonal_hand_computed_and_zero_gradient():
    g = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 0.0]], requires_grad=True)
    loss = eikonal_loss(g)
    assert float(loss.detach()) == pytest.approx(1.0, abs=1e-5)  # ((2 - 1)^2 + (0 - 1)^2) / 2
    loss.backward()
    assert torch.isfinite(g.grad).all()


def test_mask_loss_is_finite_at_the_extremes():
    acc = torch.tensor([[0.0], [1.0]], requires_grad=True)
    loss = mask_loss(acc, torch.tensor([[1.0], [0.0]]))
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(acc.grad).all()
