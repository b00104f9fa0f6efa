"""The NeuS surface model (Wang et al., 2021): SDF volume rendering with up-sampling."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Type

import torch
from torch import nn

from va_plugin.engine.callbacks import AFTER_STEP, TrainingCallback, TrainingCallbackAttributes
from va_plugin.errors import ConfigError
from va_plugin.fields.base import FieldConfig
from va_plugin.fields.sdf_field import SDFFieldConfig
from va_plugin.model_components import losses, renderers
from va_plugin.model_components.camera_opt import CameraOptimizerConfig
from va_plugin.model_components.view_deformation import ViewDeformationConfig
from va_plugin.model_components.robust import per_ray_mask_error, per_ray_rgb_error, trimmed_mean
from va_plugin.model_components.view_uncertainty import ViewUncertainty
from va_plugin.model_components.neus import (SingleVariance, neus_alpha, normal_smoothness, sdf_band, section_alpha,
                                             surface_crossings)
from va_plugin.model_components.occupancy_grid import scatter
from va_plugin.model_components.samplers import sample_pdf, uniform_edges
from va_plugin.models.base import Model, ModelConfig, SceneInfo
from va_plugin.rays import RayBundle, RaySamples, isotropic_rays, near_far_from_sphere
from va_plugin.utils.stages import stage, timed


@dataclass
class NeuSModelConfig(ModelConfig):
    """NeuS: SDF field, learned inv_s, up-sampling inside the bounding sphere, eikonal and mask losses."""

    _target: Type = field(default_factory=lambda: NeuSModel)
    field: FieldConfig = field(default_factory=SDFFieldConfig)
    """The field (an SDF field, or a view-adaptive wrapper around one)."""
    n_samples: int = 32
    """Uniform samples per ray."""
    n_importance: int = 32
    """Up-sampled samples per ray, added in ``up_sample_steps`` rounds."""
    up_sample_steps: int = 2
    """Rounds of up-sampling; round k uses inv_s = 64 * 2^k."""
    skip_empty_rays: bool = True
    """Skip rays whose SDF stays far from zero along every coarse sample (they render background).
    A ray is skipped only when inv_s * (min coarse SDF - half a coarse step) > ``skip_margin``, so the
    alpha it would get is below exp(-margin)."""
    skip_margin: float = 12.0
    """Safety margin of the empty-ray test (and of ``skip_far_samples``), in units of 1/inv_s."""
    skip_far_samples: bool = True
    """Evaluate with gradients only the samples that the coarse SDF says may lie within
    ``skip_margin / inv_s`` of the surface, or inside it (see ``sdf_band``); the others get alpha 0
    and no eikonal term. 1.14-1.46x faster training at unchanged accuracy (benchmarks/RESULTS.md,
    "ngp and skipping"). A run at an absurd learning rate then throws inv_s to its clamp without any
    non-finite value; the training guard rolls that back too (``health.inv_s_saturation``)."""
    variance_init: float = 0.3
    """Initial v of inv_s = exp(10 v)."""
    inv_s_floor: float = 0.0
    """A floor under the learned inv_s (0 turns it off): from ``inv_s_floor_start`` of the schedule it rises
    linearly to this value at the schedule's end (and stays there in a longer run), and before every step the
    learned inv_s is lifted to it where it lies below. The surface the field trains on is then about as sharp
    as the mesh cut from it, so renders show a hard edge instead of a soft fringe (compare
    ``render_sharpness``, which sharpens renders of a field trained soft)."""
    inv_s_floor_start: float = 0.5
    """Share of the schedule at which ``inv_s_floor`` starts to rise from 0."""
    render_sharpness: float = 1.0
    """Factor on the learned inv_s when rendering novel views outside training (evaluation, ``va-export
    render``, turntables: batches whose rays all take the canonical path, camera index -1). Above 1 the
    renders come closer to the surface the mesh is cut from: sharper silhouettes and texture (lower
    LPIPS), at some held-out PSNR where the surface is slightly off (benchmarks/RESULTS.md, "Render
    sharpness"). Training, and renders of training views, always use the learned value."""
    sdf_gradient: str = "auto"
    """How the SDF's gradient (the cosine term of alpha, the normals, the eikonal loss) is computed:
    "autograd" (``torch.autograd.grad`` with ``create_graph``, so the loss's backward is a double
    backward), "analytic" (the field writes out the MLP's chain rule next to its forward pass:
    the same values to float rounding, one plain backward; needs a field with
    ``geometry_and_gradient``, as the SDF field has), or "auto": analytic when the field supports it,
    else autograd. See the README for the measured speed."""
    eikonal_weight: float = 0.1
    """Weight of the eikonal loss."""
    mask_weight: float = 0.1
    """Weight of the mask loss against the foreground mask (0 turns it off)."""
    normal_weight: float = 0.1
    """Weight of the normal loss (1 - cos between rendered and given normals) on inputs that come with
    normal maps (Wonder3D folders with ``normals_000_<view>.png``); other inputs have none, and 0 turns
    it off."""
    cos_anneal_fraction: float = 0.1
    """Share of the step budget over which the cosine term is annealed (0: no annealing)."""
    smoothness_weight: float = 0.0
    """Weight of the normal-smoothness prior (0 turns it off): at up to ``smoothness_points`` points
    where training rays meet the surface (their expected depth, rays with opacity above one half), the
    mean 1 - cos between the SDF's normal there and at a point ``smoothness_radius`` away in a random
    direction. It flattens dents in flat faces that four views cannot see."""
    smoothness_radius: float = 0.01
    """Scale of the random step of the smoothness prior (scene units; the object fits a sphere of 1)."""
    smoothness_points: int = 256
    """Most surface points per batch the smoothness prior is evaluated at."""
    projected_area_weight: float = 0.0
    """Weight of the projected-area prior (0 turns it off): the mean opacity of ``projected_area_rays``
    rays from random directions through the scene sphere (:func:`va_plugin.rays.isotropic_rays`), i.e. the
    object's silhouette area averaged over every viewing direction. Only rays that graze the surface
    carry a gradient, so it moves outlines, not insides: of the shapes the input silhouettes allow it
    prefers the one with the smallest outline from other directions. Four views carve a round object
    towards the square their silhouettes allow; edges a view sees on its outline stay, since the mask
    loss holds them (unlike ``smoothness_weight``, which rounds them too)."""
    projected_area_rays: int = 128
    """Random rays per step of the projected-area prior."""
    projected_area_start: float = 0.1
    """Share of the step budget before the projected-area prior (and ``crossings_weight``) starts."""
    crossings_weight: float = 0.0
    """Weight of the crossings prior (0 turns it off): along ``projected_area_rays`` random lines through the
    scene sphere (the same kind of lines as the projected-area prior), half the number of times each line
    crosses the surface, counted as the total variation of a soft inside-indicator at
    ``crossings_samples`` stratified points. By Crofton's formula its mean is proportional to the surface
    area. On a convex body it equals the projected-area prior's opacity; unlike that prior it also charges
    a line that leaves the surface and enters it again, so it fills dents inside the outline (and any
    concavity that no input's mask or colour holds open)."""
    crossings_samples: int = 64
    """Stratified points per line of the crossings prior; the soft indicator's width is their spacing."""
    colour_angle_power: float = 0.0
    """Weight of a training ray's colour loss by how squarely it meets the surface (0 turns it off): the
    ray's weight is ``(1 - opacity) + opacity * max(cos, 0) ** colour_angle_power``, with ``cos`` between the
    ray and the rendered surface normal and both factors held constant, and the loss is the weighted mean.
    A pixel that sees the surface at a grazing angle averages a long strip of it; weighted down, each surface
    point takes its colour mostly from the view that sees it squarely (as a texture bake weights its views),
    so the field's texture is less smeared. Background rays keep weight 1. See ``colour_angle_mode``."""
    colour_angle_mode: str = "ray"
    """What ``colour_angle_power`` weights: "ray", a ray's whole colour loss (the geometry's gradient from the
    colour too), or "colour", only the gradient that flows back through the sample colours (into the colour
    network and the geometry feature and normal it reads), per sample, by ``max(cos, 0) ** power`` with the
    sample's own normal; the gradient through the opacities (where the surface lies) stays every ray's alike."""
    trim_fraction: float = 0.0
    """Robust colour and mask losses: each batch drops this share of its rays with the largest error
    from the loss (0: plain means). For generated views that are wrong in patches."""
    view_uncertainty: float = 0.0
    """Per-view uncertainty of the colour loss (0 turns it off): each foreground ray's colour error is
    weighted by ``(reference / running error of its view) ** view_uncertainty``, so a view the shared field
    explains worse counts less (1: inverse-variance weights, the optimum of a learned per-view uncertainty
    sigma with the loss ``e / 2 sigma^2 + log sigma``). Weights are clamped to [1/4, 4], constant, and
    normalised to mean 1 (va_plugin/model_components/view_uncertainty.py)."""
    view_uncertainty_grid: int = 1
    """With ``view_uncertainty``: each view split into this many cells a side, each with its own running
    error, so that a wrong patch of a view counts less rather than the whole view (1: one per view)."""
    view_uncertainty_start: float = 0.1
    """Share of the schedule before the per-view weights apply (the running errors are kept from the start)."""
    camera_opt: CameraOptimizerConfig = dataclasses.field(default_factory=CameraOptimizerConfig)  # "field" is taken
    """Per-view camera refinement (off by default; its learning rate is the "camera_opt" optimizer group)."""
    view_deformation: ViewDeformationConfig = dataclasses.field(default_factory=ViewDeformationConfig)
    """Per-view deformation of space (off by default; the "view_deformation" optimizer group): view i
    renders the shared SDF at x + d_i(x), the mesh and novel views use it undeformed."""


class NeuSModel(Model):
    config: NeuSModelConfig

    def __init__(self, config: NeuSModelConfig, scene: SceneInfo) -> None:
        super().__init__(config, scene)
        self.field = config.field.setup_for_scene(scene)
        if self.field.geometry_kind != "sdf":
            raise ConfigError("the neus model needs a field whose geometry is an SDF")
        if not 0.0 <= config.trim_fraction < 1.0:
            raise ConfigError(f"trim_fraction must be in [0, 1), got {config.trim_fraction}")
        self.view_uncertainty = self._view_uncertainty(config, scene)
        if config.smoothness_weight < 0 or config.smoothness_radius <= 0 or config.smoothness_points < 1:
            raise ConfigError("smoothness_weight must be >= 0, smoothness_radius > 0 and smoothness_points >= 1, got "
                              f"{config.smoothness_weight}, {config.smoothness_radius} and {config.smoothness_points}")
        if config.projected_area_weight < 0 or config.projected_area_rays < 1 or \
                not 0.0 <= config.projected_area_start <= 1.0:
            raise ConfigError("projected_area_weight must be >= 0, projected_area_rays >= 1 and "
                              f"projected_area_start in [0, 1], got {config.projected_area_weight}, "
                              f"{config.projected_area_rays} and {config.projected_area_start}")
        if not (math.isfinite(config.colour_angle_power) and config.colour_angle_power >= 0):
            raise ConfigError(f"colour_angle_power must be a finite number >= 0, got {config.colour_angle_power}")
        if not (math.isfinite(config.inv_s_floor) and 0.0 <= config.inv_s_floor <= 1e5) or \
                not 0.0 <= config.inv_s_floor_start < 1.0:
            raise ConfigError(f"inv_s_floor must be in [0, 1e5] and inv_s_floor_start in [0, 1), got "
                              f"{config.inv_s_floor} and {config.inv_s_floor_start}")
        if config.colour_angle_mode not in ("ray", "colour"):
            raise ConfigError(f"colour_angle_mode must be 'ray' or 'colour', got {config.colour_angle_mode!r}")
        if config.crossings_weight < 0 or config.crossings_samples < 2:
            raise ConfigError("crossings_weight must be >= 0 and crossings_samples >= 2, got "
                              f"{config.crossings_weight} and {config.crossings_samples}")
        if config.sdf_gradient not in SDF_GRADIENTS:
            raise ConfigError(f"sdf_gradient must be one of {', '.join(SDF_GRADIENTS)}, got {config.sdf_gradient!r}")
        if config.sdf_gradient == "analytic" and not hasattr(self.field, "geometry_and_gradient"):
            raise ConfigError(f"sdf_gradient='analytic' needs a field with geometry_and_gradient; "
                              f"{type(self.field).__name__} has none (use 'autograd')")
        self.sdf_gradient = config.sdf_gradient if config.sdf_gradient != "auto" else \
            ("analytic" if _supports_analytic_gradient(self.field) else "autograd")
        """The gradient path in use (``config.sdf_gradient`` with "auto" resolved)."""
        self.variance = SingleVariance(config.variance_init)
        self.camera_optimizer = config.camera_opt.setup(num_views=scene.num_train_views) \
            if config.camera_opt.mode != "off" else None
        """Per-view camera corrections, or None (then the state dict has no entry for them)."""
        self.view_deformation = config.view_deformation.setup(num_views=scene.num_train_views) \
            if config.view_deformation.enabled else None
        """Per-view deformation grids, or None."""
        self.samples_per_ray = 0.0
        """Samples per batch ray evaluated with gradients in the last training batch (skipped rays count 0)."""
        self.probed_per_ray = 0.0
        """SDF evaluations per batch ray of the gradient-free coarse and up-sampling passes, last training batch."""

    # -- schedules ------------------------------------------------------------------------------
    def inv_s_floor(self, step: int) -> float:
        """The floor under the learned inv_s at ``step`` (0: none)."""
        cfg = self.config
        if cfg.inv_s_floor <= 0:
            return 0.0
        start = cfg.inv_s_floor_start * self.scene.max_steps
        span = max(1.0, self.scene.max_steps - start)
        return cfg.inv_s_floor * min(1.0, max(0.0, (step - start) / span))

    def cos_anneal_ratio(self) -> float:
        if not self.training:
            return 1.0
        span = self.config.cos_anneal_fraction * self.scene.max_steps
        return 1.0 if span <= 0 else min(1.0, self.step / span)

    def update_step(self, step: int) -> None:
        super().update_step(step)
        floor = self.inv_s_floor(step)
        if floor > 0:
            with torch.no_grad():
                self.variance.variance.clamp_(min=math.log(floor) / 10.0)
        if self.camera_optimizer is not None:
            self.camera_optimizer.set_step(step, self.scene.max_steps)

    def training_callbacks(self) -> List[object]:
        callbacks = list(super().training_callbacks())
        if self.camera_optimizer is not None:
            callbacks.append(TrainingCallback(self._write_camera_refinement, AFTER_STEP))
        return callbacks

    def _write_camera_refinement(self, step: int, attributes: TrainingCallbackAttributes) -> None:
        self.write_after_last_step(step, attributes, CAMERA_REFINEMENT_FILE, self.camera_optimizer.summary,
                                   lambda s: f"camera refinement: largest correction {s['max_rotation_deg']:.3f} "
                                             f"deg, {s['max_translation']:.4f} units")

    def get_param_groups(self) -> Dict[str, List[nn.Parameter]]:
        groups = self.field.param_groups()
        groups["variance"] = list(self.variance.parameters())  # inv_s: its own rate (a method config sets it)
        if self.camera_optimizer is not None:
            groups["camera_opt"] = list(self.camera_optimizer.parameters())
        if self.view_deformation is not None:
            groups["view_deformation"] = list(self.view_deformation.parameters())
        return self.with_shared_param_groups(groups)

    def render_inv_s(self, ray_bundle: RayBundle) -> torch.Tensor:
        """inv_s for rendering ``ray_bundle``: the learned value, times ``render_sharpness`` for a
        novel-view batch outside training (every ray on the canonical path)."""
        inv_s = self.variance.inv_s()
        factor = self.config.render_sharpness
        if factor != 1.0 and not self.training and bool((ray_bundle.camera_indices < 0).all()):
            inv_s = inv_s * factor
        return inv_s

    def sharpness(self) -> Optional[float]:
        return float(self.variance.inv_s().detach())

    @staticmethod
    def _view_uncertainty(config: NeuSModelConfig, scene: SceneInfo) -> Optional[ViewUncertainty]:
        power, grid, start = config.view_uncertainty, config.view_uncertainty_grid, config.view_uncertainty_start
        if not (math.isfinite(power) and power >= 0):
            raise ConfigError(f"view_uncertainty must be a finite number >= 0, got {power}")
        if not (isinstance(grid, int) and 1 <= grid <= 64) or not 0.0 <= start <= 1.0:
            raise ConfigError("view_uncertainty_grid must be an integer from 1 to 64 and view_uncertainty_start "
                              f"in [0, 1], got {grid} and {start}")
        if power == 0:
            return None
        cameras = scene.train_cameras
        if grid > 1 and cameras is None:
            raise ConfigError("view_uncertainty_grid > 1 needs the training cameras' image size")
        width, height = (cameras.width, cameras.height) if cameras is not None else (1, 1)
        return ViewUncertainty(scene.num_train_views, grid, power, width, height)

    def diagnostics(self) -> Dict[str, float]:
        out = {**super().diagnostics(), "inv_s": self.sharpness(),
               "samples_per_ray": round(self.samples_per_ray, 3), "probed_per_ray": round(self.probed_per_ray, 3)}
        if self.view_uncertainty is not None:
            weights = self.view_uncertainty.view_weights()
            out["view_weight_min"], out["view_weight_max"] = min(weights), max(weights)
        if self.camera_optimizer is not None:
            summary = self.camera_optimizer.summary()
            out["camera_max_deg"] = summary["max_rotation_deg"]
            out["camera_max_shift"] = summary["max_translation"]
        if self.view_deformation is not None:
            out["deformation_max"] = round(self.view_deformation.largest(), 5)
        return out

    # -- sampling -------------------------------------------------------------------------------
    @torch.no_grad()
    @timed("sampling")
    def _coarse(self, ray_bundle: RayBundle) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Coarse edges ``[n_rays, n_samples + 2]``, their SDF, and which rays may hit a surface ``[n_rays]``."""
        cfg = self.config
        nears, fars = ray_bundle.nears, ray_bundle.fars
        coarse = uniform_edges(nears, fars, cfg.n_samples, jitter=self.training)
        edges = torch.cat([nears, coarse, fars], dim=-1)
        sdf = self._sdf_along(ray_bundle, edges)
        active = (fars > nears)[:, 0]
        if cfg.skip_empty_rays:
            # between samples the SDF (|grad| ~ 1) can dip at most half a step below the smaller end
            half_step = (edges[:, 1:] - edges[:, :-1]).max(-1).values * 0.5
            closest = sdf.min(-1).values - half_step
            active &= closest * self.render_inv_s(ray_bundle) < cfg.skip_margin
        return edges, sdf, active

    @torch.no_grad()
    @timed("sampling")
    def _sample_edges(self, ray_bundle: RayBundle, edges: torch.Tensor, sdf: torch.Tensor) -> torch.Tensor:
        """Section edges ``[n_rays, n_samples + n_importance + 2]``: the coarse ones, then up-sampled."""
        cfg = self.config
        if cfg.n_importance <= 0 or cfg.up_sample_steps <= 0:
            return edges
        per_step = cfg.n_importance // cfg.up_sample_steps
        for k in range(cfg.up_sample_steps):
            weights = renderers.weights_from_alpha(section_alpha(sdf, 64.0 * 2 ** k))
            new = sample_pdf(edges, weights, per_step, jitter=False)
            edges, order = torch.sort(torch.cat([edges, new], dim=-1), dim=-1)
            if k + 1 < cfg.up_sample_steps:
                sdf = torch.cat([sdf, self._sdf_along(ray_bundle, new)], dim=-1).gather(-1, order)
        return edges

    def _sdf_along(self, ray_bundle: RayBundle, t: torch.Tensor) -> torch.Tensor:
        points = ray_bundle.origins[:, None] + ray_bundle.directions[:, None] * t[..., None]
        return self.field.geometry(self._deformed(points, ray_bundle.camera_indices[:, None]))[0][..., 0]

    # -- rendering ------------------------------------------------------------------------------
    def get_outputs(self, ray_bundle: RayBundle) -> Dict[str, torch.Tensor]:
        if self.camera_optimizer is not None:  # training views' rays, as refined; novel views unchanged
            ray_bundle = self.camera_optimizer.apply(ray_bundle)
        nears, fars, _ = near_far_from_sphere(ray_bundle.origins, ray_bundle.directions,
                                                 self.scene.scene_radius)
        ray_bundle.nears, ray_bundle.fars = nears, fars
        edges, sdf_coarse, active = self._coarse(ray_bundle)
        n_rays = len(ray_bundle)
        blank = False
        if bool(active.all()):
            index, sub = None, ray_bundle
        else:
            index = active.nonzero().squeeze(-1)
            if index.numel() == 0:
                # render one ray so per-sample outputs (eikonal) and the graph stay well-formed; it shows nothing
                index, blank = index.new_zeros(1), True
            sub, edges, sdf_coarse = ray_bundle[index], edges[index], sdf_coarse[index]
        fine = self._sample_edges(sub, edges, sdf_coarse)
        keep = None
        if self.config.skip_far_samples:
            t_mid = 0.5 * (fine[:, 1:] + fine[:, :-1])
            keep = sdf_band(edges, sdf_coarse, t_mid, self.render_inv_s(sub).detach(), self.config.skip_margin)
        inner = self._render(sub, fine, keep)
        if self.training and self.config.smoothness_weight > 0:
            opacity = inner["accumulation"].detach()
            depth = inner["depth"].detach()
            inner["surface_points"] = sub.origins + sub.directions * depth
            inner["surface_valid"] = opacity[:, 0] > 0.5
        if self.training:
            self.samples_per_ray = inner["weights"].numel() / max(n_rays, 1)
            self.probed_per_ray = (edges.shape[1] * n_rays + self._upsample_probes() * len(sub)) / max(n_rays, 1)
        outputs = inner if index is None else _scatter_rays(inner, index, n_rays, self.background, blank)
        if self.training and self.config.colour_angle_power > 0 and self.config.colour_angle_mode == "ray":
            outputs["colour_weight"] = colour_angle_weight(outputs["normal"], outputs["accumulation"],
                                                           ray_bundle.directions, self.config.colour_angle_power)
        return self.apply_view_appearance(outputs, ray_bundle)

    def _deformed(self, points: torch.Tensor, camera_indices: torch.Tensor) -> torch.Tensor:
        """Sample points as their view sees the shared field (unchanged without per-view deformation)."""
        if self.view_deformation is None:
            return points
        return self.view_deformation.apply(points, camera_indices)

    def _upsample_probes(self) -> int:
        """SDF evaluations per rendered ray of the up-sampling rounds (the last round's samples are
        evaluated only by the rendering pass)."""
        cfg = self.config
        if cfg.n_importance <= 0 or cfg.up_sample_steps <= 0:
            return 0
        return (cfg.n_importance // cfg.up_sample_steps) * (cfg.up_sample_steps - 1)

    def _render(self, ray_bundle: RayBundle, edges: torch.Tensor,
                keep: Optional[torch.Tensor] = None) -> Dict[str, torch.Tensor]:
        """Render rays that may hit the surface, given their section edges ``[n_rays, n + 1]``.

        With ``keep`` (``[n_rays, n]`` bool) only those samples are evaluated, packed row-major as in
        ``samples.positions[keep]``; the others get alpha 0. Per-sample outputs (weights, gradients,
        inside) are then packed too."""
        samples = RaySamples.from_edges(ray_bundle, edges)
        pack = (lambda t: t) if keep is None else (lambda t: t[keep])  # noqa: E731
        unpack = (lambda t: t) if keep is None else (lambda t: scatter(t, keep))  # noqa: E731
        sample_cameras = pack(samples.camera_indices[:, None].expand(samples.t_mid.shape))
        if self.sdf_gradient == "analytic":  # a graph only while training: evaluation records nothing
            with torch.set_grad_enabled(self.training), stage("sdf_gradient"):
                positions = self._deformed(pack(samples.positions).detach(), sample_cameras)
                sdf, geo_features, gradients = self.field.geometry_and_gradient(positions)
        else:
            with torch.enable_grad(), stage("sdf_gradient"):  # the field's forward is timed on its own
                positions = pack(samples.positions).detach().requires_grad_(True)
                sdf, geo_features = self.field.geometry(self._deformed(positions, sample_cameras))
                gradients = torch.autograd.grad(sdf, positions, torch.ones_like(sdf),
                                                create_graph=self.training, retain_graph=True)[0]
        if not self.training:
            sdf, geo_features, gradients = sdf.detach(), geo_features.detach(), gradients.detach()
        elif self.camera_optimizer is not None and not self.camera_optimizer.frozen:
            # the SDF was evaluated at points detached from the rays; to first order it moves with them by
            # grad(sdf) . dx, which is how a corrected camera's rays see the surface (zero in value)
            live = pack(samples.positions)
            sdf = sdf + (gradients.detach() * (live - live.detach())).sum(-1, keepdim=True)
        directions = pack(samples.directions[:, None, :].expand(samples.positions.shape))
        true_cos = (directions * gradients).sum(-1)
        alpha = unpack(neus_alpha(sdf[..., 0], true_cos, pack(samples.deltas), self.render_inv_s(ray_bundle),
                                  self.cos_anneal_ratio()))
        weights = renderers.weights_from_alpha(alpha)
        sample_weights = pack(weights)
        normals = torch.nn.functional.normalize(gradients, dim=-1, eps=1e-6)
        camera_indices = sample_cameras
        ray_indices = pack(torch.arange(alpha.shape[0], device=alpha.device)[:, None].expand(alpha.shape))
        color = self.field.color(positions if self.training else positions.detach(), directions, normals,
                                 geo_features, camera_indices, weights=sample_weights.detach(),
                                 ray_indices=ray_indices)
        if self.training and self.config.colour_angle_power > 0 and self.config.colour_angle_mode == "colour":
            scale = (-(directions * normals).sum(-1, keepdim=True)).clamp(0.0, 1.0) ** self.config.colour_angle_power
            color = dict(color, rgb=losses.scale_gradient(color["rgb"], scale.detach()))
        outputs = {
            "rgb": renderers.render_rgb(self.rgb_weights(weights), unpack(color["rgb"]), self.background),
            "accumulation": weights.sum(-1, keepdim=True),
            "depth": renderers.render_depth(weights, samples.t_mid),
            "normal": (weights[..., None] * unpack(normals)).sum(-2),
            "weights": sample_weights,
            "gradients": gradients,
            "inside": (positions.detach().norm(dim=-1) < self.scene.scene_radius),
        }
        return self.composite_other_colours(outputs, color, weights, unpack)

    def get_loss_dict(self, outputs, batch) -> Dict[str, torch.Tensor]:
        cfg = self.config
        trim = cfg.trim_fraction > 0
        uncertain = self.view_uncertainty is not None and self.training and "pixel" in batch
        if uncertain or "colour_weight" in outputs:
            error = per_ray_rgb_error(outputs["rgb"], batch["rgb"], cfg.rgb_loss)
            per_ray = error
            if "colour_weight" in outputs:
                weight = outputs["colour_weight"]
                per_ray = per_ray * (weight / weight.mean().clamp_min(1e-6))
            if uncertain:
                keep = batch["mask"][:, 0] > 0.5 if "mask" in batch else None
                if self.step >= cfg.view_uncertainty_start * self.scene.max_steps:
                    per_ray = per_ray * self.view_uncertainty.weights(batch["pixel"], keep)
                self.view_uncertainty.update(batch["pixel"], error, keep)
            loss = {"rgb": trimmed_mean(per_ray, cfg.trim_fraction)}
        else:
            loss = {"rgb": trimmed_mean(per_ray_rgb_error(outputs["rgb"], batch["rgb"], cfg.rgb_loss),
                                        cfg.trim_fraction)
                    if trim else losses.rgb_loss(outputs["rgb"], batch["rgb"], cfg.rgb_loss)}
        if cfg.eikonal_weight > 0:
            loss["eikonal"] = cfg.eikonal_weight * losses.eikonal_loss(outputs["gradients"], outputs["inside"])
        if cfg.mask_weight > 0 and "mask" in batch:
            loss["mask"] = cfg.mask_weight * (
                trimmed_mean(per_ray_mask_error(outputs["accumulation"], batch["mask"]), cfg.trim_fraction) if trim
                else losses.mask_loss(outputs["accumulation"], batch["mask"]))
        if cfg.normal_weight > 0 and "normal" in batch:
            loss["normal"] = cfg.normal_weight * losses.normal_loss(outputs["normal"], batch["normal"])
        if self.camera_optimizer is not None:
            loss["camera_opt"] = self.camera_optimizer.loss()
        if self.view_deformation is not None:
            loss["view_deformation"] = self.view_deformation.loss()
        if cfg.smoothness_weight > 0 and "surface_points" in outputs:
            loss["smoothness"] = cfg.smoothness_weight * self._smoothness(outputs)
        if self.training and self.step >= cfg.projected_area_start * self.scene.max_steps:
            if cfg.projected_area_weight > 0:
                loss["projected_area"] = cfg.projected_area_weight * self._projected_area(outputs)
            if cfg.crossings_weight > 0:
                loss["crossings"] = cfg.crossings_weight * self._crossings(outputs["accumulation"].device)
        return self.apply_extra_losses(loss, outputs, batch)

    def _projected_area(self, outputs) -> torch.Tensor:
        """The mean opacity of random rays from every direction (the projected-area prior); the batch's
        sample counters keep the training rays' figures."""
        device = outputs["accumulation"].device
        rays = isotropic_rays(self.config.projected_area_rays, self.scene.scene_radius, device=device)
        counters = self.samples_per_ray, self.probed_per_ray
        try:
            accumulation = self.get_outputs(rays)["accumulation"]
        finally:
            self.samples_per_ray, self.probed_per_ray = counters
        return accumulation.mean()

    def _crossings(self, device: torch.device) -> torch.Tensor:
        """Half the mean number of surface crossings of random lines through the scene sphere (the
        crossings prior), from stratified samples of the SDF on each line's chord."""
        cfg = self.config
        rays = isotropic_rays(cfg.projected_area_rays, self.scene.scene_radius, device=device)
        nears, fars, _ = near_far_from_sphere(rays.origins, rays.directions, self.scene.scene_radius)
        return surface_crossings(lambda p: self.field.geometry(p)[0][..., 0], rays.origins, rays.directions,
                                 nears, fars, cfg.crossings_samples).mean()

    def _smoothness(self, outputs) -> torch.Tensor:
        """The normal-smoothness prior at (a random subset of) the batch's surface points."""
        points = outputs["surface_points"][outputs["surface_valid"]]
        if points.shape[0] > self.config.smoothness_points:
            points = points[torch.randperm(points.shape[0], device=points.device)[: self.config.smoothness_points]]
        step = torch.randn_like(points) * self.config.smoothness_radius
        both = torch.cat([points, points + step])
        gradients = self._sdf_gradient(both)
        return normal_smoothness(gradients[: len(points)], gradients[len(points):])

    def _sdf_gradient(self, points: torch.Tensor) -> torch.Tensor:
        """The SDF's gradient at ``points [n, 3]`` with a graph to train from, by the model's gradient path."""
        if self.sdf_gradient == "analytic":
            return self.field.geometry_and_gradient(points)[2]
        points = points.detach().requires_grad_(True)
        sdf = self.field.geometry(points)[0]
        return torch.autograd.grad(sdf, points, torch.ones_like(sdf), create_graph=True)[0]

    # -- export ---------------------------------------------------------------------------------
    @torch.no_grad()
    def mesh_field(self, points: torch.Tensor) -> torch.Tensor:
        return self.field.geometry(points)[0][..., 0]

    def surface_color(self, points: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            _, geo_features = self.field.geometry(points)
            camera = torch.full(points.shape[:-1], -1, dtype=torch.long, device=points.device)
            return self.field.color(points, -normals, normals, geo_features, camera)["rgb"]


CAMERA_REFINEMENT_FILE = "camera_refinement.json"
"""In a run folder with camera refinement: each training view's correction (degrees, scene units)."""

SDF_GRADIENTS = ("auto", "autograd", "analytic")
"""The values of ``NeuSModelConfig.sdf_gradient``."""


def _supports_analytic_gradient(field) -> bool:
    """Whether ``field.geometry_and_gradient`` exists and handles this field's network (its activations)."""
    if not hasattr(field, "geometry_and_gradient"):
        return False
    try:
        with torch.no_grad():
            field.geometry_and_gradient(torch.zeros(1, 3, device=next(field.parameters()).device))
    except NotImplementedError:
        return False
    return True


def colour_angle_weight(normal: torch.Tensor, accumulation: torch.Tensor, directions: torch.Tensor,
                        power: float) -> torch.Tensor:
    """Per-ray weights ``[n]`` of ``colour_angle_power``, held constant: ``(1 - a) + a * max(cos, 0) ** power``
    from the rendered normal ``[n, 3]`` (the opacity-weighted sum of sample normals), the opacity ``a``
    ``[n, 1]`` (clamped to [0, 1]) and the ray directions ``[n, 3]``; a ray with no normal counts as grazing."""
    normal, accumulation, directions = normal.detach(), accumulation.detach(), directions.detach()
    cos = -(torch.nn.functional.normalize(normal, dim=-1, eps=1e-6)
            * torch.nn.functional.normalize(directions, dim=-1, eps=1e-6)).sum(-1)
    opacity = accumulation[..., 0].clamp(0.0, 1.0)
    return (1.0 - opacity) + opacity * cos.clamp(0.0, 1.0) ** power


PER_RAY_KEYS = ("rgb", "accumulation", "depth", "normal")


def _scatter_rays(inner: Dict[str, torch.Tensor], index: torch.Tensor, n_rays: int,
                  background: torch.Tensor, blank: bool = False) -> Dict[str, torch.Tensor]:
    """Per-ray outputs for all ``n_rays`` from those of the rendered subset ``index``; skipped rays
    render the background with zero opacity. Per-sample outputs keep only the rendered rays. With
    ``blank``, the rendered rays were skipped too (kept only for the graph): they show nothing either."""
    out = dict(inner)
    for key in PER_RAY_KEYS + tuple(k for k in inner if k.startswith("rgb_")):
        value = inner[key]
        full = value.new_zeros((n_rays,) + value.shape[1:])
        if key.startswith("rgb"):
            full = full + background
        if blank:  # zero times the render keeps the graph (and finite, zero gradients)
            value = value * 0.0 + full[index]
        out[key] = full.index_put((index,), value)
    return out

