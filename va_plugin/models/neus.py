"""The NeuS surface model (Wang et al., 2021): SDF volume rendering with up-sampling."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import nn

from va_plugin.cameras import ORTHOGRAPHIC
from va_plugin.errors import ConfigError
from va_plugin.fields.base import FieldConfig
from va_plugin.fields.sdf_field import SDFFieldConfig
from va_plugin.model_components import losses, renderers
from va_plugin.model_components.neus import SingleVariance, neus_alpha, sdf_band, section_alpha, surface_crossings
from va_plugin.model_components.occupancy_grid import scatter
from va_plugin.model_components.samplers import sample_pdf, uniform_edges
from va_plugin.models.base import Model, ModelConfig, SceneInfo
from va_plugin.rays import RayBundle, RaySamples, isotropic_rays, near_far_from_sphere
from va_plugin.utils.stages import stage, timed


@dataclass
class NeuSModelConfig(ModelConfig):
    """NeuS: SDF field, learned inv_s, up-sampling inside the bounding sphere, eikonal and mask losses."""

    _target: type = field(default_factory=lambda: NeuSModel)
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
    and no eikonal term."""
    variance_init: float = 0.3
    """Initial v of inv_s = exp(10 v)."""
    inv_s_floor: float = 0.0
    """A floor under the learned inv_s (0 turns it off): from ``inv_s_floor_start`` of the schedule it rises
    linearly to this value at the schedule's end, and before every step inv_s is lifted to it where below,
    so the trained surface is about as sharp as the mesh cut from it."""
    inv_s_floor_start: float = 0.5
    """Share of the schedule at which ``inv_s_floor`` starts to rise from 0."""
    sdf_gradient: str = "auto"
    """How the SDF's gradient is computed: "autograd" (a double backward), "analytic" (the field's own
    chain rule next to its forward pass, the same values to rounding; needs ``field.analytic_sdf_gradient``),
    or "auto": analytic when the field supports it, else autograd."""
    eikonal_weight: float = 0.1
    """Weight of the eikonal loss."""
    mask_weight: float = 0.1
    """Weight of the mask loss against the foreground mask (0 turns it off)."""
    normal_weight: float = 0.1
    """Weight of the normal loss (1 - cos between rendered and given normals) on inputs with normal maps
    (Wonder3D folders with ``normals_000_<view>.png``); 0 turns it off."""
    cos_anneal_fraction: float = 0.1
    """Share of the step budget over which the cosine term is annealed (0: no annealing)."""
    crossings_weight: float = 0.0
    """Weight of the crossings prior (0 turns it off): half the mean number of times ``crossings_rays`` random
    lines through the scene sphere cross the surface (by Crofton's formula proportional to its area), so it
    shrinks outlines and fills dents that no input holds open."""
    crossings_rays: int = 128
    """Random lines per step of the crossings prior."""
    crossings_samples: int = 64
    """Stratified points per line of the crossings prior; the soft indicator's width is their spacing."""
    crossings_start: float = 0.1
    """Share of the step budget before the crossings prior starts."""
    crossings_orthographic: bool = False
    """Whether the crossings prior also runs on scenes whose cameras are orthographic and that have no normal
    maps. Off: there the silhouettes hold a flat face seen head-on or edge-on only at its edges, and the
    prior caves it in (a box's sides); with normal maps, or perspective cameras, the prior runs."""

    def samples_per_ray(self) -> int:
        return int(self.n_samples) + int(self.n_importance)


