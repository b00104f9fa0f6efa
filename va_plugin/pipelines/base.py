"""The Pipeline: one DataManager and one Model, with a training step and evaluation."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

from va_plugin.config import InstantiateConfig
from va_plugin.data.datamanager import DataManager, DataManagerConfig
from va_plugin.model_components.losses import psnr_from_mse
from va_plugin.models.base import ModelConfig, SceneInfo
from va_plugin.models.neus import NeuSModelConfig
from va_plugin.utils.stages import stage


@dataclass
class PipelineConfig(InstantiateConfig):
    """A data manager and a model."""

    _target: type = field(default_factory=lambda: Pipeline)
    datamanager: DataManagerConfig = field(default_factory=DataManagerConfig)
    """Where training rays come from."""
    model: ModelConfig = field(default_factory=NeuSModelConfig)
    """What renders them."""


class Pipeline(nn.Module):
    def __init__(self, config: PipelineConfig, device: torch.device, schedule_steps: int,
                 datamanager: DataManager | None = None) -> None:
        """``datamanager``: one already built from ``config.datamanager`` (a host framework's data manager
        holds it); by default it is built here."""
        super().__init__()
        self.config = config
        self.device = device
        self.datamanager = config.datamanager.setup(device=device) if datamanager is None else datamanager
        scene = SceneInfo(num_train_views=self.datamanager.num_train_views,
                          scene_radius=self.datamanager.scene_radius,
                          background=self.datamanager.background, schedule_steps=schedule_steps,
                          train_cameras=self.datamanager.cameras, train_masks=self.datamanager.masks,
                          has_normals=self.datamanager.normals is not None)
        self.model = config.model.setup(scene=scene).to(device)

    def train_step(self, step: int) -> tuple[dict[str, torch.Tensor], dict[str, float]]:
        """Losses (weighted, to be summed) and metrics of one training batch."""
        self.model.update_step(step)
        with stage("data"):
            ray_bundle, batch = self.datamanager.next_train(step)
        with stage("rendering"):  # what the stages nested in the model's forward (sampling, ...) leave
            outputs = self.model.get_outputs(ray_bundle)
            loss_dict = self.model.get_loss_dict(outputs, batch)
        metrics = self.model.get_metrics_dict(outputs, batch)
        return loss_dict, metrics

    @torch.no_grad()
    def evaluate_views(self, max_views: int | None = None) -> tuple[dict[str, float], list[dict[str, torch.Tensor]]]:
        """Render the held-out views; mean PSNR and the rendered images ``[H, W, 3]``."""
        renders, psnrs = [], []
        height, width = (self.datamanager.test.cameras.height, self.datamanager.test.cameras.width) \
            if self.datamanager.test is not None else (0, 0)
        for index, rays, image, _mask in self.datamanager.eval_views():
            if max_views is not None and index >= max_views:
                break
            out = self.model.render_rays(rays)
            rgb = out["rgb"].reshape(height, width, 3).cpu()
            renders.append({"rgb": rgb, "accumulation": out["accumulation"].reshape(height, width, 1).cpu(),
                            "target": image})
            psnrs.append(float(psnr_from_mse(((rgb - image) ** 2).mean())))
        metrics = {"eval_psnr": sum(psnrs) / len(psnrs)} if psnrs else {}
        return metrics, renders
