"""The hash-grid SDF field against plain references: the encoding's Jacobian against autograd, the
analytic SDF gradient and its eikonal loss's parameter gradients against double backward, the
finite-difference gradient on a known sphere, and the coarse-to-fine schedule."""

import pytest
import torch

from va_plugin.errors import ConfigError
from va_plugin.fields.encodings.hash_grid import HashGridEncoding
from va_plugin.fields.hash_sdf_field import HashSDFFieldConfig


def _small_field(**overrides):
    torch.manual_seed(0)
    options = dict(n_levels=4, log2_hashmap_size=10, base_resolution=4, max_resolution=32, start_levels=4)
    options.update(overrides)
    field = HashSDFFieldConfig(**options).setup()
    with torch.no_grad():  # a trained-looking table: the grid then shapes the SDF as much as x does
        field.encoding.table.uniform_(-0.2, 0.2)
    return field


def _points(n=64, seed=1, extent=0.9):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, 3, generator=g) * 2 * extent - extent


@pytest.mark.parametrize("active", [4, 2, 0])
def test_encoding_pullback_matches_autograd(active):
    """The pulled-back derivative is autograd's vector-Jacobian product of the encoding."""
    torch.manual_seed(0)
    enc = HashGridEncoding(n_levels=4, n_features_per_level=2, log2_hashmap_size=8, base_resolution=3,
                           max_resolution=20, init_scale=1.0)  # 2 dense levels, 2 hashed
    enc.set_active_levels(active)
    x = _points(20).requires_grad_(True)
    cotangent = torch.randn(20, enc.output_dim, generator=torch.Generator().manual_seed(2))
    values, pullback = enc.forward_with_pullback(x.detach())
    assert torch.equal(values, enc(x.detach()))
    encoded = enc(x)
    reference = torch.autograd.grad(encoded, x, cotangent)[0] if encoded.requires_grad else torch.zeros_like(x)
    torch.testing.assert_close(pullback(cotangent), reference, atol=1e-5, rtol=1e-5)


def test_encoding_pullback_is_zero_along_a_clamped_axis():
    enc = HashGridEncoding(n_levels=2, log2_hashmap_size=8, base_resolution=4, max_resolution=8, init_scale=1.0)
    _, pullback = enc.forward_with_pullback(torch.tensor([[1.5, 0.1, -0.2]]))
    grad = pullback(torch.ones(1, enc.output_dim))
    assert grad[0, 0] == 0 and grad[0, 1:].abs().sum() > 0


def test_analytic_gradient_matches_autograd():
    field = _small_field()
    x = _points()
    sdf, features, gradient = field.geometry_and_gradient(x)
    xr = x.clone().requires_grad_(True)
    sdf_ref, features_ref = field.geometry(xr)
    (grad_ref,) = torch.autograd.grad(sdf_ref.sum(), xr)
    torch.testing.assert_close(sdf, sdf_ref)
    torch.testing.assert_close(features, features_ref)
    torch.testing.assert_close(gradient, grad_ref, atol=1e-5, rtol=1e-4)
    with torch.no_grad():  # the chunked gradient-free path (rendering) gives the same numbers
        many = _points(40000, seed=5)
        chunked = field.geometry_and_gradient(many)
    direct = [t.detach() for t in field.geometry_and_gradient(many)]
    for a, b in zip(chunked, direct):
        torch.testing.assert_close(a, b)


