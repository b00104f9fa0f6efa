"""The Model interface: rays in, rendered outputs and losses out."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence

import torch
from torch import nn

from va_plugin.cameras import Cameras
from va_plugin.config import InstantiateConfig
from va_plugin.engine.callbacks import AFTER_STEP, TrainingCallback, TrainingCallbackAttributes
from va_plugin.model_components import renderers
from va_plugin.model_components.losses import psnr_from_mse, rgb_loss
from va_plugin.model_components.view_appearance import ViewAppearanceConfig
from va_plugin.model_components.view_blur import ViewBlurConfig
from va_plugin.model_components.view_warp import ViewWarpConfig
from va_plugin.rays import RayBundle


@dataclass
class SceneInfo:
    """What a model needs to know about its scene."""

    num_train_views: int
    scene_radius: float
    background: Sequence[float] = (1.0, 1.0, 1.0)
    max_steps: int = 1000
    """The step at which the run's schedules end (``schedule_horizon`` of the trainer config: the budget, or
    ``schedule_steps`` when that is shorter); the model's schedules are fractions of it."""
    train_cameras: Optional[Cameras] = None
    """The training views' cameras (the NGP occupancy grid keeps only cells they all see), on the device."""


@dataclass
class ModelConfig(InstantiateConfig):
    """Options every model has."""

    rgb_loss: str = "l2"
    """Photometric loss: "l2" (the paper's eq. 13) or "l1"."""
    eval_chunk: int = 2048
    """Rays rendered at once when rendering whole images."""
    grid_decay_weight: float = 0.0
    """Normalised weight decay of the field's hash grids: the weight times the sum over levels of each
    level's mean squared feature (every level counts alike whatever its size). Under Adam it pulls the
    entries that few rays reach towards zero while those the photometric loss keeps using stay; 0 (the
    default) turns it off. Fields without a hash grid ignore it."""
    view_appearance: ViewAppearanceConfig = field(default_factory=ViewAppearanceConfig)
    """Per-view colour correction of the training views' renders (``mode``: off, gain or affine; its
    learning rate is the "view_appearance" optimizer group). Novel views and mesh colours never use it."""
    view_warp: ViewWarpConfig = field(default_factory=ViewWarpConfig)
    """Per-view smooth image warp of the training targets (``enabled``; its learning rate is the "view_warp"
    optimizer group): view i's ray through pixel p is compared with the input at p + s_i(p). The geometry,
    the mesh and novel views never use it."""
    view_blur: ViewBlurConfig = field(default_factory=ViewBlurConfig)
    """Per-view learned blur of the training views' renders (``enabled``; its learning rate is the
    "view_blur" optimizer group): view i's pixel is compared with the field rendered through a point-spread
    function of its own, so a soft generated view need not make the shared field soft. Novel views and the
    mesh never use it."""


VIEW_APPEARANCE_FILE = "view_appearance.json"
"""In a run folder with per-view appearance: each training view's colour matrix and offset."""
VIEW_WARP_FILE = "view_warp.json"
"""In a run folder with per-view warps: each training view's RMS and largest shift."""
VIEW_BLUR_FILE = "view_blur.json"
"""In a run folder with per-view blur: each training view's ring weight and blur (pixels)."""

ExtraLoss = Callable[[Dict[str, torch.Tensor], Dict[str, torch.Tensor], int], Dict[str, torch.Tensor]]


