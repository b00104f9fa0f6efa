import math

import pytest
import torch

from va_plugin.adaptive.attention import LOGIT_BOUND, ViewAttention, reference_attention
from va_plugin.adaptive.branches import ViewBranches


def _randomised(module: ViewAttention, seed: int = 0) -> ViewAttention:
    """The output projection starts at zero; give it values so the fused features depend on it."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        module.out.weight.copy_(torch.randn(module.out.weight.shape, generator=gen) * 0.1)
        module.out.bias.copy_(torch.randn(module.out.bias.shape, generator=gen) * 0.1)
    return module


@pytest.mark.parametrize("n_views,heads", [(4, 4), (3, 1), (16, 2)])
def test_attention_matches_the_loop_reference_and_rows_sum_to_one(n_views, heads):
    torch.manual_seed(0)
    module = _randomised(ViewAttention(feature_dim=12, attention_dim=8 * heads, n_heads=heads))
    tokens = torch.randn(5, n_views, 12)
    fused, alpha = module(tokens)
    ref_fused, ref_alpha = reference_attention(module, tokens)
    assert alpha.shape == (5, heads, n_views, n_views)
    torch.testing.assert_close(alpha.sum(-1), torch.ones(5, heads, n_views))
    torch.testing.assert_close(alpha, ref_alpha, atol=1e-6, rtol=1e-5)
    torch.testing.assert_close(fused, ref_fused, atol=1e-5, rtol=1e-5)


def test_fresh_attention_is_the_identity_and_uniform_for_equal_tokens():
    module = ViewAttention(feature_dim=6, attention_dim=8, n_heads=2)
    tokens = torch.randn(3, 1, 6).expand(3, 4, 6).contiguous()
    fused, alpha = module(tokens)
    assert torch.equal(fused, tokens)  # zero-initialised output projection: phase 3 starts where phase 2 ended
    torch.testing.assert_close(alpha, torch.full_like(alpha, 0.25))


def test_query_and_key_projections_learn_only_once_the_output_projection_moves():
    """Phase 3 starts with a zero output projection: on the first step only it gets a gradient (the
    query/key/value projections get exactly zero, whatever the tokens); one Adam step later it is
    non-zero and the query and key rows are trained too. Tokens that differ little give attention
    that differs little from uniform: the logits scale with the tokens' differences."""
    torch.manual_seed(0)
    module = ViewAttention(feature_dim=8, attention_dim=8, n_heads=2)
    tokens = torch.randn(6, 4, 8)
    target = torch.randn(6, 4, 8)
    optimizer = torch.optim.Adam(module.parameters(), lr=1e-2)
    grads = []
    for _ in range(2):
        optimizer.zero_grad()
        fused, _ = module(tokens)
        ((fused - target) ** 2).mean().backward()
        grads.append((module.qkv.weight.grad[:16].abs().sum().item(), module.out.weight.grad.abs().sum().item()))
        optimizer.step()
    assert grads[0][0] == 0.0 and grads[0][1] > 0  # step 1: only the output projection learns
    assert grads[1][0] > 0  # step 2: queries and keys receive a gradient
    near_equal = tokens[:, :1] + 1e-3 * torch.randn(6, 4, 8)
    _, alpha = module(near_equal)
    assert (alpha - 0.25).abs().max() < 1e-2


def test_huge_features_give_finite_attention_and_gradients():
    module = _randomised(ViewAttention(feature_dim=4, attention_dim=4, n_heads=1))
    tokens = (torch.randn(2, 3, 4) * 1e6).requires_grad_(True)
    fused, alpha = module(tokens)
    (fused.sum() + alpha.sum()).backward()
    assert torch.isfinite(alpha).all() and torch.isfinite(tokens.grad).all()
    assert math.log(torch.finfo(torch.float32).max) > LOGIT_BOUND


