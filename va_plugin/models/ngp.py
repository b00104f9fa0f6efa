"""The NGP density model (InstantNGP-style): a hash-grid density field rendered with an occupancy grid.

Rays are sampled uniformly inside the bounding sphere; samples in empty cells, or behind an opaque part
of the ray (found by a gradient-free pass), are dropped. The field runs on the packed remaining samples,
scattered back to ``[n_rays, n_samples]`` (zero density elsewhere) for volume rendering.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn

from va_plugin.callbacks import BEFORE_STEP, TrainingCallback, TrainingCallbackAttributes
from va_plugin.errors import ConfigError
from va_plugin.fields.base import FieldConfig
from va_plugin.fields.density_field import DensityFieldConfig, trunc_exp
from va_plugin.model_components import losses, renderers
from va_plugin.model_components.occupancy_grid import OccupancyGrid, OccupancyGridConfig, scatter, transmittance_before
from va_plugin.model_components.samplers import uniform_edges
from va_plugin.models.base import Model, ModelConfig, SceneInfo
from va_plugin.rays import RayBundle, RaySamples, near_far_from_sphere
from va_plugin.utils.stages import timed


@dataclass
class NGPModelConfig(ModelConfig):
    """NGP: hash-grid density field, occupancy-grid marching, early ray termination, mask loss."""

    _target: type = field(default_factory=lambda: NGPModel)
    occupancy_grid: OccupancyGridConfig = field(default_factory=OccupancyGridConfig)
    """Empty-space skipping (``occupancy_grid.enabled=false`` evaluates every sample)."""
    field: FieldConfig = field(default_factory=DensityFieldConfig)
    """The field (a density field, or a view-adaptive wrapper around one)."""
    n_samples: int = 96
    """Samples (sections) per ray, spread uniformly between where the ray enters and leaves the bounding sphere."""
    early_stop_transmittance: float = 1e-4
    """Samples whose transmittance is below this are not evaluated with gradients (0: no early termination)."""
    mask_weight: float = 0.1
    """Weight of the mask loss against the foreground mask (0 turns it off)."""
    distortion_weight: float = 0.01
    """Weight of the distortion loss (mip-NeRF 360) that pulls each ray's weights together (0: off)."""
    density_threshold: float = 10.0
    """Density of the extracted surface: the mesh is the level set density = threshold (mesh_field is
    threshold - density, negative inside)."""
    mesh_smoothing: float = 0.021
    """Std (scene units) of the Gaussian that smooths the occupancy before the mesh is extracted (0: not
    smoothed; 0.021 is 1.5 cells of a 128^3 grid over a 0.9 scene radius)."""
    fill_mesh_cavities: bool = True
    """Make empty space that is enclosed by the surface solid before the mesh is extracted (no camera
    sees it; a density shell leaves it behind its front wall)."""

    def samples_per_ray(self) -> int:
        return int(self.n_samples)


LOG_DENSITY_FLOOR = 1e-2
"""Added to the density before its log in :meth:`NGPModel.prepare_mesh_grid`."""


