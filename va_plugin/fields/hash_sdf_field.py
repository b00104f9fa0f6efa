"""A hash-grid SDF field: multiresolution hash encoding, a small SDF MLP and a small color MLP.

The capacity sits in the hash tables, so a step is cheap. The levels open coarse to fine (all open at
once fit each view with high-frequency noise before the shape is right). The color is
view-independent by default: with few input directions a direction input overfits each view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import nn

from va_plugin.errors import ConfigError
from va_plugin.fields.base import MLP, Field, HashGridFieldConfig
from va_plugin.fields.encodings.hash_grid import CPU_CHUNK_POINTS
from va_plugin.fields.encodings.positional import optional_direction_encoding
from va_plugin.fields.sdf_field import has_analytic_slope, mlp_with_input_gradient

SDF_GRADIENT_KINDS = ("analytic", "finite_difference")

# Vertices of a regular tetrahedron: sum_k v_k f(x + e v_k) / (4 e) is a second-order estimate of
# grad f(x) from four evaluations (central differences need six).
_TETRAHEDRON = ((1.0, -1.0, -1.0), (-1.0, -1.0, 1.0), (-1.0, 1.0, -1.0), (1.0, 1.0, 1.0))


@dataclass
class HashSDFFieldConfig(HashGridFieldConfig):
    """A NeuS field on a hash grid: SDF MLP on (x, hash(x)), color MLP on (feature, normal[, gamma(d)])."""

    _target: type = field(default_factory=lambda: HashSDFField)
    coarse_to_fine_fraction: float = 0.3
    """Share of the step budget after which every grid level is open (0: all open from the start)."""
    sdf_width: int = 64
    """Hidden width of the SDF MLP."""
    sdf_layers: int = 1
    """Hidden layers of the SDF MLP."""
    geo_feature_dim: int = 15
    """Width of the geometry feature passed to the color MLP."""
    softplus_beta: float = 100.0
    """Sharpness of the SDF MLP's softplus activations."""
    init_radius: float = 0.5
    """Radius of the sphere the SDF starts as."""
    color_width: int = 64
    """Hidden width of the color MLP; f_shared has this width."""
    color_layers: int = 2
    """Hidden layers of the color MLP."""
    use_normal: bool = True
    """Feed the surface normal to the color MLP."""
    direction_frequencies: int = -1
    """The view direction in the color MLP: -1 leaves it out (view-independent color, the default
    for few views), 0 feeds the raw direction, k > 0 adds k frequency bands."""
    sdf_gradient: str = "analytic"
    """"analytic" (the grid's trilinear derivative) or "finite_difference" (four tetrahedral SDF
    evaluations: smoother normals, about 4x the geometry cost)."""
    finite_difference_cells: float = 0.5
    """Step of the finite differences, in cells of the finest open level."""


