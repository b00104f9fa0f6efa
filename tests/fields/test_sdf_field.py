import torch

from va_plugin.fields.encodings.positional import PositionalEncoding
from va_plugin.fields.sdf_field import SDFField, SDFFieldConfig


def test_positional_encoding_hand_computed():
    pe = PositionalEncoding(1, 2)
    x = torch.tensor([[0.5]])
    expected = torch.tensor([[0.5, torch.sin(torch.tensor(0.5)), torch.sin(torch.tensor(1.0)),
                              torch.cos(torch.tensor(0.5)), torch.cos(torch.tensor(1.0))]])
    assert pe.output_dim == 5
    assert torch.allclose(pe(x), expected)


def test_geometric_init_is_close_to_a_sphere():
    torch.manual_seed(0)
    field = SDFField(SDFFieldConfig(sdf_width=128, sdf_layers=4, init_radius=0.5))
    directions = torch.nn.functional.normalize(torch.randn(200, 3), dim=-1)
    with torch.no_grad():
        for radius in (0.2, 0.5, 0.8):
            # finite width makes the init only approximately radial: allow 0.1 on average
            error = (field.sdf(directions * radius)[:, 0] - (radius - 0.5)).abs()
            assert error.mean() < 0.1, radius
        # inside negative near the centre, outside positive near the bound
        assert (field.sdf(directions * 0.05) < 0).all() and (field.sdf(directions * 0.95) > 0).all()


def test_sdf_gradient_is_unit_at_init():
    torch.manual_seed(0)
    field = SDFField(SDFFieldConfig(sdf_width=128, sdf_layers=4))
    x = (torch.rand(500, 3) - 0.5).requires_grad_(True)
    grad = torch.autograd.grad(field.sdf(x).sum(), x)[0]
    assert 0.8 < float(grad.norm(dim=-1).mean()) < 1.2


def test_color_shapes_and_range():
    field = SDFField(SDFFieldConfig(sdf_width=32, sdf_layers=2, color_width=16))
    x = torch.rand(4, 5, 3)
    _, feat = field.geometry(x)
    rgb = field.color(x, torch.rand(4, 5, 3), torch.rand(4, 5, 3), feat)["rgb"]
    assert rgb.shape == (4, 5, 3) and (rgb >= 0).all() and (rgb <= 1).all()
    assert field.feature_dim == 16
