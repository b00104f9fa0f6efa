"""The Field interface shared by every backbone: a point's geometry (SDF or density, plus a feature)
and its color, split into ``color_features`` (f_shared) and ``decode_color`` so the view-adaptive
wrapper can act between the halves.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import nn

from va_plugin.config import InstantiateConfig
from va_plugin.errors import ConfigError
from va_plugin.fields.encodings.hash_grid import HashGridEncoding


@dataclass
class FieldConfig(InstantiateConfig):
    """Options every field has."""

    def setup_for_scene(self, scene):
        """The field for a scene (``models.base.SceneInfo``); overridden by the per-view wrapper."""
        return self.setup()


@dataclass
class HashGridFieldConfig(FieldConfig):
    """Options of fields built on a multiresolution hash grid (the density field, the hash SDF field)."""

    n_levels: int = 12
    """Levels of the hash grid."""
    features_per_level: int = 2
    """Features stored per grid vertex."""
    log2_hashmap_size: int = 17
    """log2 of the most table entries a level may have."""
    base_resolution: int = 16
    """Cells per axis of the coarsest level."""
    max_resolution: int = 512
    """Cells per axis of the finest level."""
    bound: float = 1.0
    """The grid covers [-bound, bound]^3; it must hold the scene's bounding sphere."""
    start_levels: int = 4
    """Levels open at step 0 when the grid opens coarse to fine; the others open one by one."""
    coarse_to_fine_fraction: float = 0.0
    """Share of the step budget after which every level is open (0: all open from the start)."""

    def active_levels(self, step: int, schedule_steps: int) -> int:
        """Open levels at ``step``: ``start_levels``, then linearly more until every level is open at
        ``coarse_to_fine_fraction * schedule_steps``."""
        span = self.coarse_to_fine_fraction * schedule_steps
        if span <= 0 or step >= span:
            return self.n_levels
        return min(self.n_levels, self.start_levels + int((self.n_levels - self.start_levels) * step / span))

    def make_encoding(self):
        """The field's :class:`HashGridEncoding` (a one-line error for a bound that is not positive)."""

        if self.bound <= 0:
            raise ConfigError(f"field.bound must be positive, got {self.bound}")
        if not 0 <= self.start_levels <= self.n_levels:
            raise ConfigError(f"field.start_levels must be in [0, {self.n_levels}], got {self.start_levels}")
        if not 0.0 <= self.coarse_to_fine_fraction <= 1.0:
            raise ConfigError(f"field.coarse_to_fine_fraction must be in [0, 1], got {self.coarse_to_fine_fraction}")
        encoding = HashGridEncoding(n_levels=self.n_levels, n_features_per_level=self.features_per_level,
                                    log2_hashmap_size=self.log2_hashmap_size, base_resolution=self.base_resolution,
                                    max_resolution=self.max_resolution, bound=self.bound)
        encoding.set_active_levels(self.active_levels(0, 1))
        return encoding


