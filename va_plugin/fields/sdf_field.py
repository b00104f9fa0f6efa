"""The NeuS SDF field: an SDF network with geometric initialisation and a color network."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import nn

from va_plugin.fields.base import MLP, Field, FieldConfig
from va_plugin.fields.encodings.positional import PositionalEncoding


@dataclass
class SDFFieldConfig(FieldConfig):
    """A NeuS field: SDF network on gamma(x) and a color network on (x, normal, gamma(d), feature)."""

    _target: type = field(default_factory=lambda: SDFField)
    position_frequencies: int = 6
    """Frequency bands of gamma(x) (the paper uses 6)."""
    direction_frequencies: int = 4
    """Frequency bands of gamma(d) (the paper uses 4)."""
    sdf_width: int = 256
    """Hidden width of the SDF network (the paper's shared MLP: 4 x 256)."""
    sdf_layers: int = 4
    """Hidden layers of the SDF network."""
    geo_feature_dim: int = 64
    """Width of the geometry feature passed to the color network."""
    color_width: int = 128
    """Hidden width of the color network; f_shared has this width."""
    color_layers: int = 2
    """Hidden layers of the color network."""
    init_radius: float = 0.5
    """Radius of the sphere the SDF starts as (geometric initialisation)."""
    softplus_beta: float = 100.0
    """Sharpness of the SDF network's softplus activations."""


class SDFField(Field):
    geometry_kind = "sdf"

    def __init__(self, config: SDFFieldConfig) -> None:
        super().__init__()
        self.config = config
        self.position_encoding = PositionalEncoding(3, config.position_frequencies)
        self.direction_encoding = PositionalEncoding(3, config.direction_frequencies)
        self.sdf_net = MLP(self.position_encoding.output_dim, config.sdf_width, config.sdf_layers,
                           1 + config.geo_feature_dim, activation=nn.Softplus(beta=config.softplus_beta))
        color_in = 3 + 3 + self.direction_encoding.output_dim + config.geo_feature_dim
        self.color_net = MLP(color_in, config.color_width, config.color_layers, 3, out_activation=nn.Sigmoid())
        self.feature_dim = config.color_width
        self._geometric_init()

    def _geometric_init(self) -> None:
        """Start as the SDF of a sphere of ``init_radius`` (IGR/SAL initialisation, as in NeuS)."""
        layers = list(self.sdf_net.hidden)
        with torch.no_grad():
            for k, layer in enumerate(layers):
                nn.init.normal_(layer.weight, 0.0, math.sqrt(2.0) / math.sqrt(layer.out_features))
                nn.init.zeros_(layer.bias)
                if k == 0:
                    layer.weight[:, 3:] = 0.0  # frequencies start silent: the sphere comes from x alone
            out = self.sdf_net.out
            nn.init.normal_(out.weight, math.sqrt(math.pi) / math.sqrt(out.in_features), 1e-4)
            nn.init.constant_(out.bias, -self.config.init_radius)

    def geometry(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.sdf_net(self.position_encoding(positions))
        return out[..., :1], out[..., 1:]

    @property
    def analytic_sdf_gradient(self) -> bool:
        """The hand-written chain rule covers the SDF network (its activation and linear output)."""
        return has_analytic_slope(self.sdf_net)

    def geometry_and_gradient(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """SDF ``[..., 1]``, geometry feature ``[..., G]`` and the SDF's gradient ``[..., 3]`` in one pass
        (:func:`mlp_with_input_gradient`, pulled back through the encoding): losses on the gradient need
        one backward pass, not a double backward. Matches ``torch.autograd.grad`` to float rounding."""
        out, grad = mlp_with_input_gradient(self.sdf_net, self.position_encoding(positions))
        return out[..., :1], out[..., 1:], self.position_encoding.pull_back(positions, grad)

    def sdf(self, positions: torch.Tensor) -> torch.Tensor:
        """SDF only, ``[..., 1]``."""
        return self.geometry(positions)[0]

    def color_features(self, positions, directions, normals, geo_features) -> torch.Tensor:
        x = torch.cat([positions, normals, self.direction_encoding(directions), geo_features], dim=-1)
        return self.color_net.features(x)

    def decode_color(self, features: torch.Tensor) -> torch.Tensor:
        return self.color_net.head(features)


def mlp_with_input_gradient(net: MLP, inputs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """An MLP's output ``[..., out]`` and the derivative of its first output with respect to its
    input ``[..., in]``, the chain rule written out next to the forward pass.

    With z_k = W_k h_(k-1) + b_k and h_k = a(z_k): dy/dh_(k-1) = (dy/dh_k * a'(z_k)) W_k, started
    from the first row of the (linear) output layer. Every step is differentiable once, so a loss on
    the derivative trains the weights with one ordinary backward pass."""
    if net.out_activation is not None:
        raise NotImplementedError("the analytic SDF gradient assumes a linear output layer")
    h, slopes = inputs, []
    for layer in net.hidden:
        h, slope = _activation_and_slope(net.activation, layer(h))
        slopes.append(slope)
    out = net.out(h)
    grad = net.out.weight[0]  # d y / d h of the last hidden layer, broadcast over the points
    for layer, slope in zip(reversed(net.hidden), reversed(slopes)):
        grad = (grad * slope) @ layer.weight
    return out, grad


ANALYTIC_ACTIVATIONS = (nn.Softplus, nn.ReLU)
"""The activations :func:`mlp_with_input_gradient` has the slope of."""


def has_analytic_slope(net: MLP) -> bool:
    """Whether :func:`mlp_with_input_gradient` handles ``net``: a covered activation, a linear output layer."""
    return net.out_activation is None and isinstance(net.activation, ANALYTIC_ACTIVATIONS)


def _activation_and_slope(activation: nn.Module, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """a(z) and a'(z) of the SDF network's activation, both differentiable in ``z``."""
    if isinstance(activation, nn.Softplus):
        return _SoftplusAndSlope.apply(z, float(activation.beta), float(activation.threshold))
    if isinstance(activation, nn.ReLU):
        return activation(z), (z > 0).to(z.dtype)
    raise NotImplementedError(f"no analytic slope for {type(activation).__name__}; use sdf_gradient='autograd'")


class _SoftplusAndSlope(torch.autograd.Function):
    """h = softplus_beta(z) and s = dh/dz = sigmoid(beta z), as torch's Softplus defines them (linear
    above ``threshold`` in units of beta z). One autograd node that keeps only s (ds/dz = beta s (1 - s))."""

    @staticmethod
    def forward(ctx, z: torch.Tensor, beta: float, threshold: float):
        scaled = z * beta
        if math.exp(-threshold) < 0.5 * torch.finfo(z.dtype).eps:
            # float32: above the threshold the sigmoid has rounded to exactly 1 (1 - sigmoid(20) = 2e-9)
            slope = scaled.sigmoid_()
        else:  # finer dtypes: switch to torch's linear branch explicitly
            slope = torch.where(scaled > threshold, torch.ones_like(scaled), torch.sigmoid(scaled))
        ctx.save_for_backward(slope)
        ctx.beta = beta
        return nn.functional.softplus(z, beta, threshold), slope

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_h: torch.Tensor | None, grad_slope: torch.Tensor | None):
        (slope,) = ctx.saved_tensors
        if grad_slope is None:
            return (None if grad_h is None else grad_h * slope), None, None
        grad = torch.mul(grad_slope, slope).neg_().add_(grad_slope)  # grad_slope (1 - s)
        grad.mul_(ctx.beta)
        if grad_h is not None:
            grad.add_(grad_h)
        return grad.mul_(slope), None, None
