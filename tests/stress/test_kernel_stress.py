"""Property-based stress tests of every numeric kernel: finite outputs and finite gradients at the
extremes (alphas of exactly 0 and 1, long rays, huge and tiny SDFs, inv_s at both clamps, rays that
miss or graze the bound or have no length, huge/tiny/equal attention logits, zero gradients, the edges
of the hash grid). Where a kernel once failed, a hand-computed test pins the fix."""

import math

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from va_plugin.adaptive.attention import LOGIT_BOUND, ViewAttention
from va_plugin.adaptive.losses import attention_entropy, feature_consistency, weighted_mean
from va_plugin.fields.density_field import trunc_exp
from va_plugin.fields.encodings.hash_grid import HashGridEncoding
from va_plugin.model_components.losses import GRADIENT_BOUND, eikonal_loss, mask_loss, psnr_from_mse
from va_plugin.model_components.neus import INV_S_MAX, INV_S_MIN, SDF_BOUND, SingleVariance, neus_alpha, section_alpha
from va_plugin.model_components.renderers import alpha_from_density, render_depth, render_rgb, weights_from_alpha
from va_plugin.model_components.samplers import sample_pdf, uniform_edges
from va_plugin.models.ngp import distortion
from va_plugin.rays import near_far_from_sphere

FAST = settings(max_examples=25, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def f32(lo: float, hi: float) -> st.SearchStrategy:
    """Floats in [lo, hi] that fp32 can hold (the bounds rounded to fp32 first)."""
    return st.floats(float(np.float32(lo)), float(np.float32(hi)), width=32)


def finite(*tensors) -> bool:
    return all(t is not None and bool(torch.isfinite(t).all()) for t in tensors)


def grad_of(output: torch.Tensor, *inputs: torch.Tensor):
    return torch.autograd.grad(output.sum(), inputs, allow_unused=True)


# -- volume rendering ----------------------------------------------------------------------------

alpha_values = st.one_of(st.just(0.0), st.just(1.0), f32(0.0, 1.0))


@FAST
@given(rows=st.lists(st.lists(alpha_values, min_size=1, max_size=12), min_size=1, max_size=4),
       long_ray=st.sampled_from([0, 4096, 16384]))
def test_weights_from_alpha_at_zero_one_and_on_long_rays(rows, long_ray):
    width = max(len(r) for r in rows)
    alpha = torch.tensor([r + [0.0] * (width - len(r)) for r in rows])
    if long_ray:  # a long ray of small alphas, then the hand-made row
        alpha = torch.cat([torch.full((alpha.shape[0], long_ray), 1e-4), alpha], dim=1)
    alpha.requires_grad_(True)
    weights = weights_from_alpha(alpha)
    rgb = torch.rand(*alpha.shape, 3, requires_grad=True)
    color = render_rgb(weights, rgb, torch.tensor([1.0, 1.0, 1.0]))
    depth = render_depth(weights, torch.linspace(0.1, 5.0, alpha.shape[1]).expand_as(alpha))
    assert finite(weights, color, depth)
    assert bool((weights >= 0).all()) and bool((weights.sum(-1) <= 1.0 + 1e-5).all())
    assert bool((color >= -1e-6).all()) and bool((color <= 1.0 + 1e-5).all())
    assert finite(*grad_of(color + depth, alpha, rgb))


def test_weights_of_a_long_ray_sum_to_at_most_one_hand_computed():
    # 4096 samples of alpha 1e-4, then an opaque one: the weights must sum to exactly 1 (the opaque
    # sample takes all that is left). With NeuS's "1 - alpha + 1e-7" they summed to 1.0003.
    alpha = torch.cat([torch.full((1, 4096), 1e-4), torch.ones(1, 1)], dim=1)
    weights = weights_from_alpha(alpha)
    assert float(weights.sum()) <= 1.0 and float(weights.sum()) == pytest.approx(1.0, abs=1e-4)  # fp32 rounding
    assert float(weights[0, -1]) == pytest.approx((1 - 1e-4) ** 4096, rel=1e-4)


def test_an_opaque_sample_hides_everything_behind_it():
    alpha = torch.tensor([[0.0, 1.0, 0.7, 1.0]])
    weights = weights_from_alpha(alpha)
    # transmittance before the second sample is 1 (+1e-7), after it (1 - 1 + 1e-7): effectively 0
    assert weights[0, 1] == pytest.approx(1.0, abs=1e-6) and float(weights[0, 2:].sum()) < 1e-6
    assert float(render_depth(weights, torch.tensor([[1.0, 2.0, 3.0, 4.0]]))) == pytest.approx(2.0, abs=1e-5)


@FAST
@given(density=f32(0.0, 3e38), delta=f32(0.0, 1e6))
def test_alpha_from_density_is_a_probability(density, delta):
    d = torch.tensor([[density]], requires_grad=True)
    alpha = alpha_from_density(d, torch.tensor([[delta]]))
    assert finite(alpha, *grad_of(alpha, d)) and 0.0 <= float(alpha.detach()) <= 1.0


@FAST
@given(raw=f32(-1e30, 1e30))
def test_truncated_exponential_density(raw):
    x = torch.tensor([raw], requires_grad=True)
    y = trunc_exp(x)
    assert finite(y, *grad_of(y, x)) and float(y.detach()) >= 0.0


def test_render_without_any_weight_is_the_background():
    weights = torch.zeros(3, 5)
    color = render_rgb(weights, torch.rand(3, 5, 3), torch.tensor([0.2, 0.4, 0.6]))
    assert torch.allclose(color, torch.tensor([0.2, 0.4, 0.6]).expand(3, 3))
    assert torch.equal(render_depth(weights, torch.rand(3, 5)), torch.zeros(3, 1))
    assert float(distortion(weights, torch.rand(3, 5), torch.rand(3, 5)).abs().sum()) == 0.0


# -- NeuS ----------------------------------------------------------------------------------------

extreme_sdf = st.one_of(f32(-3e38, 3e38), st.sampled_from([0.0, 1e-30, -1e-30, 1e6, -1e6]))


@FAST
@given(sdf=st.lists(extreme_sdf, min_size=1, max_size=8),
       cos=f32(-1e6, 1e6), delta=f32(0.0, 1e3),
       variance=st.sampled_from([-100.0, -1.3816, 0.3, 1.3816, 100.0]), anneal=st.floats(0.0, 1.0))
def test_neus_alpha_at_extreme_sdf_and_clamped_inv_s(sdf, cos, delta, variance, anneal):
    s = torch.tensor([sdf], requires_grad=True)
    true_cos = torch.full_like(s, cos).requires_grad_(True)
    var = SingleVariance(variance)
    inv_s = var.inv_s()
    assert INV_S_MIN * (1 - 1e-5) <= float(inv_s.detach()) <= INV_S_MAX * (1 + 1e-5)
    alpha = neus_alpha(s, true_cos, torch.full_like(s, delta), inv_s, anneal)
    assert finite(alpha) and bool(((alpha >= 0) & (alpha <= 1)).all())
    loss = weights_from_alpha(alpha).sum() + alpha.sum()
    grads = torch.autograd.grad(loss, (s, true_cos, var.variance))
    assert finite(*grads)


@FAST
@given(edges=st.lists(extreme_sdf, min_size=2, max_size=9), inv_s=st.sampled_from([INV_S_MIN, 1.0, 64.0, INV_S_MAX]))
def test_section_alpha_used_by_up_sampling(edges, inv_s):
    alpha = section_alpha(torch.tensor([edges]), inv_s)
    assert finite(alpha) and bool(((alpha >= 0) & (alpha <= 1)).all())


def test_neus_alpha_at_an_sdf_beyond_the_bound_hand_computed():
    # 3e38 * 1e6 overflowed to inf and gave the gradient of inv_s inf * 0 = NaN; the SDF is now clamped
    # to +-1e6 first. Inside by 3e38 (both ends clamped to -1e6): Phi = 0 at both ends -> alpha = 1e-5/1e-5 = 1;
    # outside by 3e38: Phi = 1 at both ends -> alpha = 1e-5 / (1 + 1e-5).
    s = torch.tensor([[-3e38, 3e38]], requires_grad=True)
    inv_s = torch.tensor(INV_S_MAX, requires_grad=True)
    alpha = neus_alpha(s, torch.zeros_like(s), torch.full_like(s, 0.1), inv_s, 1.0)
    assert torch.allclose(alpha, torch.tensor([[1.0, 1e-5 / (1 + 1e-5)]]), rtol=1e-6, atol=0)
    assert finite(*torch.autograd.grad(alpha.sum(), (s, inv_s)))
    # a sane SDF is untouched by the clamp: section from +0.1 to -0.1 at inv_s 10
    hi, lo = torch.sigmoid(torch.tensor(1.0)), torch.sigmoid(torch.tensor(-1.0))
    assert (float(section_alpha(torch.tensor([[0.1, -0.1]]), 10.0))
            == pytest.approx(float((hi - lo + 1e-5) / (hi + 1e-5))))
    assert SDF_BOUND == 1e6


# -- rays and samplers ---------------------------------------------------------------------------

coordinate = f32(-1e4, 1e4)


@FAST
@given(origin=st.tuples(coordinate, coordinate, coordinate),
       direction=st.one_of(st.tuples(f32(-1, 1), f32(-1, 1),
                                     f32(-1, 1)), st.just((0.0, 0.0, 0.0))),
       radius=st.floats(0.1, 10.0))
def test_near_far_any_ray(origin, direction, radius):
    o, d = torch.tensor([origin]), torch.tensor([direction])
    near, far, hits = near_far_from_sphere(o, d, radius)
    assert finite(near, far) and float(near) >= 0.0 and float(far) >= float(near)
    assert bool(hits) == (float(far) > float(near))
    if float(d.norm()) < 1e-6:
        assert not bool(hits)  # a zero-length ray goes nowhere
    edges = uniform_edges(near, far, 8, jitter=True)
    assert finite(edges) and bool((edges >= near - 1e-3).all()) and bool((edges <= far + 1e-3).all())
    if bool(hits):  # the points where the ray enters and leaves lie on (or, from inside, in) the sphere
        unit = float(d.norm())
        exit_point = o + d * far
        assert float(exit_point.norm()) == pytest.approx(radius, abs=1e-3 * max(1.0, float(o.norm()) * unit))


def test_near_far_hand_computed_for_far_tangent_and_empty_rays():
    origins = torch.tensor([[0.0, 0.0, -1e4], [0.0, 1.0, -5.0], [0.0, 0.0, -5.0], [0.0, 0.0, 0.5],
                            [0.0, 0.0, 5.0]])
    directions = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0],
                               [0.0, 0.0, 1.0]])
    near, far, hits = near_far_from_sphere(origins, directions, 1.0)
    # 10^4 radii away: the discriminant form lost every digit in fp32 and called this a miss
    assert hits.tolist() == [True, False, False, False, False]
    assert float(near[0]) == pytest.approx(9999.0) and float(far[0]) == pytest.approx(10001.0)
    # grazing (tangent), zero-length (outside and inside) and pointing away: empty intervals
    assert torch.equal(near[1:], far[1:])


