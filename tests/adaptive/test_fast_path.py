"""The adaptive color path's fast (culled, routed) implementation against a plain-torch reference, in
train mode, forward and gradients with the same random cotangents, on several shapes (gsplat's habit).

The reference runs every sample through every path (the shared decoder, every view's branch, the
attention) and picks each sample's color with ``torch.where``: the shared color for a sample at most
``min_sample_weight`` heavy or of a novel view, its own view's branch in phase 2 (and, in phase 3, for the
visible samples that are not among their ray's ``fused_samples_per_ray`` heaviest), f_fused,i for the
rest. The fast path evaluates the branches and the attention only where they are used."""

from __future__ import annotations

import pytest
import torch

from va_plugin.adaptive.field import BRANCHES, FUSION, ViewAdaptiveFieldConfig
from va_plugin.adaptive.losses import attention_entropy, feature_consistency
from va_plugin.fields.density_field import DensityFieldConfig
from va_plugin.fields.sdf_field import SDFFieldConfig

N_VIEWS = 4
BASES = {
    "sdf": lambda: SDFFieldConfig(sdf_width=32, sdf_layers=2, geo_feature_dim=8, color_width=16),
    "density": lambda: DensityFieldConfig(n_levels=4, log2_hashmap_size=10, max_resolution=32, hidden_width=16,
                                          color_width=16),
}


def _field(base: str, phase: int, k: int):
    torch.manual_seed(0)
    field = ViewAdaptiveFieldConfig(base=BASES[base](), branch_width=16, attention_dim=16, fused_samples_per_ray=k
                                    ).setup(num_train_views=N_VIEWS)
    with torch.no_grad():  # the last branch layer and the attention's output start at zero: make them count
        for p in (field.branches.weights[-1], field.branches.biases[-1], field.attention.out.weight):
            p.add_(torch.randn_like(p) * 0.3)
    field.set_phase(phase)
    return field.train()


def _inputs(base: str, n_rays: int, n_samples: int, seed: int):
    gen = torch.Generator().manual_seed(seed)
    positions = (torch.rand(n_rays, n_samples, 3, generator=gen) - 0.5).requires_grad_(True)
    normals = torch.nn.functional.normalize(torch.randn(n_rays, n_samples, 3, generator=gen), dim=-1)
    geo_dim = 8 if base == "sdf" else 15
    geo = torch.randn(n_rays, n_samples, geo_dim, generator=gen).requires_grad_(True)
    ray_views = torch.randint(-1, N_VIEWS, (n_rays,), generator=gen)  # -1: a novel view's ray
    ray_views[0] = 0  # at least one training ray
    views = ray_views[:, None].expand(n_rays, n_samples)
    weights = torch.rand(n_rays, n_samples, generator=gen).round(decimals=1)  # ties
    weights[torch.rand(n_rays, n_samples, generator=gen) < 0.4] = 1e-5  # culled: below min_sample_weight
    rays = torch.arange(n_rays)[:, None].expand(n_rays, n_samples)
    return positions, -normals, normals, geo, views, weights, rays


def _heaviest(weights: torch.Tensor, k: int) -> torch.Tensor:
    """``[n_rays, n_samples]``: the k heaviest samples of each row, ties to the earlier sample."""
    chosen = torch.zeros_like(weights, dtype=torch.bool)
    for ray in range(weights.shape[0]):
        order = sorted(range(weights.shape[1]), key=lambda i: (-float(weights[ray, i]), i))
        chosen[ray, order[:k]] = True
    return chosen


def _reference(field, positions, directions, normals, geo, views, weights, rays, k):
    """Every sample through every path, then the per-sample choice."""
    shared = field.base.color_features(positions, directions, normals, geo)
    plain = field.base.decode_color(shared)
    tokens = field.branches.forward_all(shared.reshape(-1, shared.shape[-1]))  # [S, n, D]
    pick = torch.arange(tokens.shape[0]), views.reshape(-1).clamp_min(0)
    own = field.base.decode_color(tokens[pick]).reshape(plain.shape)
    visible = (weights > field.config.min_sample_weight) & (views >= 0)
    if field.current_phase < FUSION:
        return {"rgb": torch.where(visible[..., None], own, plain)}
    fused_tokens, alpha = field.attention(tokens)
    fused_rgb = field.base.decode_color(fused_tokens[pick]).reshape(plain.shape)
    fused = visible & _heaviest(weights, k) if k > 0 else visible
    own_only = visible & ~fused
    rgb = torch.where(fused[..., None], fused_rgb, torch.where(own_only[..., None], own, plain))
    # the regularizers see the shared features detached
    fused_tokens, alpha = field.attention(field.branches.forward_all(shared.reshape(-1, shared.shape[-1]).detach()))
    zero = torch.zeros(())
    return {"rgb": rgb,
            "va_entropy": torch.where(fused, attention_entropy(alpha).reshape(fused.shape), zero),
            "va_consistency": torch.where(fused, feature_consistency(fused_tokens).reshape(fused.shape), zero),
            "va_evaluated": fused.to(rgb.dtype)}


