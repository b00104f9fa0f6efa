"""The InstantNGP-style density field: a hash grid, a small density MLP and a small color MLP."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

from va_plugin.fields.base import MLP, Field, HashGridFieldConfig
from va_plugin.fields.encodings.positional import optional_direction_encoding

TRUNC_EXP_MAX = 15.0
"""Largest exponent of :func:`trunc_exp` (exp(15) is about 3.3e6, far above any useful density)."""


class _TruncatedExp(torch.autograd.Function):
    """``exp`` whose forward input is clamped at ``TRUNC_EXP_MAX`` and whose gradient uses the input
    clamped to ``[-TRUNC_EXP_MAX, TRUNC_EXP_MAX]`` (InstantNGP's density activation): finite for any
    finite input, and a raw density that overshoots still gets a bounded gradient pulling it back."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(x)
        return torch.exp(x.clamp(max=TRUNC_EXP_MAX))

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (x,) = ctx.saved_tensors
        return grad * torch.exp(x.clamp(-TRUNC_EXP_MAX, TRUNC_EXP_MAX))


def trunc_exp(x: torch.Tensor) -> torch.Tensor:
    """Density from raw density: a truncated exponential, ``[...] -> [...]``, always finite and >= 0."""
    return _TruncatedExp.apply(x)


@dataclass
class DensityFieldConfig(HashGridFieldConfig):
    """An NGP field: hash grid -> density MLP -> (raw density, feature); color MLP on (feature, gamma(d))."""

    _target: type = field(default_factory=lambda: DensityField)
    hidden_width: int = 64
    """Hidden width of the density MLP."""
    hidden_layers: int = 1
    """Hidden layers of the density MLP."""
    geo_feature_dim: int = 15
    """Width of the geometry feature passed to the color MLP (InstantNGP: 15)."""
    direction_frequencies: int = 4
    """Frequency bands of gamma(d) in the color MLP; -1 leaves the direction out (view-independent
    color, which few input views cannot mislead)."""
    color_width: int = 64
    """Hidden width of the color MLP; f_shared has this width."""
    color_layers: int = 2
    """Hidden layers of the color MLP."""


class DensityField(Field):
    geometry_kind = "density"

    def __init__(self, config: DensityFieldConfig) -> None:
        super().__init__()
        self.config = config
        self.bound = float(config.bound)
        self.encoding = config.make_encoding()
        self.density_net = MLP(self.encoding.output_dim, config.hidden_width, config.hidden_layers,
                               1 + config.geo_feature_dim)
        self.direction_encoding = optional_direction_encoding(config.direction_frequencies)
        direction_dim = self.direction_encoding.output_dim if self.direction_encoding is not None else 0
        self.color_net = MLP(direction_dim + config.geo_feature_dim, config.color_width,
                             config.color_layers, 3, out_activation=nn.Sigmoid())
        self.feature_dim = config.color_width

    def geometry(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``positions [..., 3]`` -> (raw density ``[..., 1]``, before :func:`trunc_exp`; feature ``[..., G]``)."""
        out = self.density_net(self.encoding(positions))
        return out[..., :1], out[..., 1:]

    def update_step(self, step: int, schedule_steps: int) -> None:
        self.encoding.set_active_levels(self.config.active_levels(step, schedule_steps))

    def density(self, positions: torch.Tensor) -> torch.Tensor:
        """Activated density ``[..., 1]`` (>= 0)."""
        return trunc_exp(self.geometry(positions)[0])

    def color_features(self, positions, directions, normals, geo_features) -> torch.Tensor:
        # The geometry feature already encodes the position; normals are unused (a density field has none).
        if self.direction_encoding is None:
            return self.color_net.features(geo_features)
        return self.color_net.features(torch.cat([self.direction_encoding(directions), geo_features], dim=-1))

    def decode_color(self, features: torch.Tensor) -> torch.Tensor:
        return self.color_net.head(features)
