"""Our models (NeuS, NGP, each with or without the view-adaptive field) behind nerfstudio's ``Model``.

The pipeline builds our model (so that the random initialisation draws what ``va-train``'s does) and hands
it in as ``va_model``; this class forwards nerfstudio's calls to it, renders the viewer's cameras with it,
and turns its training callbacks (the view-adaptive phases, the step schedules) into nerfstudio's.
``field`` is its field behind nerfstudio's ``Field``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import torch
from nerfstudio.cameras.cameras import Cameras as NSCameras
from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.models.base_model import Model, ModelConfig

from va_plugin.callbacks import AFTER_STEP
from va_plugin.callbacks import TrainingCallbackAttributes as VAAttributes
from va_plugin.models.base import ModelConfig as VAModelConfigBase
from va_plugin.models.neus import NeuSModelConfig
from va_plugin.nerfstudio.field import VAField
from va_plugin.rays import RayBundle

NOVEL_VIEW = -1  # the camera index of rays from a camera that is no training view (the viewer's)
OUTPUTS = ("rgb", "accumulation", "depth")


@dataclass
class VAModelConfig(ModelConfig):
    """One of va-plugin's models (``va``: its options, as ``va-train --set pipeline.model.KEY=VALUE`` sets
    them)."""

    _target: type = field(default_factory=lambda: VAModel)
    enable_collider: bool = False
    """Off: our models bound their rays with the scene sphere themselves."""
    va: VAModelConfigBase = field(default_factory=NeuSModelConfig)
    """The va-plugin model and its field."""


class VAModel(Model):
    """nerfstudio's view of one of our models (``va_model``)."""

    config: VAModelConfig

    def populate_modules(self) -> None:
        self.va_model = self.kwargs["va_model"]
        object.__setattr__(self, "field", VAField(self.va_model.field))  # the same weights, reached once
        self.lr_factors: dict[str, float] = {}
        """Learning-rate factors by optimizer group, as our callbacks last asked (the pipeline applies them)."""

    def get_param_groups(self) -> dict[str, list[torch.nn.Parameter]]:
        return {name: params for name, params in self.va_model.get_param_groups().items() if params}

    def get_outputs(self, ray_bundle: RayBundle) -> dict[str, torch.Tensor]:
        return self.va_model.get_outputs(ray_bundle)

    def get_metrics_dict(self, outputs: dict[str, torch.Tensor], batch: dict[str, torch.Tensor]
                         ) -> dict[str, Any]:
        return {**self.va_model.get_metrics_dict(outputs, batch), **self.va_model.diagnostics()}

    def get_loss_dict(self, outputs: dict[str, torch.Tensor], batch: dict[str, torch.Tensor],
                      metrics_dict: dict[str, Any] | None = None) -> dict[str, torch.Tensor]:
        return self.va_model.get_loss_dict(outputs, batch)

    @torch.no_grad()
    def get_outputs_for_camera(self, camera: NSCameras, obb_box: Any = None) -> dict[str, torch.Tensor]:
        """A whole image of a nerfstudio camera (the viewer's, ns-render's): ``[H, W, C]`` outputs."""
        rays = camera.generate_rays(camera_indices=0, keep_shape=True, obb_box=obb_box)
        height, width = rays.origins.shape[:2]
        origins = rays.origins.reshape(-1, 3).to(self.device)
        directions = torch.nn.functional.normalize(rays.directions.reshape(-1, 3).to(self.device), dim=-1)
        bundle = RayBundle(origins, directions, torch.full((origins.shape[0],), NOVEL_VIEW, device=self.device))
        outputs = self.va_model.render_rays(bundle, OUTPUTS)
        return {key: value.reshape(height, width, -1) for key, value in outputs.items()}

    def get_image_metrics_and_images(self, outputs: dict[str, torch.Tensor], batch: dict[str, torch.Tensor]):
        image = batch["image"].to(outputs["rgb"])[..., :3]
        psnr = -10.0 * torch.log10(((outputs["rgb"] - image) ** 2).mean().clamp_min(1e-10))
        return {"psnr": float(psnr)}, {"img": torch.cat([image, outputs["rgb"]], dim=1)}

    def update_to_step(self, step: int) -> None:
        """A loaded checkpoint of step ``step``: our schedules as they stood then (no parameter changes)."""
        self.va_model.restore_step(step)

    def get_training_callbacks(self, training_callback_attributes: TrainingCallbackAttributes
                               ) -> list[TrainingCallback]:
        """Our model's callbacks (the view-adaptive phases) before each step, in our trainer's order, then
        the model's step schedules; the pipeline adds the learning rates."""
        attributes = va_attributes(training_callback_attributes)
        callbacks = []
        for callback in self.va_model.training_callbacks():
            where = (TrainingCallbackLocation.AFTER_TRAIN_ITERATION if callback.where == AFTER_STEP
                     else TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)
            callbacks.append(TrainingCallback([where], self._runner(callback, attributes)))
        callbacks.append(TrainingCallback([TrainingCallbackLocation.BEFORE_TRAIN_ITERATION],
                                          self._update_step))
        return callbacks

    def _runner(self, callback: Callable, attributes: VAAttributes) -> Callable[[int], None]:
        def run(step: int) -> None:
            factors = callback(step, attributes)
            if factors:
                self.lr_factors.update(factors)

        return run

    def _update_step(self, step: int) -> None:
        self.va_model.update_step(step)


def va_attributes(attributes: TrainingCallbackAttributes) -> VAAttributes:
    """What our callbacks read, from what nerfstudio's trainer gives: our pipeline (``pipeline.va``), the
    budget, the run folder, and an announcer that prints a line and logs it to the run's metrics.jsonl."""
    trainer, pipeline = attributes.trainer, attributes.pipeline
    return VAAttributes(pipeline=pipeline.va, max_steps=trainer.config.max_num_iterations, run_dir=trainer.base_dir,
                        progress=True, announce=pipeline.announce, schedule_steps=pipeline.schedule_steps)