class Field(nn.Module):
    """Base class of geometry + color fields; subclasses set ``geometry_kind`` ("sdf" or "density") and
    ``feature_dim`` (width of f_shared).

    The optional capabilities are declared here, with defaults for a field without them; models read the
    declarations instead of probing for attributes: ``analytic_sdf_gradient`` (``geometry_and_gradient``
    works), ``has_view_branches`` (the per-view wrapper: ``branches_active``, ``attention_matrix``),
    ``bound``, ``current_phase`` and the hooks ``extra_losses``, ``training_callbacks`` and ``diagnostics``."""

    geometry_kind: str = "sdf"
    feature_dim: int = 0
    analytic_sdf_gradient: bool = False
    """Whether :meth:`geometry_and_gradient` gives the SDF's gradient in the forward pass (False: the model
    takes the gradient by autograd)."""
    has_view_branches: bool = False
    """Whether the field is the view-adaptive wrapper (per-view branches, their phases and attention)."""
    bound: float | None = None
    """The field covers [-bound, bound]^3 (a hash grid's extent); None where it is not bounded."""
    current_phase: int = 1
    """The training phase the field is in (the paper's Sec. 3.4: 1 trains the shared field alone; the
    view-adaptive wrapper moves to 2 and 3, a field without phases stays in 1)."""

    def geometry(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``positions [..., 3]`` -> (SDF or raw density ``[..., 1]``, geometry feature ``[..., G]``)."""
        raise NotImplementedError

    def color_features(self, positions: torch.Tensor, directions: torch.Tensor, normals: torch.Tensor,
                       geo_features: torch.Tensor) -> torch.Tensor:
        """The shared color feature f_shared ``[..., feature_dim]``."""
        raise NotImplementedError

    def decode_color(self, features: torch.Tensor) -> torch.Tensor:
        """RGB in [0, 1] ``[..., 3]`` from a feature ``[..., feature_dim]``."""
        raise NotImplementedError

    def geometry_and_gradient(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """SDF ``[..., 1]``, geometry feature ``[..., G]`` and the SDF's gradient ``[..., 3]`` in one pass;
        only for fields that declare ``analytic_sdf_gradient``."""
        raise NotImplementedError(f"{type(self).__name__} has no analytic SDF gradient")

    def color(self, positions, directions, normals, geo_features, camera_indices=None,
              weights=None, ray_indices=None) -> dict[str, torch.Tensor]:
        """RGB of samples. ``camera_indices`` (``[...]``, -1 for novel views), the detached rendering
        ``weights`` and ``ray_indices`` (``[...]``, None where unknown) are ignored by plain fields."""
        return {"rgb": self.decode_color(self.color_features(positions, directions, normals, geo_features))}

    def update_step(self, step: int, schedule_steps: int) -> None:
        """Schedules of the field (e.g. coarse-to-fine grid levels), called before each training step
        and when a run is loaded."""

    def param_groups(self) -> dict[str, list[nn.Parameter]]:
        """Parameters keyed like the optimizer config."""
        return {"fields": list(self.parameters())}

    def extra_losses(self, outputs: dict[str, torch.Tensor], batch: dict[str, torch.Tensor] | None = None,
                     color_loss: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = None
                     ) -> dict[str, torch.Tensor]:
        """Scalar loss terms ``[]`` of the field's own (e.g. the view-adaptive regularizers) from the model's
        ``outputs``, the ``batch`` and the model's photometric loss (``[R, 3]`` against ``[R, 3]``); none by
        default."""
        return {}

    def training_callbacks(self) -> list:
        """Callbacks the trainer runs for the field (e.g. phase switches); none by default."""
        return []

    def diagnostics(self) -> dict[str, float]:
        """Scalars worth logging; none by default."""
        return {}


class MLP(nn.Module):
    """A plain MLP: ``n_layers`` hidden layers of ``width`` with an activation after each."""

    def __init__(self, in_dim: int, width: int, n_layers: int, out_dim: int,
                 activation: nn.Module | None = None, out_activation: nn.Module | None = None) -> None:
        super().__init__()
        dims = [in_dim] + [width] * n_layers
        self.hidden = nn.ModuleList(nn.Linear(a, b) for a, b in itertools.pairwise(dims))
        self.activation = activation if activation is not None else nn.ReLU()
        self.out = nn.Linear(dims[-1], out_dim) if out_dim > 0 else None
        self.out_activation = out_activation

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """The last hidden layer's output ``[..., width]`` of inputs ``[..., in_dim]``."""
        for layer in self.hidden:
            x = self.activation(layer(x))
        return x

    def head(self, h: torch.Tensor) -> torch.Tensor:
        """The output layer (and its activation): ``[..., width]`` -> ``[..., out_dim]``."""
        y = self.out(h)
        return self.out_activation(y) if self.out_activation is not None else y

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``[..., in_dim]`` -> ``[..., out_dim]`` (``[..., width]`` when ``out_dim`` is 0)."""
        h = self.features(x)
        return h if self.out is None else self.head(h)