def test_branches_batched_equal_per_view_loop_and_own_equals_gathered_all():
    torch.manual_seed(1)
    branches = ViewBranches(n_views=3, feature_dim=5, width=7, n_layers=3)
    with torch.no_grad():  # the last layer starts at zero; make it non-trivial
        branches.weights[-1].normal_()
        branches.biases[-1].normal_()
    features = torch.randn(10, 5)
    views = torch.tensor([2, 0, 0, 1, 2, 2, 1, 0, 2, 1])
    everything = branches.forward_all(features)
    for i in range(3):  # plain per-view MLP
        x = features
        for k, (w, b) in enumerate(zip(branches.weights, branches.biases)):
            x = x @ w[i] + b[i]
            if k < 2:
                x = torch.relu(x)
        torch.testing.assert_close(everything[:, i], features + x)
    own = branches.forward_own(features, views)
    torch.testing.assert_close(own, everything[torch.arange(10), views])


def test_fresh_branches_are_the_identity():
    branches = ViewBranches(n_views=4, feature_dim=6, width=8, n_layers=3)
    features = torch.randn(7, 6)
    assert torch.equal(branches.forward_all(features), features[:, None].expand(7, 4, 6))
    assert torch.equal(branches.forward_own(features, torch.tensor([0, 1, 2, 3, 0, 1, 2])), features)
    assert branches.forward_own(features[:0], torch.zeros(0, dtype=torch.long)).shape == (0, 6)


def _own_by_advanced_indexing(branches: ViewBranches, features: torch.Tensor, views: torch.Tensor) -> torch.Tensor:
    """The own-view branches written with advanced indexing into the padded block (the formulation the
    row copies of ``forward_own`` replace)."""
    order = torch.argsort(views)
    sorted_views = views[order]
    counts = torch.bincount(sorted_views, minlength=branches.n_views)
    slot = torch.arange(views.shape[0]) - (torch.cumsum(counts, 0) - counts)[sorted_views]
    padded = features.new_zeros(branches.n_views, int(counts.max()), features.shape[-1])
    padded[sorted_views, slot] = features[order]
    out = branches._mlp(padded)[sorted_views, slot]
    result = torch.empty_like(out)
    result[order] = out
    return features + result


@pytest.mark.parametrize("n_samples", [1, 37, 1000])
def test_own_branches_give_the_same_bits_as_advanced_indexing(n_samples):
    """Outputs and every gradient (features, weights, biases) are equal bit for bit."""
    torch.manual_seed(n_samples)
    branches = ViewBranches(n_views=16, feature_dim=8, width=12, n_layers=2)
    with torch.no_grad():
        for p in branches.parameters():
            p.normal_()
    views = torch.randint(0, 16, (n_samples,))
    views[views == 3] = 4  # a view without samples
    features, cotangent = torch.randn(n_samples, 8), torch.randn(n_samples, 8)
    results = []
    for compute in (branches.forward_own, lambda f, v: _own_by_advanced_indexing(branches, f, v)):
        branches.zero_grad(set_to_none=True)
        x = features.clone().requires_grad_(True)
        out = compute(x, views)
        (out * cotangent).sum().backward()
        results.append([out.detach(), x.grad] + [p.grad for p in branches.parameters()])
    for fast, plain in zip(*results):
        assert torch.equal(fast, plain)


def test_own_branches_of_one_view_run_one_branch(monkeypatch):
    """A render of one training view sends its samples through that view's branch alone (one block, not
    n), with the bits of the padded all-views block."""
    torch.manual_seed(5)
    branches = ViewBranches(n_views=16, feature_dim=8, width=12, n_layers=3)
    with torch.no_grad():
        for p in branches.parameters():
            p.normal_()
    features, views = torch.randn(50, 8), torch.full((50,), 9)
    reference = _own_by_advanced_indexing(branches, features, views)
    blocks = []
    mlp = branches._mlp
    monkeypatch.setattr(branches, "_mlp", lambda x, chosen=None: blocks.append(x.shape[0]) or mlp(x, chosen))
    assert torch.equal(branches.forward_own(features, views), reference)
    assert blocks == [1]
