import math

import pytest
import torch

from va_plugin.errors import ConfigError
from va_plugin.fields.density_field import TRUNC_EXP_MAX, DensityField, DensityFieldConfig, trunc_exp


def _small_field(**changes) -> DensityField:
    torch.manual_seed(0)
    options = dict(n_levels=4, log2_hashmap_size=12, max_resolution=64, hidden_width=16, color_width=16)
    options.update(changes)
    return DensityField(DensityFieldConfig(**options))


def test_trunc_exp_is_finite_at_huge_inputs():
    x = torch.tensor([-1e30, -1e4, -20.0, 0.0, 1.0, 20.0, 1e4, 1e30], requires_grad=True)
    y = trunc_exp(x)
    y.sum().backward()
    cap = math.exp(TRUNC_EXP_MAX)
    assert torch.isfinite(y).all() and torch.isfinite(x.grad).all()
    assert (y >= 0).all() and float(y.detach().max()) == pytest.approx(cap, rel=1e-6)
    assert torch.allclose(y[3:5], torch.exp(x[3:5].detach()))
    # the gradient keeps flowing beyond the cap (bounded by exp(15)) and is clamped below too
    assert float(x.grad[-1]) == pytest.approx(cap, rel=1e-6)
    assert float(x.grad[0]) == pytest.approx(math.exp(-TRUNC_EXP_MAX), rel=1e-6)


def test_field_interface_shapes_and_ranges():
    field = _small_field()
    x = torch.rand(4, 5, 3) * 1.6 - 0.8
    raw, features = field.geometry(x)
    assert raw.shape == (4, 5, 1) and features.shape == (4, 5, 15)
    assert field.geometry_kind == "density" and field.feature_dim == 16
    assert torch.allclose(field.density(x), trunc_exp(raw))
    f_shared = field.color_features(x, torch.rand(4, 5, 3), torch.zeros(4, 5, 3), features)
    assert f_shared.shape == (4, 5, field.feature_dim)
    rgb = field.decode_color(f_shared)
    assert rgb.shape == (4, 5, 3) and (rgb >= 0).all() and (rgb <= 1).all()
    camera = torch.full((4, 5), -1, dtype=torch.long)
    assert field.color(x, torch.rand(4, 5, 3), torch.zeros(4, 5, 3), features, camera)["rgb"].shape == (4, 5, 3)


def test_density_gradient_reaches_the_hash_table():
    field = _small_field()
    field.density(torch.rand(64, 3) - 0.5).sum().backward()
    assert field.encoding.table.grad is not None and field.encoding.table.grad.abs().sum() > 0
    assert all(torch.isfinite(p.grad).all() for p in field.parameters() if p.grad is not None)


def test_empty_input_keeps_a_graph():
    field = _small_field()
    raw, _features = field.geometry(torch.zeros(0, 3))
    assert raw.shape == (0, 1) and raw.requires_grad
    raw.sum().backward()


def test_bad_bound_is_a_config_error():
    with pytest.raises(ConfigError, match="bound"):
        DensityField(DensityFieldConfig(bound=-1.0))


def test_density_field_can_open_its_levels_coarse_to_fine():
    from va_plugin.fields.density_field import DensityFieldConfig

    assert DensityFieldConfig().setup().encoding.n_active_levels == 12  # default: every level from the start
    field = DensityFieldConfig(start_levels=3, coarse_to_fine_fraction=0.5).setup()
    assert field.encoding.n_active_levels == 3
    field.update_step(25, 100)
    assert 3 < field.encoding.n_active_levels < 12
    field.update_step(50, 100)
    assert field.encoding.n_active_levels == 12