class HashSDFField(Field):
    geometry_kind = "sdf"

    def __init__(self, config: HashSDFFieldConfig) -> None:
        super().__init__()
        if config.sdf_gradient not in SDF_GRADIENT_KINDS:
            raise ConfigError(f"field.sdf_gradient must be one of {', '.join(SDF_GRADIENT_KINDS)}, "
                              f"got {config.sdf_gradient!r}")
        if not 0 < config.init_radius < config.bound:
            raise ConfigError(f"field.init_radius must be in (0, bound = {config.bound}): the starting sphere has to "
                              f"fit inside the hash grid, got {config.init_radius}")
        self.config = config
        self.encoding = config.make_encoding()
        self.sdf_net = MLP(3 + self.encoding.output_dim, config.sdf_width, config.sdf_layers,
                           1 + config.geo_feature_dim, activation=nn.Softplus(beta=config.softplus_beta))
        self.direction_encoding = optional_direction_encoding(config.direction_frequencies)
        color_in = config.geo_feature_dim + (3 if config.use_normal else 0) + \
            (self.direction_encoding.output_dim if self.direction_encoding is not None else 0)
        self.color_net = MLP(color_in, config.color_width, config.color_layers, 3, out_activation=nn.Sigmoid())
        self.feature_dim = config.color_width
        self._sphere_init()

    def _sphere_init(self) -> None:
        """Start as the SDF of a sphere of ``init_radius`` from the raw coordinates (the tables start near
        0): one hidden layer gets unit pairs +-u_k over a Fibonacci lattice, so sum_k softplus(+-u_k . x)
        ~ (width / 4) |x|; deeper networks take IGR's initialisation. The output bias puts the zero
        level set on the sphere."""
        layers = list(self.sdf_net.hidden)
        out = self.sdf_net.out
        with torch.no_grad():
            for layer in layers:
                nn.init.normal_(layer.weight, 0.0, math.sqrt(2.0) / math.sqrt(layer.out_features))
                nn.init.zeros_(layer.bias)
            width = layers[0].out_features
            if len(layers) == 1 and width >= 8:
                pairs = fibonacci_sphere(width // 2)
                layers[0].weight[: 2 * len(pairs), :3] = torch.cat([pairs, -pairs])
                layers[0].weight[2 * len(pairs):, :3] = 0.0
                nn.init.constant_(out.weight, 4.0 / (2 * len(pairs)))
            else:
                nn.init.normal_(out.weight, math.sqrt(math.pi) / math.sqrt(out.in_features), 1e-4)
            # the geometry features start small and varied rather than as copies of the SDF
            nn.init.normal_(out.weight[1:], 0.0, 1.0 / math.sqrt(out.in_features))
            nn.init.zeros_(out.bias)
            on_sphere = fibonacci_sphere(256) * self.config.init_radius
            out.bias[0] = -self.sdf_net(self._inputs(on_sphere))[:, 0].mean()

    # -- schedule -------------------------------------------------------------------------------
    def update_step(self, step: int, schedule_steps: int) -> None:
        active = self.config.active_levels(step, schedule_steps)
        self.encoding.set_active_levels(active)

    def finite_difference_step(self) -> float:
        """Step (world units) of the finite-difference gradient: a fraction of the finest open cell."""
        finest = self.encoding.resolutions[max(self.encoding.n_active_levels, 1) - 1]
        return self.config.finite_difference_cells * 2.0 * self.config.bound / finest

    # -- geometry -------------------------------------------------------------------------------
    def _inputs(self, positions: torch.Tensor) -> torch.Tensor:
        """The SDF network's input ``[..., 3 + L * F]``: ``positions [..., 3]`` and their grid encoding."""
        return torch.cat([positions, self.encoding(positions)], dim=-1)

    def geometry(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.sdf_net(self._inputs(positions))
        return out[..., :1], out[..., 1:]

    def sdf(self, positions: torch.Tensor) -> torch.Tensor:
        """SDF only, ``[..., 1]``."""
        return self.geometry(positions)[0]

    @property
    def bound(self) -> float:
        return float(self.config.bound)

    @property
    def analytic_sdf_gradient(self) -> bool:
        """Finite differences need only the SDF; the grid's derivative needs the chain rule through the MLP."""
        return self.config.sdf_gradient == "finite_difference" or has_analytic_slope(self.sdf_net)

    def geometry_and_gradient(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """SDF ``[..., 1]``, geometry feature ``[..., G]`` and the SDF's gradient ``[..., 3]``, with a
        graph that one ordinary backward pass trains from (no double backward)."""
        if self.config.sdf_gradient == "finite_difference":
            return self._finite_difference(positions)
        flat = positions.reshape(-1, 3)
        if torch.is_grad_enabled() or flat.device.type != "cpu" or flat.shape[0] <= CPU_CHUNK_POINTS:
            out, gradient = self._sdf_and_gradient(flat)
        else:  # rendering many points on CPU: the grid's cache-sized chunks, nothing recorded
            parts = [self._sdf_and_gradient(flat[start:start + CPU_CHUNK_POINTS])
                     for start in range(0, flat.shape[0], CPU_CHUNK_POINTS)]
            out, gradient = torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])
        lead = positions.shape[:-1]
        return out[:, :1].reshape(*lead, 1), out[:, 1:].reshape(*lead, out.shape[-1] - 1), gradient.reshape(*lead, 3)

    def _sdf_and_gradient(self, flat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The SDF MLP's output ``[n, 1 + G]`` and the SDF's gradient ``[n, 3]`` at points ``[n, 3]``."""
        encoded, pullback = self.encoding.forward_with_pullback(flat)
        out, grad_in = mlp_with_input_gradient(self.sdf_net, torch.cat([flat, encoded], dim=-1))
        return out, grad_in[:, :3] + pullback(grad_in[:, 3:])

    def _finite_difference(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """SDF ``[..., 1]``, geometry feature ``[..., G]`` and the SDF's gradient ``[..., 3]`` from four
        probes on a tetrahedron around each of ``positions [..., 3]``."""
        step = self.finite_difference_step()
        vertices = positions.new_tensor(_TETRAHEDRON)  # [4, 3]
        sdf, features = self.geometry(positions)
        probes = self.sdf(positions[..., None, :] + step * vertices)[..., 0]  # [..., 4]
        gradient = (probes[..., None] * vertices).sum(-2) / (4.0 * step)
        return sdf, features, gradient

    # -- color ---------------------------------------------------------------------------------
    def color_features(self, positions, directions, normals, geo_features) -> torch.Tensor:
        parts = [geo_features]
        if self.config.use_normal:
            parts.append(normals)
        if self.direction_encoding is not None:
            parts.append(self.direction_encoding(directions))
        return self.color_net.features(torch.cat(parts, dim=-1))

    def decode_color(self, features: torch.Tensor) -> torch.Tensor:
        return self.color_net.head(features)


def fibonacci_sphere(n: int) -> torch.Tensor:
    """``n`` unit vectors spread evenly over the sphere (a Fibonacci lattice), ``[n, 3]``."""
    k = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1.0 - 2.0 * k / n
    radius = torch.sqrt((1.0 - z * z).clamp_min(0.0))
    angle = math.pi * (3.0 - math.sqrt(5.0)) * k
    return torch.stack([radius * torch.cos(angle), radius * torch.sin(angle), z], dim=-1).float()