@FAST
@given(weights=st.lists(st.one_of(st.just(0.0), f32(0.0, 1e30)), min_size=1, max_size=10),
       width=st.sampled_from([0.0, 1e-7, 1.0, 1e4]), jitter=st.booleans())
def test_sample_pdf_with_zero_weights_and_empty_bins(weights, width, jitter):
    bins = torch.linspace(0.0, width, len(weights) + 1)[None]
    samples = sample_pdf(bins, torch.tensor([weights]), 16, jitter=jitter)
    assert finite(samples) and bool((samples >= -1e-6).all()) and bool((samples <= width * (1 + 1e-5) + 1e-6).all())


# -- losses --------------------------------------------------------------------------------------

@FAST
@given(gradient=st.tuples(*[st.one_of(st.just(0.0), f32(-3e38, 3e38))] * 3))
def test_eikonal_at_zero_tiny_and_huge_gradients(gradient):
    g = torch.tensor([gradient], requires_grad=True)
    loss = eikonal_loss(g)
    assert finite(loss, *grad_of(loss, g))


def test_eikonal_hand_computed_at_zero_and_beyond_the_bound():
    g = torch.tensor([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0]], requires_grad=True)
    loss = eikonal_loss(g)  # ((5 - 1)^2 + (1e-6 - 1)^2) / 2
    assert float(loss.detach()) == pytest.approx((16.0 + (1 - 1e-6) ** 2) / 2, rel=1e-6)
    (grad,) = grad_of(loss, g)
    assert torch.allclose(grad[0], torch.tensor([0.5 * 2 * 4 * 3 / 5, 0.5 * 2 * 4 * 4 / 5, 0.0]))
    assert torch.equal(grad[1], torch.zeros(3))  # sqrt(0 + 1e-12) has a finite (zero) gradient at 0
    # a component of 1e20 squared to inf (loss inf, gradient NaN); it is clamped to 1e12 first
    huge = torch.tensor([[1e20, 0.0, 0.0]], requires_grad=True)
    loss = eikonal_loss(huge)
    assert float(loss.detach()) == pytest.approx((GRADIENT_BOUND - 1) ** 2, rel=1e-5)
    assert finite(*grad_of(loss, huge))


