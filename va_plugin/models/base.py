"""The Model interface: rays in, rendered outputs and losses out."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from va_plugin.cameras import Cameras
from va_plugin.config import InstantiateConfig
from va_plugin.fields.base import Field
from va_plugin.model_components import renderers
from va_plugin.model_components.losses import psnr_from_mse, rgb_loss
from va_plugin.rays import RayBundle


@dataclass
class SceneInfo:
    """What a model needs to know about its scene."""

    num_train_views: int
    scene_radius: float
    background: Sequence[float] = (1.0, 1.0, 1.0)
    schedule_steps: int = 1000  # where the run's schedules end (the trainer's ``schedule_steps_of``)
    train_cameras: Cameras | None = None  # on the device (the NGP occupancy grid keeps cells they all see)
    train_masks: torch.Tensor | None = None  # [n, H, W, 1] foreground of the training views, or None
    has_normals: bool = False  # whether the training views come with normal maps


@dataclass
class ModelConfig(InstantiateConfig):
    """Options every model has."""

    eval_chunk: int = 2048
    """Rays rendered at once when rendering whole images."""

    def samples_per_ray(self) -> int:
        """The most samples a training ray evaluates with gradients (for the up-front memory estimate); a
        model config that samples rays says how many (0: no estimate)."""
        return 0


ExtraLoss = Callable[[dict[str, torch.Tensor], dict[str, torch.Tensor], int], dict[str, torch.Tensor]]


class Model(nn.Module):
    """Base class of models. Subclasses set ``field`` and implement ``get_outputs`` and ``get_loss_dict``."""

    config: ModelConfig
    field: Field
    fill_mesh_cavities: bool = False
    """Whether :func:`va_plugin.export.mesh.extract_mesh` makes enclosed empty space solid (ngp sets it)."""
    mesh_field_lipschitz: float | None = None
    """A bound on the gradient norm of :meth:`mesh_field` when it is a signed distance that
    :meth:`prepare_mesh_grid` leaves as it is (None: it is not), so that the mesh's grid skips the blocks
    it places away from the surface (:func:`va_plugin.export.mesh.sample_distance_grid`)."""

    def __init__(self, config: ModelConfig, scene: SceneInfo) -> None:
        super().__init__()
        self.config = config
        self.scene = scene
        self.register_buffer("background", torch.tensor(list(scene.background), dtype=torch.float32),
                             persistent=False)
        self.step = 0
        self.extra_losses: list[ExtraLoss] = []  # hooks adding loss terms: ``(outputs, batch, step) -> dict``

    # -- training -------------------------------------------------------------------------------
    def update_step(self, step: int) -> None:
        """Called by the trainer before each step; schedules read ``self.step``, and the field's own
        schedules (``Field.update_step``) follow."""
        self.step = step
        self.field.update_step(step, self.scene.schedule_steps)

    def restore_step(self, step: int) -> None:
        """Set the step schedules (``self.step``, the field's) as :meth:`update_step` sets them for step
        ``step``, without touching any parameter: for a model loaded from a checkpoint."""
        Model.update_step(self, step)

    def get_outputs(self, ray_bundle: RayBundle) -> dict[str, torch.Tensor]:
        """The ``R`` rays of ``ray_bundle`` rendered: ``rgb [R, 3]``, ``accumulation [R, 1]``, ``depth [R, 1]``,
        and the model's own outputs (per-sample ones, such as ``weights``, packed over the samples evaluated)."""
        raise NotImplementedError

    def get_loss_dict(self, outputs: dict[str, torch.Tensor], batch: dict[str, torch.Tensor]
                      ) -> dict[str, torch.Tensor]:
        """Scalar loss terms ``[]`` of ``outputs`` (:meth:`get_outputs`) against the ``batch`` of ``R`` rays:
        ``rgb [R, 3]``, and where the inputs have them ``mask [R, 1]`` and ``normal [R, 3]``."""
        raise NotImplementedError

    def composite_other_colors(self, outputs: dict[str, torch.Tensor], color: dict[str, torch.Tensor],
                                weights: torch.Tensor, per_ray: Callable[[torch.Tensor], torch.Tensor]
                                ) -> dict[str, torch.Tensor]:
        """``outputs`` plus the field's other per-sample outputs besides ``rgb``: colors (``rgb_*``, e.g. the
        canonical or the shared one) composited per ray with ``weights [R, s]``, anything else as it is.
        ``per_ray`` lays a per-sample tensor out as ``[R, s, ...]``."""
        for key, value in color.items():
            if key == "rgb":
                continue
            if key.startswith("rgb_"):
                outputs[key] = renderers.render_rgb(weights, per_ray(value), self.background)
            else:
                outputs[key] = value
        return outputs

    def apply_extra_losses(self, losses: dict[str, torch.Tensor], outputs, batch) -> dict[str, torch.Tensor]:
        """The losses every model shares, after its own: the field's (``extra_losses``, e.g. the
        view-adaptive regularizers) and the registered hooks', each a scalar ``[]``."""
        losses.update(self.field.extra_losses(outputs, batch, self.color_loss))
        for hook in self.extra_losses:
            losses.update(hook(outputs, batch, self.step))
        return losses

    def color_loss(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """The model's photometric loss (mean squared error) of rendered against target colors ``[R, 3]``."""
        return rgb_loss(pred, target)

    def get_metrics_dict(self, outputs: dict[str, torch.Tensor], batch: dict[str, torch.Tensor]
                         ) -> dict[str, float]:
        """Training-batch PSNR of the rendered color."""
        mse = ((outputs["rgb"].detach() - batch["rgb"].detach()) ** 2).mean()
        return {"psnr": float(psnr_from_mse(mse))}

    def get_param_groups(self) -> dict[str, list[nn.Parameter]]:
        raise NotImplementedError

    def training_callbacks(self) -> list[object]:
        """Callbacks the trainer runs (e.g. phase switches); the model knows nothing of the trainer.
        By default those of the model's ``field``."""
        return list(self.field.training_callbacks())

    def diagnostics(self) -> dict[str, float]:
        """Scalars worth logging (e.g. inv_s); by default those of the model's ``field``."""
        return dict(self.field.diagnostics())

    def sharpness(self) -> float | None:
        """NeuS's inv_s for the training guard's collapse test; None for models without one."""
        return None

    # -- evaluation and export ------------------------------------------------------------------
    def render_rays(self, ray_bundle: RayBundle, keys: Sequence[str] = ("rgb", "accumulation", "depth")
                    ) -> dict[str, torch.Tensor]:
        """Render many rays in chunks without building a graph; returns the chosen outputs, each
        ``[n_rays, ...]`` (``rgb [n_rays, 3]``, ``accumulation`` and ``depth [n_rays, 1]``)."""
        was_training = self.training
        self.eval()
        collected: dict[str, list[torch.Tensor]] = {k: [] for k in keys}
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
        """Canonical RGB ``[n, 3]`` of surface points seen head-on from outside (mesh vertex colors)."""
        raise NotImplementedError

    def prepare_mesh_grid(self, values: np.ndarray, spacing: float) -> np.ndarray:
        """The grid ``[r, r, r]`` of :meth:`mesh_field` values (cells ``spacing`` apart) as marching cubes
        should see it (e.g. ngp's density smoothed in log space); unchanged by default."""
        return values

