"""The SDF field's analytic gradient (``geometry_and_gradient``) against autograd's double-backward reference.

Tolerances: both paths evaluate the same chain rule (including torch's softplus threshold) and differ
only in the order of floating-point sums. In float64 they agree to ~5e-16 relative (measured), so the
tests ask for 1e-12; in float32 the measured difference is ~2.5e-7 relative (a few ulps after four
layers of 64-wide sums), and the tests ask for 1e-5: 40x headroom, and still far below anything
training could notice.
"""

import pytest
import torch
from torch import nn

from va_plugin.fields.encodings.positional import PositionalEncoding
from va_plugin.fields.sdf_field import SDFField, SDFFieldConfig


def _field(dtype=torch.float32, seed=0, **options) -> SDFField:
    torch.manual_seed(seed)
    field = SDFField(SDFFieldConfig(sdf_width=64, sdf_layers=4, geo_feature_dim=16, color_width=32, **options))
    with torch.no_grad():  # wake the frequency columns (zero at the geometric init) so the sin/cos terms count
        field.sdf_net.hidden[0].weight[:, 3:].normal_(0.0, 0.1)
    return field.to(dtype)


def _points(n=400, dtype=torch.float32, seed=1) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return ((torch.rand(n, 3, generator=generator) - 0.5) * 2.0).to(dtype)


def _reference(field, x):
    x = x.detach().requires_grad_(True)
    sdf, features = field.geometry(x)
    gradient = torch.autograd.grad(sdf, x, torch.ones_like(sdf), create_graph=True)[0]
    return sdf, features, gradient


def _loss(sdf, features, gradient):
    """Every way the model uses the gradient: eikonal, normals (color input, cosine term), plus the outputs."""
    normals = nn.functional.normalize(gradient, dim=-1, eps=1e-6)
    weights = torch.linspace(-1.0, 1.0, features.shape[-1], dtype=features.dtype)
    return (sdf.square().mean() + (features * weights).mean() + ((gradient.norm(dim=-1) - 1) ** 2).mean()
            + (normals * torch.tensor([0.3, -0.5, 0.8], dtype=sdf.dtype)).sum(-1).mean())


@pytest.mark.parametrize("dtype, rtol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
def test_gradient_values_match_autograd(dtype, rtol):
    field, x = _field(dtype), _points(dtype=dtype)
    sdf, features, gradient = field.geometry_and_gradient(x)
    ref_sdf, ref_features, ref_gradient = _reference(field, x)
    assert torch.equal(sdf, ref_sdf) and torch.equal(features, ref_features)
    scale = float(ref_gradient.detach().abs().max())
    assert 0.1 < scale < 100.0  # a gradient of sensible size, so the relative bound means something
    assert torch.allclose(gradient, ref_gradient, rtol=rtol, atol=rtol * scale)


def test_points_in_both_regimes_of_the_softplus():
    """beta z above torch's threshold (20) is the linear branch; the sigmoid slope must match there too."""
    field = _field(torch.float64)
    z = field.sdf_net.hidden[0](field.position_encoding(_points(dtype=torch.float64))) * field.config.softplus_beta
    assert (z > 20).any() and (z.abs() < 20).any()


@pytest.mark.parametrize("dtype, rtol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
def test_parameter_gradients_of_the_loss_match_double_backward(dtype, rtol):
    field, x = _field(dtype), _points(dtype=dtype)
    grads = {}
    for name, fn in (("autograd", lambda: _reference(field, x)), ("analytic", lambda: field.geometry_and_gradient(x))):
        field.zero_grad(set_to_none=True)
        _loss(*fn()).backward()
        grads[name] = {k: p.grad.clone() for k, p in field.sdf_net.named_parameters()}
    for key, ref in grads["autograd"].items():
        got = grads["analytic"][key]
        error = float((got - ref).norm() / ref.norm().clamp_min(1e-30))
        assert error < rtol, (key, error)


def test_relu_network_matches_autograd():
    field, x = _field(torch.float64), _points(dtype=torch.float64)
    field.sdf_net.activation = nn.ReLU()
    _, _, gradient = field.geometry_and_gradient(x)
    assert torch.allclose(gradient, _reference(field, x)[2], rtol=1e-12, atol=1e-12)


def test_unknown_activation_is_refused():
    field = _field()
    field.sdf_net.activation = nn.Tanh()
    with pytest.raises(NotImplementedError, match="sdf_gradient='autograd'"):
        field.geometry_and_gradient(_points(8))


def test_no_graph_without_grad_mode():
    field = _field()
    with torch.no_grad():
        outputs = field.geometry_and_gradient(_points(8))
    assert not any(t.requires_grad for t in outputs)


@pytest.mark.parametrize("include_input, in_dim, n_frequencies", [(True, 3, 6), (False, 2, 3), (True, 3, 0)])
def test_encoding_pull_back_is_the_vector_jacobian_product(include_input, in_dim, n_frequencies):
    encoding = PositionalEncoding(in_dim, n_frequencies, include_input=include_input).double()
    x = torch.rand(5, 7, in_dim, dtype=torch.float64, requires_grad=True)
    upstream = torch.randn(5, 7, encoding.output_dim, dtype=torch.float64)
    expected = torch.autograd.grad(encoding(x), x, upstream)[0]
    assert torch.allclose(encoding.pull_back(x.detach(), upstream), expected, rtol=1e-12, atol=1e-12)