@FAST
@given(acc=f32(0.0, 1.0), mask=st.sampled_from([0.0, 0.5, 1.0]),
       mse=st.one_of(st.just(0.0), f32(0.0, 1e30)))
def test_mask_loss_and_psnr_at_the_extremes(acc, mask, mse):
    a = torch.tensor([[acc]], requires_grad=True)
    loss = mask_loss(a, torch.tensor([[mask]]))
    assert finite(loss, *grad_of(loss, a))
    assert math.isfinite(float(psnr_from_mse(torch.tensor(mse)))) and float(psnr_from_mse(torch.tensor(mse))) <= 100.0


# -- view-adaptive attention and its regularizers ---------------------------------------------------

@FAST
@given(scale=st.sampled_from([0.0, 1e-30, 1e-6, 1.0, 1e3, 1e6, 1e9, 1e12]), n_views=st.integers(1, 6),
       equal=st.booleans(), seed=st.integers(0, 2 ** 16))
def test_attention_with_huge_tiny_and_equal_logits(scale, n_views, equal, seed):
    torch.manual_seed(seed)
    module = ViewAttention(8, 16, 2)
    torch.nn.init.normal_(module.out.weight)  # a trained, non-zero output projection
    tokens = torch.randn(3, 1 if equal else n_views, 8).expand(3, n_views, 8) * scale
    tokens = tokens.contiguous().requires_grad_(True)
    fused, alpha = module(tokens)
    assert finite(fused, alpha)
    assert torch.allclose(alpha.sum(-1), torch.ones(()), atol=1e-5)
    if equal:  # identical tokens: every view gets the same attention
        assert torch.allclose(alpha, torch.full_like(alpha, 1.0 / n_views), atol=1e-5)
    weights = torch.rand(3)
    loss = weighted_mean(attention_entropy(alpha), weights) + weighted_mean(feature_consistency(fused), weights)
    grads = torch.autograd.grad(loss + fused.sum(), [tokens, *module.parameters()])
    assert finite(loss, *grads)