def _forward_and_gradients(field, compute, inputs, cotangents):
    field.zero_grad(set_to_none=True)
    for tensor in (inputs[0], inputs[3]):
        tensor.grad = None
    out = compute()
    loss = sum((out[key] * cotangent).sum() for key, cotangent in cotangents.items())
    loss.backward()
    grads = {name: p.grad.clone() if p.grad is not None else torch.zeros_like(p)
             for name, p in field.named_parameters()}
    for name, tensor in (("positions", inputs[0]), ("geo_features", inputs[3])):  # the density field's
        grads[name] = tensor.grad.clone() if tensor.grad is not None else torch.zeros_like(tensor)  # color: no x
    return {key: value.detach() for key, value in out.items()}, grads


@pytest.mark.parametrize("base", sorted(BASES))
@pytest.mark.parametrize("phase,k", [(BRANCHES, 1), (FUSION, 0), (FUSION, 1), (FUSION, 2)])
@pytest.mark.parametrize("shape", [(1, 1), (3, 5), (8, 16)])
def test_fast_path_matches_the_reference_forward_and_backward(base, phase, k, shape):
    field = _field(base, phase, k)
    inputs = _inputs(base, *shape, seed=shape[0] * 31 + shape[1])
    positions, directions, normals, geo, views, weights, rays = inputs
    gen = torch.Generator().manual_seed(7)
    keys = ["rgb"] + (["va_entropy", "va_consistency"] if phase == FUSION else [])
    reference_shapes = {"rgb": shape + (3,), "va_entropy": shape, "va_consistency": shape}
    cotangents = {key: torch.randn(reference_shapes[key], generator=gen) for key in keys}

    fast, fast_grads = _forward_and_gradients(
        field, lambda: field.color(positions, directions, normals, geo, views, weights=weights, ray_indices=rays),
        inputs, cotangents)
    ref, ref_grads = _forward_and_gradients(
        field, lambda: _reference(field, positions, directions, normals, geo, views, weights, rays, k),
        inputs, cotangents)

    assert set(keys) <= set(fast)
    for key in keys + (["va_evaluated"] if phase == FUSION else []):
        torch.testing.assert_close(fast[key], ref[key], atol=1e-6, rtol=1e-5, msg=key)
    assert fast_grads.keys() == ref_grads.keys()
    for name, grad in ref_grads.items():
        torch.testing.assert_close(fast_grads[name], grad, atol=1e-6, rtol=1e-5, msg=name)
    if phase == FUSION and bool(ref["va_evaluated"].any()):
        assert any(grad.abs().sum() > 0 for name, grad in fast_grads.items() if name.startswith("attention."))


@pytest.mark.parametrize("base", sorted(BASES))
def test_every_sample_path_matches_the_reference_with_nothing_culled(base):
    """Without rendering weights every sample of a training view is fused (and a novel view's sample keeps
    the shared color): the reference with every weight above the threshold and every sample fused."""
    field = _field(base, FUSION, 0)
    positions, directions, normals, geo, views, weights, rays = inputs = _inputs(base, 4, 6, seed=3)
    gen = torch.Generator().manual_seed(11)
    cotangents = {"rgb": torch.randn(4, 6, 3, generator=gen), "va_entropy": torch.randn(4, 6, generator=gen)}
    every = torch.ones_like(weights)
    fast, fast_grads = _forward_and_gradients(
        field, lambda: field.color(positions, directions, normals, geo, views), inputs, cotangents)
    ref, ref_grads = _forward_and_gradients(
        field, lambda: _reference(field, positions, directions, normals, geo, views, every, rays, 0), inputs,
        cotangents)
    training = views >= 0  # the every-sample path evaluates the regularizers on novel samples too
    torch.testing.assert_close(fast["rgb"], ref["rgb"], atol=1e-6, rtol=1e-5)
    torch.testing.assert_close(fast["va_entropy"][training], ref["va_entropy"][training], atol=1e-6, rtol=1e-5)
    cotangents["va_entropy"] = cotangents["va_entropy"] * training  # compare gradients of the same terms
    fast, fast_grads = _forward_and_gradients(
        field, lambda: field.color(positions, directions, normals, geo, views), inputs, cotangents)
    ref, ref_grads = _forward_and_gradients(
        field, lambda: _reference(field, positions, directions, normals, geo, views, every, rays, 0), inputs,
        cotangents)
    for name, grad in ref_grads.items():
        torch.testing.assert_close(fast_grads[name], grad, atol=1e-6, rtol=1e-5, msg=name)