def test_eikonal_parameter_gradients_match_double_backward():
    """One ordinary backward through the analytic path trains the table and the MLP exactly as
    autograd's double backward of the same eikonal loss does."""
    field = _small_field()
    x = _points()
    params = list(field.sdf_net.parameters()) + [field.encoding.table]

    def grads():
        out = [p.grad.clone() if p.grad is not None else torch.zeros_like(p) for p in params]
        field.zero_grad()
        return out

    _, _, gradient = field.geometry_and_gradient(x)
    ((gradient.norm(dim=-1) - 1.0) ** 2).mean().backward()
    analytic = grads()
    xr = x.clone().requires_grad_(True)
    (reference,) = torch.autograd.grad(field.sdf(xr).sum(), xr, create_graph=True)
    ((reference.norm(dim=-1) - 1.0) ** 2).mean().backward()
    double = grads()
    assert any(g.abs().sum() > 0 for g in double[-1:]), "the table must receive an eikonal gradient"
    for a, b in zip(analytic, double):
        torch.testing.assert_close(a, b, atol=1e-6, rtol=1e-4)


def test_starts_as_a_sphere_and_finite_differences_find_its_normal():
    field = HashSDFFieldConfig(sdf_gradient="finite_difference", init_radius=0.5).setup()
    directions = torch.nn.functional.normalize(_points(200, seed=3), dim=-1)
    surface_far = field.sdf(directions * 0.8)[..., 0]
    assert torch.all(surface_far > 0.1) and torch.all(field.sdf(directions * 0.1)[..., 0] < 0)
    _, _, gradient = field.geometry_and_gradient(directions * 0.5)
    cosine = (torch.nn.functional.normalize(gradient, dim=-1) * directions).sum(-1)
    assert cosine.min() > 0.9  # the sphere's outward normal
    # the finite-difference step follows the finest open level
    assert field.finite_difference_step() == pytest.approx(0.5 * 2.0 / field.encoding.resolutions[3])


def test_finite_difference_gradient_approximates_analytic_on_smooth_field():
    field = _small_field(sdf_gradient="finite_difference", finite_difference_cells=0.01)
    with torch.no_grad():
        field.encoding.table.zero_()  # the MLP of x alone: smooth, so small steps converge
    x = _points()
    _, _, fd = field.geometry_and_gradient(x)
    field.config.sdf_gradient = "analytic"
    _, _, exact = field.geometry_and_gradient(x)
    torch.testing.assert_close(fd, exact, atol=2e-3, rtol=1e-2)


def test_levels_open_coarse_to_fine():
    field = HashSDFFieldConfig(n_levels=8, start_levels=2, coarse_to_fine_fraction=0.5).setup()
    assert field.encoding.n_active_levels == 2
    opened = []
    for step in range(0, 100, 5):
        field.update_step(step, 100)
        opened.append(field.encoding.n_active_levels)
    assert opened[0] >= 2 and opened == sorted(opened) and opened[-1] == 8
    assert field.config.active_levels(50, 100) == 8 and field.config.active_levels(24, 100) < 8
    x = _points(10)
    field.update_step(0, 100)
    encoded = field.encoding(x)
    width = field.encoding.n_active_levels * field.encoding.n_features_per_level
    assert torch.all(encoded[:, width:] == 0)
    assert HashSDFFieldConfig(coarse_to_fine_fraction=0.0).setup().encoding.n_active_levels == 12


def test_color_inputs_follow_the_config():
    x = _points(5)
    normals = torch.nn.functional.normalize(x, dim=-1)
    for freqs, use_normal in [(-1, True), (0, False), (2, True)]:
        field = HashSDFFieldConfig(direction_frequencies=freqs, use_normal=use_normal).setup()
        _, feat = field.geometry(x)
        rgb = field.color(x, normals, normals, feat)["rgb"]
        assert rgb.shape == (5, 3) and torch.all((rgb >= 0) & (rgb <= 1))
        other_dirs = field.color(x, -normals, normals, feat)["rgb"]
        assert torch.equal(rgb, other_dirs) == (freqs < 0)


@pytest.mark.parametrize("bad", [dict(sdf_gradient="exact"), dict(start_levels=20), dict(bound=0.0),
                                 dict(coarse_to_fine_fraction=1.5), dict(direction_frequencies=-2)])
def test_bad_options_are_one_line_errors(bad):
    with pytest.raises(ConfigError):
        HashSDFFieldConfig(**bad).setup()