class NeuSModel(Model):
    config: NeuSModelConfig
    mesh_field_lipschitz = 4.0  # the eikonal loss holds the SDF's gradient norm near 1; the margin is wide

    def __init__(self, config: NeuSModelConfig, scene: SceneInfo) -> None:
        super().__init__(config, scene)
        self.field = config.field.setup_for_scene(scene)
        if self.field.geometry_kind != "sdf":
            raise ConfigError("the neus model needs a field whose geometry is an SDF")
        if not (math.isfinite(config.inv_s_floor) and 0.0 <= config.inv_s_floor <= 1e5) or \
                not 0.0 <= config.inv_s_floor_start < 1.0:
            raise ConfigError(f"inv_s_floor must be in [0, 1e5] and inv_s_floor_start in [0, 1), got "
                              f"{config.inv_s_floor} and {config.inv_s_floor_start}")
        if config.crossings_weight < 0 or config.crossings_rays < 1 or config.crossings_samples < 2 or \
                not 0.0 <= config.crossings_start <= 1.0:
            raise ConfigError("crossings_weight must be >= 0, crossings_rays >= 1, crossings_samples >= 2 and "
                              f"crossings_start in [0, 1], got {config.crossings_weight}, {config.crossings_rays}, "
                              f"{config.crossings_samples} and {config.crossings_start}")
        if config.sdf_gradient not in SDF_GRADIENTS:
            raise ConfigError(f"sdf_gradient must be one of {', '.join(SDF_GRADIENTS)}, got {config.sdf_gradient!r}")
        if config.sdf_gradient == "analytic" and not self.field.analytic_sdf_gradient:
            raise ConfigError(f"sdf_gradient='analytic' needs a field with an analytic SDF gradient; "
                              f"{type(self.field).__name__} has none (use 'autograd')")
        self.sdf_gradient = config.sdf_gradient if config.sdf_gradient != "auto" else \
            ("analytic" if self.field.analytic_sdf_gradient else "autograd")  # "auto" resolved
        self.variance = SingleVariance(config.variance_init)
        self.crossings_weight = config.crossings_weight if crossings_apply(config, scene) else 0.0
        """The crossings prior's weight in this scene (0: off)."""
        # per batch ray of the last training batch: samples evaluated with gradients (skipped rays count 0),
        # and SDF evaluations of the gradient-free coarse and up-sampling passes
        self.samples_per_ray = 0.0
        self.probed_per_ray = 0.0

    # -- schedules ------------------------------------------------------------------------------
    def inv_s_floor(self, step: int) -> float:
        """The floor under the learned inv_s at ``step`` (0: none)."""
        cfg = self.config
        if cfg.inv_s_floor <= 0:
            return 0.0
        start = cfg.inv_s_floor_start * self.scene.schedule_steps
        span = max(1.0, self.scene.schedule_steps - start)
        return cfg.inv_s_floor * min(1.0, max(0.0, (step - start) / span))

    def cos_anneal_ratio(self) -> float:
        if not self.training:
            return 1.0
        span = self.config.cos_anneal_fraction * self.scene.schedule_steps
        return 1.0 if span <= 0 else min(1.0, self.step / span)

    def update_step(self, step: int) -> None:
        super().update_step(step)
        floor = self.inv_s_floor(step)
        if floor > 0:
            with torch.no_grad():
                self.variance.variance.clamp_(min=math.log(floor) / 10.0)

    def get_param_groups(self) -> dict[str, list[nn.Parameter]]:
        groups = self.field.param_groups()
        groups["variance"] = list(self.variance.parameters())  # inv_s: its own rate (a method config sets it)
        return groups

    def sharpness(self) -> float | None:
        return float(self.variance.inv_s().detach())

    def diagnostics(self) -> dict[str, float]:
        return {**super().diagnostics(), "inv_s": self.sharpness(),
                "samples_per_ray": round(self.samples_per_ray, 3), "probed_per_ray": round(self.probed_per_ray, 3)}

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
            active &= closest * self.variance.inv_s() < cfg.skip_margin
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
        """The SDF ``[n_rays, m]`` at distances ``t [n_rays, m]`` along the rays."""
        points = ray_bundle.origins[:, None] + ray_bundle.directions[:, None] * t[..., None]
        return self.field.geometry(points)[0][..., 0]

    # -- rendering ------------------------------------------------------------------------------
    def get_outputs(self, ray_bundle: RayBundle) -> dict[str, torch.Tensor]:
        """:meth:`Model.get_outputs`, plus ``normal [R, 3]`` and, over the ``k`` samples evaluated with
        gradients, ``weights [k]``, ``gradients [k, 3]`` and ``inside [k]`` (packed row-major)."""
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
            keep = sdf_band(edges, sdf_coarse, t_mid, self.variance.inv_s().detach(), self.config.skip_margin)
        inner = self._render(sub, fine, keep)
        if self.training:
            self.samples_per_ray = inner["weights"].numel() / max(n_rays, 1)
            self.probed_per_ray = (edges.shape[1] * n_rays + self._upsample_probes() * len(sub)) / max(n_rays, 1)
        return inner if index is None else _scatter_rays(inner, index, n_rays, self.background, blank)

    def _upsample_probes(self) -> int:
        """SDF evaluations per rendered ray of the up-sampling rounds (the last round's samples are
        evaluated only by the rendering pass)."""
        cfg = self.config
        if cfg.n_importance <= 0 or cfg.up_sample_steps <= 0:
            return 0
        return (cfg.n_importance // cfg.up_sample_steps) * (cfg.up_sample_steps - 1)

    def _render(self, ray_bundle: RayBundle, edges: torch.Tensor,
                keep: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Render rays that may hit the surface, given their section edges ``[n_rays, n + 1]``.

        With ``keep`` (``[n_rays, n]`` bool) only those samples are evaluated, packed row-major as in
        ``samples.positions[keep]``; the others get alpha 0. Per-sample outputs (weights, gradients,
        inside) are then packed too."""
        samples = RaySamples.from_edges(ray_bundle, edges)
        pack = (lambda t: t) if keep is None else (lambda t: t[keep])
        unpack = (lambda t: t) if keep is None else (lambda t: scatter(t, keep))
        sample_cameras = pack(samples.camera_indices[:, None].expand(samples.t_mid.shape))
        if self.sdf_gradient == "analytic":  # a graph only while training: evaluation records nothing
            with torch.set_grad_enabled(self.training), stage("sdf_gradient"):
                positions = pack(samples.positions).detach()
                sdf, geo_features, gradients = self.field.geometry_and_gradient(positions)
        else:
            with torch.enable_grad(), stage("sdf_gradient"):  # the field's forward is timed on its own
                positions = pack(samples.positions).detach().requires_grad_(True)
                sdf, geo_features = self.field.geometry(positions)
                gradients = torch.autograd.grad(sdf, positions, torch.ones_like(sdf),
                                                create_graph=self.training, retain_graph=True)[0]
        if not self.training:
            sdf, geo_features, gradients = sdf.detach(), geo_features.detach(), gradients.detach()
        directions = pack(samples.directions[:, None, :].expand(samples.positions.shape))
        true_cos = (directions * gradients).sum(-1)
        alpha = unpack(neus_alpha(sdf[..., 0], true_cos, pack(samples.deltas), self.variance.inv_s(),
                                  self.cos_anneal_ratio()))
        weights = renderers.weights_from_alpha(alpha)
        sample_weights = pack(weights)
        normals = torch.nn.functional.normalize(gradients, dim=-1, eps=1e-6)
        camera_indices = sample_cameras
        ray_indices = pack(torch.arange(alpha.shape[0], device=alpha.device)[:, None].expand(alpha.shape))
        color = self.field.color(positions if self.training else positions.detach(), directions, normals,
                                 geo_features, camera_indices, weights=sample_weights.detach(),
                                 ray_indices=ray_indices)
        outputs = {
            "rgb": renderers.render_rgb(weights, unpack(color["rgb"]), self.background),
            "accumulation": weights.sum(-1, keepdim=True),
            "depth": renderers.render_depth(weights, samples.t_mid),
            "normal": (weights[..., None] * unpack(normals)).sum(-2),
            "weights": sample_weights,
            "gradients": gradients,
            "inside": (positions.detach().norm(dim=-1) < self.scene.scene_radius),
        }
        return self.composite_other_colors(outputs, color, weights, unpack)

    def get_loss_dict(self, outputs, batch) -> dict[str, torch.Tensor]:
        """Scalar terms ``[]``: ``rgb``, and those whose weight is on: ``eikonal`` (of ``gradients [k, 3]``),
        ``mask``, ``normal``, ``crossings``; then the shared ones (:meth:`Model.apply_extra_losses`)."""
        cfg = self.config
        loss = {"rgb": losses.rgb_loss(outputs["rgb"], batch["rgb"])}
        if cfg.eikonal_weight > 0:
            loss["eikonal"] = cfg.eikonal_weight * losses.eikonal_loss(outputs["gradients"], outputs["inside"])
        if cfg.mask_weight > 0 and "mask" in batch:
            loss["mask"] = cfg.mask_weight * losses.mask_loss(outputs["accumulation"], batch["mask"])
        if cfg.normal_weight > 0 and "normal" in batch:
            loss["normal"] = cfg.normal_weight * losses.normal_loss(outputs["normal"], batch["normal"])
        if self.crossings_weight > 0 and self.training and self.step >= cfg.crossings_start * self.scene.schedule_steps:
            loss["crossings"] = self.crossings_weight * self._crossings(outputs["accumulation"].device)
        return self.apply_extra_losses(loss, outputs, batch)

    def _crossings(self, device: torch.device) -> torch.Tensor:
        """Half the mean number of surface crossings of random lines through the scene sphere (the
        crossings prior, a scalar ``[]``), from stratified samples of the SDF on each line's chord."""
        cfg = self.config
        rays = isotropic_rays(cfg.crossings_rays, self.scene.scene_radius, device=device)
        nears, fars, _ = near_far_from_sphere(rays.origins, rays.directions, self.scene.scene_radius)
        return surface_crossings(lambda p: self.field.geometry(p)[0][..., 0], rays.origins, rays.directions,
                                 nears, fars, cfg.crossings_samples).mean()

    # -- export ---------------------------------------------------------------------------------
    @torch.no_grad()
    def mesh_field(self, points: torch.Tensor) -> torch.Tensor:
        """The SDF ``[n]`` at points ``[n, 3]``, negative inside."""
        return self.field.geometry(points)[0][..., 0]

    def surface_color(self, points: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        """RGB ``[n, 3]`` of surface points ``[n, 3]`` seen head-on against their normals ``[n, 3]``, from the
        canonical feature (camera index -1)."""
        with torch.no_grad():
            _, geo_features = self.field.geometry(points)
            camera = torch.full(points.shape[:-1], -1, dtype=torch.long, device=points.device)
            return self.field.color(points, -normals, normals, geo_features, camera)["rgb"]


SDF_GRADIENTS = ("auto", "autograd", "analytic")
"""The values of ``NeuSModelConfig.sdf_gradient``."""


PER_RAY_KEYS = ("rgb", "accumulation", "depth", "normal")


def _scatter_rays(inner: dict[str, torch.Tensor], index: torch.Tensor, n_rays: int,
                  background: torch.Tensor, blank: bool = False) -> dict[str, torch.Tensor]:
    """Per-ray outputs ``[n_rays, ...]`` from those ``[len(index), ...]`` of the rendered subset ``index``
    ``[len(index)]``; skipped rays
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


def crossings_apply(config: NeuSModelConfig, scene: SceneInfo) -> bool:
    """Whether the crossings prior runs in ``scene``: always when ``config.crossings_orthographic`` is set,
    else unless the training cameras are orthographic and there are no normal maps."""
    if config.crossings_orthographic or scene.has_normals or scene.train_cameras is None:
        return True
    return scene.train_cameras.camera_type != ORTHOGRAPHIC