def test_attention_logits_beyond_the_clamp_are_a_hard_choice():
    module = ViewAttention(2, 2, 1)
    with torch.no_grad():  # q = k = 1e30 * token: logits ~1e60 overflow to inf before the clamp
        module.qkv.weight.copy_(torch.cat([torch.eye(2) * 1e30, torch.eye(2) * 1e30, torch.eye(2)]))
        module.qkv.bias.zero_()
    tokens = torch.tensor([[[1.0, 0.0], [0.0, 1.0]]], requires_grad=True)
    _, alpha = module(tokens)
    # each view attends to itself with logit +50 (clamped), to the other with 0: exp(-50) ~ 2e-22
    assert torch.allclose(alpha[0, 0], torch.eye(2), atol=1e-20)
    assert LOGIT_BOUND == 50.0


@FAST
@given(rows=st.lists(st.lists(st.one_of(st.just(0.0), f32(0.0, 1.0)), min_size=3, max_size=3),
                     min_size=3, max_size=3))
def test_entropy_at_attention_weights_of_zero(rows):
    alpha = torch.tensor(rows).clamp_min(0.0)
    alpha = torch.where(alpha.sum(-1, keepdim=True) > 0, alpha, torch.eye(3))  # rows of a softmax sum to 1
    alpha = (alpha / alpha.sum(-1, keepdim=True))[None, None].requires_grad_(True)
    entropy = attention_entropy(alpha)
    assert finite(entropy, *grad_of(entropy, alpha))
    assert -3 * math.log(3) - 1e-4 <= float(entropy.detach()) <= 1e-6  # between uniform rows and one-hot rows


# -- hash encoding -------------------------------------------------------------------------------

edge_coordinate = st.sampled_from([-1.0, 1.0, 0.0, -1.0 + 1e-7, 1.0 - 1e-7, 1.0 + 1e-7, -1.0 - 1e-7, 0.5, -1e30, 1e30])


@FAST
@given(points=st.lists(st.tuples(edge_coordinate, edge_coordinate, edge_coordinate), min_size=1, max_size=6))
def test_hash_encoding_at_the_domain_edges(points, hash_grid):
    x = torch.tensor(points, requires_grad=True)
    out = hash_grid(x)
    (dx,) = torch.autograd.grad(out.square().sum(), x, create_graph=True)  # as an eikonal term would
    second = torch.autograd.grad(dx.square().sum() + out.sum(), [x, *hash_grid.parameters()])
    assert finite(out, dx, *second)


@pytest.fixture(scope="module")
def hash_grid():
    torch.manual_seed(0)
    grid = HashGridEncoding(n_levels=4, n_features_per_level=2, log2_hashmap_size=8, base_resolution=4,
                            max_resolution=64, bound=1.0)
    with torch.no_grad():
        for p in grid.parameters():
            p.uniform_(-1.0, 1.0)
    return grid