class Model(nn.Module):
    """Base class of models. Subclasses implement ``get_outputs`` and ``get_loss_dict``."""

    config: ModelConfig

    def __init__(self, config: ModelConfig, scene: SceneInfo) -> None:
        super().__init__()
        self.config = config
        self.scene = scene
        self.register_buffer("background", torch.tensor(list(scene.background), dtype=torch.float32),
                             persistent=False)
        self.step = 0
        self.extra_losses: List[ExtraLoss] = []
        """Hooks adding loss terms (e.g. a score-distillation loss): ``(outputs, batch, step) -> dict``."""
        self.view_appearance = config.view_appearance.setup(num_views=scene.num_train_views) \
            if config.view_appearance.mode != "off" else None
        """Per-view colour corrections, or None (then the state dict has no entry for them)."""
        self.view_warp = config.view_warp.setup(num_views=scene.num_train_views) \
            if config.view_warp.enabled else None
        """Per-view target warps (applied by the pipeline to each batch's targets), or None."""
        self.view_blur = config.view_blur.setup(num_views=scene.num_train_views) \
            if config.view_blur.enabled else None
        """Per-view point-spread functions (the pipeline renders each batch through them), or None."""

    # -- training -------------------------------------------------------------------------------
    def update_step(self, step: int) -> None:
        """Called by the trainer before each step; schedules read ``self.step``, and the field's own
        schedules (``Field.update_step``) follow."""
        self.step = step
        field = getattr(self, "field", None)
        if field is not None:
            field.update_step(step, self.scene.max_steps)
        if self.view_warp is not None:
            self.view_warp.set_step(step, self.scene.max_steps)
        if self.view_blur is not None:
            self.view_blur.set_step(step, self.scene.max_steps)

    def get_outputs(self, ray_bundle: RayBundle) -> Dict[str, torch.Tensor]:
        raise NotImplementedError

    def get_loss_dict(self, outputs: Dict[str, torch.Tensor], batch: Dict[str, torch.Tensor]
                      ) -> Dict[str, torch.Tensor]:
        raise NotImplementedError

    def apply_view_appearance(self, outputs: Dict[str, torch.Tensor], ray_bundle: RayBundle
                              ) -> Dict[str, torch.Tensor]:
        """``outputs`` with each training view's colour correction applied to ``rgb`` (unchanged without
        per-view appearance; novel-view rays, camera index -1, are never changed)."""
        if self.view_appearance is not None:
            outputs["rgb"] = self.view_appearance.apply(outputs["rgb"], outputs["accumulation"], self.background,
                                                        ray_bundle.camera_indices)
        return outputs

    def with_shared_param_groups(self, groups: Dict[str, List[nn.Parameter]]) -> Dict[str, List[nn.Parameter]]:
        """``groups`` plus the groups of the parts every model may have (the per-view colour correction)."""
        if self.view_appearance is not None:
            groups["view_appearance"] = list(self.view_appearance.parameters())
        if self.view_warp is not None:
            groups["view_warp"] = list(self.view_warp.parameters())
        if self.view_blur is not None:
            groups["view_blur"] = list(self.view_blur.parameters())
        return groups

    def rgb_weights(self, weights: torch.Tensor) -> torch.Tensor:
        """The rendering weights to composite ``rgb`` with: detached while the field lists ``rgb`` in its
        ``detached_weight_keys`` (a view-adaptive field whose branch colours must not reshape the shared
        geometry, see ``branch_colour_reaches_shared``), else ``weights`` themselves."""
        detached = getattr(getattr(self, "field", None), "detached_weight_keys", ())
        return weights.detach() if "rgb" in detached else weights

    def composite_other_colours(self, outputs: Dict[str, torch.Tensor], color: Dict[str, torch.Tensor],
                                weights: torch.Tensor, per_ray: Callable[[torch.Tensor], torch.Tensor]
                                ) -> Dict[str, torch.Tensor]:
        """``outputs`` plus the field's other per-sample outputs besides ``rgb``: colours (``rgb_*``, e.g. the
        canonical or the shared one) composited per ray with ``weights [R, s]`` (detached for the keys the
        field lists in ``detached_weight_keys``: a loss on them then trains the colour, not the opacities),
        anything else as it is. ``per_ray`` lays a per-sample tensor out as ``[R, s, ...]``."""
        detached = getattr(getattr(self, "field", None), "detached_weight_keys", ())
        for key, value in color.items():
            if key == "rgb":
                continue
            if key.startswith("rgb_"):
                w = weights.detach() if key in detached else weights
                outputs[key] = renderers.render_rgb(w, per_ray(value), self.background)
            else:
                outputs[key] = value
        return outputs

    def apply_extra_losses(self, losses: Dict[str, torch.Tensor], outputs, batch) -> Dict[str, torch.Tensor]:
        """The losses every model shares, after its own: the grid decay (``grid_decay_weight``), the
        field's (``extra_losses``, e.g. the view-adaptive regularizers), the per-view corrections' penalties
        and the registered hooks'."""
        if self.config.grid_decay_weight > 0:
            grids = self.hash_grids()
            if grids:
                losses["grid_decay"] = self.config.grid_decay_weight * sum(
                    grid.level_mean_squares().sum() for grid in grids)
        field_losses = getattr(getattr(self, "field", None), "extra_losses", None)
        if field_losses is not None:
            losses.update(field_losses(outputs, batch, self.colour_loss))
        if self.view_appearance is not None:
            losses["view_appearance"] = self.view_appearance.loss()
        if self.view_warp is not None:
            losses["view_warp"] = self.view_warp.loss()
        if self.view_blur is not None and self.config.view_blur.penalty_weight > 0:
            losses["view_blur"] = self.view_blur.loss()
        for hook in self.extra_losses:
            losses.update(hook(outputs, batch, self.step))
        return losses

    def hash_grids(self) -> List[nn.Module]:
        """The hash-grid encodings of the model's field (the backbone's inside a view-adaptive wrapper)."""
        from va_plugin.fields.encodings.hash_grid import HashGridEncoding

        field = getattr(self, "field", None)
        return [m for m in field.modules() if isinstance(m, HashGridEncoding)] if field is not None else []

    def colour_loss(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """The model's plain photometric loss (``rgb_loss``) of rendered against target colours ``[R, 3]``."""
        return rgb_loss(pred, target, self.config.rgb_loss)

    def get_metrics_dict(self, outputs: Dict[str, torch.Tensor], batch: Dict[str, torch.Tensor]
                         ) -> Dict[str, float]:
        """Training-batch PSNR of the rendered colour."""
        mse = ((outputs["rgb"].detach() - batch["rgb"].detach()) ** 2).mean()
        return {"psnr": float(psnr_from_mse(mse))}

    def get_param_groups(self) -> Dict[str, List[nn.Parameter]]:
        raise NotImplementedError

    def training_callbacks(self) -> List[object]:
        """Callbacks the trainer runs (e.g. phase switches); the model knows nothing of the trainer.
        By default those of the model's ``field``, if it has any."""
        make = getattr(getattr(self, "field", None), "training_callbacks", None)
        callbacks = list(make()) if make is not None else []
        if self.view_appearance is not None:
            callbacks.append(TrainingCallback(self._write_view_appearance, AFTER_STEP))
        if self.view_warp is not None:
            callbacks.append(TrainingCallback(self._write_view_warp, AFTER_STEP))
        if self.view_blur is not None:
            callbacks.append(TrainingCallback(self._write_view_blur, AFTER_STEP))
        return callbacks

    def _write_view_appearance(self, step: int, attributes: TrainingCallbackAttributes) -> None:
        self.write_after_last_step(step, attributes, VIEW_APPEARANCE_FILE, self.view_appearance.summary,
                                   lambda s: f"view appearance: largest colour change {s['max_change']:.4f}")

    def _write_view_warp(self, step: int, attributes: TrainingCallbackAttributes) -> None:
        self.write_after_last_step(step, attributes, VIEW_WARP_FILE, self.view_warp.summary,
                                   lambda s: f"view warp: largest shift {s['largest_px']:.2f} px")

    def _write_view_blur(self, step: int, attributes: TrainingCallbackAttributes) -> None:
        self.write_after_last_step(step, attributes, VIEW_BLUR_FILE, self.view_blur.summary,
                                   lambda s: f"view blur: largest {s['largest_sigma_px']:.2f} px")

    @staticmethod
    def write_after_last_step(step: int, attributes: TrainingCallbackAttributes, filename: str,
                              summarize: Callable[[], Dict[str, object]],
                              describe: Callable[[Dict[str, object]], str]) -> None:
        """After the last step only: ``summarize()`` as JSON to ``RUN/filename``, announced as ``describe``
        says."""
        if step + 1 != attributes.max_steps:
            return
        summary = summarize()
        run_dir = Path(attributes.run_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / filename).write_text(json.dumps(summary, indent=2))
        attributes.announce(step, f"{describe(summary)} ({filename})")

    def diagnostics(self) -> Dict[str, float]:
        """Scalars worth logging (e.g. inv_s); by default those of the model's ``field``."""
        report = getattr(getattr(self, "field", None), "diagnostics", None)
        out = dict(report()) if report is not None else {}
        if self.view_appearance is not None:
            out["appearance_max"] = round(self.view_appearance.max_change(), 5)
        if self.view_warp is not None:
            out["warp_max_px"] = round(self.view_warp.largest(), 4)
        if self.view_blur is not None:
            out["blur_max_px"] = round(float(self.view_blur.sigma_px().max()), 4)
        return out

    def sharpness(self) -> Optional[float]:
        """NeuS's inv_s for the training guard's collapse test; None for models without one."""
        return None

    # -- evaluation and export ------------------------------------------------------------------
    def render_rays(self, ray_bundle: RayBundle, keys: Sequence[str] = ("rgb", "accumulation", "depth")
                    ) -> Dict[str, torch.Tensor]:
        """Render many rays in chunks without building a graph; returns the chosen outputs."""
        was_training = self.training
        self.eval()
        collected: Dict[str, List[torch.Tensor]] = {k: [] for k in keys}
        try:
            for start in range(0, len(ray_bundle), self.config.eval_chunk):
                chunk = ray_bundle[start:start + self.config.eval_chunk]
                outputs = self.get_outputs(chunk)
                for k in keys:
                    collected[k].append(outputs[k].detach())
        finally:
            self.train(was_training)
        return {k: torch.cat(v) for k, v in collected.items()}

    def mesh_field(self, points: torch.Tensor) -> torch.Tensor:
        """A scalar ``[n]`` at points ``[n, 3]`` whose zero level set is the surface, negative inside."""
        raise NotImplementedError

    def surface_color(self, points: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        """Canonical RGB ``[n, 3]`` of surface points seen head-on from outside (mesh vertex colours)."""
        raise NotImplementedError