class NGPModel(Model):
    config: NGPModelConfig

    def __init__(self, config: NGPModelConfig, scene: SceneInfo) -> None:
        super().__init__(config, scene)
        if config.n_samples < 1:
            raise ConfigError(f"n_samples must be at least 1, got {config.n_samples}")
        if not 0.0 <= config.early_stop_transmittance < 1.0:
            raise ConfigError(f"early_stop_transmittance must be in [0, 1), got {config.early_stop_transmittance}")
        if config.density_threshold <= 0:
            raise ConfigError(f"density_threshold must be positive, got {config.density_threshold}")
        if not (math.isfinite(config.mesh_smoothing) and config.mesh_smoothing >= 0):
            raise ConfigError(f"mesh_smoothing must be a finite width >= 0, got {config.mesh_smoothing}")
        self.fill_mesh_cavities = bool(config.fill_mesh_cavities)  # read by :func:`va_plugin.export.mesh.extract_mesh`
        self.field = config.field.setup_for_scene(scene)
        if self.field.geometry_kind != "density":
            raise ConfigError("the ngp model needs a field whose geometry is a density")
        bound = self.field.bound
        if bound is not None and bound < scene.scene_radius:
            raise ConfigError(f"field.bound ({bound}) must be at least the scene radius ({scene.scene_radius})")
        self.occupancy_grid: OccupancyGrid | None = \
            config.occupancy_grid.setup(bound=scene.scene_radius) if config.occupancy_grid.enabled else None
        self._views_marked = False
        # per ray of the last training batch: samples evaluated with gradients, and by the gradient-free pass
        self.samples_per_ray = float(config.n_samples)
        self.probed_per_ray = 0.0

    # -- training -------------------------------------------------------------------------------
    def get_param_groups(self) -> dict[str, list[nn.Parameter]]:
        return self.field.param_groups()

    def training_callbacks(self) -> list[object]:
        callbacks = list(super().training_callbacks())
        if self.occupancy_grid is not None:
            callbacks.append(TrainingCallback(self._update_occupancy, BEFORE_STEP,
                                              self.config.occupancy_grid.update_every))
        return callbacks

    def _update_occupancy(self, step: int, _attributes: TrainingCallbackAttributes) -> None:
        grid, fraction, cameras = self.occupancy_grid, self.config.occupancy_grid.min_view_fraction, \
            self.scene.train_cameras
        if not self._views_marked and fraction > 0 and cameras is not None:
            grid.restrict_to_views(cameras, max(1, math.ceil(fraction * len(cameras) - 1e-6)))
            self._views_marked = True
        grid.update(step, self.density)

    def diagnostics(self) -> dict[str, float]:
        out = {**super().diagnostics(), "samples_per_ray": round(self.samples_per_ray, 3),
               "probed_per_ray": round(self.probed_per_ray, 3)}
        if self.occupancy_grid is not None:
            out["occupied_fraction"] = round(self.occupancy_grid.occupied_fraction(), 4)
        return out

    def density(self, points: torch.Tensor) -> torch.Tensor:
        """Density ``[...]`` (>= 0) at points ``[..., 3]``."""
        return trunc_exp(self.field.geometry(points)[0][..., 0])

    # -- rendering ------------------------------------------------------------------------------
    def get_outputs(self, ray_bundle: RayBundle) -> dict[str, torch.Tensor]:
        """:meth:`Model.get_outputs`, plus ``weights [k]`` over the ``k`` samples evaluated and, while
        training with ``distortion_weight`` on, ``distortion [R]``."""
        if self.training:
            return self._render(ray_bundle)
        with torch.no_grad():
            return self._render(ray_bundle)

    @timed("sampling")
    def _samples_to_evaluate(self, samples: RaySamples) -> tuple[torch.Tensor, tuple | None]:
        """Which samples ``[n_rays, n_samples]`` the field must evaluate (inside the sphere, occupied, in
        front of where the ray turns opaque), and the gradient-free pass's (raw density, feature) of
        them when no gradient is needed."""
        keep = samples.deltas > 0
        if self.occupancy_grid is not None:
            keep &= self.occupancy_grid.occupied(samples.positions)
        if self.config.early_stop_transmittance <= 0 or not bool(keep.any()):
            return keep, None
        with torch.no_grad():
            raw, geo_features = self.field.geometry(samples.positions[keep])
            alpha = renderers.alpha_from_density(scatter(trunc_exp(raw[..., 0]), keep), samples.deltas)
            visible = keep & (transmittance_before(alpha) >= self.config.early_stop_transmittance)
        if self.training:
            self.probed_per_ray = raw.shape[0] / max(keep.shape[0], 1)
        if torch.is_grad_enabled():
            return visible, None
        chosen = visible[keep]
        return visible, (raw[chosen], geo_features[chosen])

    def _render(self, ray_bundle: RayBundle) -> dict[str, torch.Tensor]:
        """The outputs of :meth:`get_outputs` for ``R`` rays of ``n_samples`` uniform sections each (``[R,
        n_samples]``), the samples skipped at density 0."""
        nears, fars, _ = near_far_from_sphere(ray_bundle.origins, ray_bundle.directions, self.scene.scene_radius)
        ray_bundle.nears, ray_bundle.fars = nears, fars
        inner = uniform_edges(nears, fars, self.config.n_samples - 1, jitter=self.training)
        samples = RaySamples.from_edges(ray_bundle, torch.cat([nears, inner, fars], dim=-1))
        keep, evaluated = self._samples_to_evaluate(samples)
        positions = samples.positions[keep]  # [n_kept, 3], row-major over (ray, sample)
        raw, geo_features = evaluated if evaluated is not None else self.field.geometry(positions)
        ray_index = keep.nonzero()[:, 0]
        directions = ray_bundle.directions[ray_index]
        camera_indices = ray_bundle.camera_indices[ray_index]
        alpha = renderers.alpha_from_density(scatter(trunc_exp(raw[..., 0]), keep), samples.deltas)
        weights = renderers.weights_from_alpha(alpha)
        color = self.field.color(positions, directions, torch.zeros_like(positions), geo_features, camera_indices,
                                 weights=weights.detach()[keep], ray_indices=ray_index)
        if self.training:
            self.samples_per_ray = positions.shape[0] / max(len(ray_bundle), 1)
        outputs = {
            "rgb": renderers.render_rgb(weights, scatter(color["rgb"], keep), self.background),
            "accumulation": weights.sum(-1, keepdim=True),
            "depth": renderers.render_depth(weights, samples.t_mid),
            "weights": weights[keep],  # [n_kept], like the positions given to field.color
        }
        if self.training and self.config.distortion_weight > 0:
            scale = 1.0 / (2.0 * self.scene.scene_radius)  # distances in units of the bound's diameter
            outputs["distortion"] = distortion(weights, samples.t_mid * scale, samples.deltas * scale)
        return self.composite_other_colors(outputs, color, weights, lambda value: scatter(value, keep))

    def get_loss_dict(self, outputs, batch) -> dict[str, torch.Tensor]:
        """Scalar terms ``[]``: ``rgb``, ``mask`` (of ``accumulation [R, 1]``) and ``distortion`` (the mean of
        ``[R]``) where on; then the shared ones (:meth:`Model.apply_extra_losses`)."""
        cfg = self.config
        loss = {"rgb": losses.rgb_loss(outputs["rgb"], batch["rgb"])}
        if cfg.mask_weight > 0 and "mask" in batch:
            loss["mask"] = cfg.mask_weight * losses.mask_loss(outputs["accumulation"], batch["mask"])
        if "distortion" in outputs:
            loss["distortion"] = cfg.distortion_weight * outputs["distortion"].mean()
        return self.apply_extra_losses(loss, outputs, batch)

    # -- export ---------------------------------------------------------------------------------
    @torch.no_grad()
    def mesh_field(self, points: torch.Tensor) -> torch.Tensor:
        """``density_threshold - density`` ``[n]`` at points ``[n, 3]``; cells the occupancy grid marks empty
        count as empty, as in rendering."""
        density = self.density(points)
        if self.occupancy_grid is not None:
            density = density * self.occupancy_grid.occupied(points)
        return self.config.density_threshold - density

    def prepare_mesh_grid(self, values: np.ndarray, spacing: float) -> np.ndarray:
        """``mesh_field`` sampled on a grid ``[R, R, R]`` with cells ``spacing`` wide -> the grid marching
        cubes runs on: unchanged, or with ``mesh_smoothing`` a Gaussian-smoothed occupancy
        ``-tanh(log(density / threshold) / 2)``: a step symmetric about the surface (-1 inside, +1
        outside), so smoothing it does not move a flat surface."""
        width = self.config.mesh_smoothing
        if width <= 0:
            return values
        from scipy import ndimage

        threshold = self.config.density_threshold
        density = np.clip(threshold - values, 0.0, None)
        # the floor keeps empty space finite in log space (density 1e-2 is transparent at any sampling)
        occupancy = np.tanh(0.5 * np.log((density + LOG_DENSITY_FLOOR) / threshold))
        return -ndimage.gaussian_filter(occupancy, sigma=width / spacing, mode="nearest").astype(np.float32)

    @torch.no_grad()
    def surface_color(self, points: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        """RGB ``[n, 3]`` of surface points ``[n, 3]`` seen head-on against their normals ``[n, 3]``, from the
        canonical feature (camera index -1)."""
        camera = torch.full(points.shape[:-1], -1, dtype=torch.long, device=points.device)
        geo_features = self.field.geometry(points)[1]
        return self.field.color(points, -normals, normals, geo_features, camera)["rgb"]


def distortion(weights: torch.Tensor, t_mid: torch.Tensor, deltas: torch.Tensor) -> torch.Tensor:
    """Distortion of each ray ``[n_rays]`` (mip-NeRF 360, eq. 15): ``sum_ij w_i w_j |t_i - t_j| +
    1/3 sum_i w_i^2 delta_i``, in O(n) with exclusive prefix sums over the sorted samples ``[n_rays, n]``."""
    w_before = torch.cumsum(weights, dim=-1) - weights
    wt_before = torch.cumsum(weights * t_mid, dim=-1) - weights * t_mid
    pairs = 2.0 * (weights * (t_mid * w_before - wt_before)).sum(-1)
    return pairs + (weights * weights * deltas).sum(-1) / 3.0
