"""The va methods as nerfstudio ``MethodSpecification`` s, made from our registered methods.

``va-neus`` and ``va-ngp`` are the paper's view-adaptive methods, ``va-plugin-neus`` our NeuS backbone
(nerfstudio has a ``neus`` of its own). Each keeps its ``va-train`` defaults: the model and field, rays per
batch, learning rates, warm-up and cosine schedule, step budget and seed. The trainer runs on CUDA when
there is one, else on the CPU; the viewer listens on 127.0.0.1.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from nerfstudio.configs.base_config import MachineConfig, ViewerConfig
from nerfstudio.engine.optimizers import AdamOptimizerConfig
from nerfstudio.engine.trainer import Trainer, TrainerConfig
from nerfstudio.plugins.types import MethodSpecification

from va_plugin.nerfstudio.datamanager import VAGeneratorDataManagerConfig
from va_plugin.nerfstudio.dataparser import VAGeneratorDataParserConfig
from va_plugin.nerfstudio.model import VAModelConfig
from va_plugin.nerfstudio.pipeline import VAPipelineConfig
from va_plugin.registry import builtin_methods

NERFSTUDIO_NAMES = {"va-neus": "va-neus", "va-ngp": "va-ngp", "va-plugin-neus": "neus"}
"""Name in nerfstudio -> our method it is made from."""


@dataclass
class FusedAdamConfig(AdamOptimizerConfig):
    """Adam on its fused kernel (one pass over each tensor), as va-train runs it."""

    fused: bool = True
    """Use the fused kernel (CPU and CUDA floating-point parameters)."""


@dataclass
class VATrainerConfig(TrainerConfig):
    """nerfstudio's trainer config, which tells the pipeline the step budget (our schedules end at it)."""

    _target: type = field(default_factory=lambda: Trainer)
    pipeline: VAPipelineConfig = field(default_factory=VAPipelineConfig)
    """The va pipeline: data manager, model and schedules."""

    def __post_init__(self) -> None:
        self.pipeline.max_steps = self.max_num_iterations

    def set_experiment_name(self) -> None:
        """The input's name (also when --data is given to the dataparser)."""
        if self.experiment_name is None and self.pipeline.datamanager.data is None:
            data = self.pipeline.datamanager.dataparser.data
            if str(data) not in ("", "."):
                self.experiment_name = data.stem
        super().set_experiment_name()


def nerfstudio_config(name: str, ours: str) -> VATrainerConfig:
    """The trainer config of our method ``ours`` under the nerfstudio name ``name``."""
    config = builtin_methods()[ours].make_config()
    data = config.pipeline.datamanager
    parser = VAGeneratorDataParserConfig(background=tuple(data.dataparser.background),
                                         scene_radius=data.dataparser.scene_radius,
                                         image_scale=data.dataparser.image_scale)
    datamanager = VAGeneratorDataManagerConfig(dataparser=parser, rays_per_batch=data.rays_per_batch,
                                               foreground_fraction=data.foreground_fraction, seed=data.seed)
    optimizers = {group: {"optimizer": FusedAdamConfig(lr=opt.lr, eps=opt.eps, weight_decay=opt.weight_decay),
                          "scheduler": None}
                  for group, opt in config.optimizers.items()}
    return VATrainerConfig(
        method_name=name,
        max_num_iterations=config.max_steps,
        steps_per_save=config.checkpoint_every,
        # the va methods evaluate with va-eval; the viewer shows the training
        steps_per_eval_batch=0, steps_per_eval_image=0, steps_per_eval_all_images=0,
        mixed_precision=False,
        machine=MachineConfig(seed=config.seed, device_type="cuda" if torch.cuda.is_available() else "cpu"),
        viewer=ViewerConfig(websocket_host="127.0.0.1", num_rays_per_chunk=config.pipeline.model.eval_chunk),
        vis="viewer",
        pipeline=VAPipelineConfig(datamanager=datamanager, model=VAModelConfig(va=config.pipeline.model),
                                  scheduler=config.scheduler, schedule_steps=config.schedule_steps,
                                  average_fraction=config.average_fraction),
        optimizers=optimizers,
    )


def _specification(name: str, description: str) -> MethodSpecification:
    return MethodSpecification(config=nerfstudio_config(name, NERFSTUDIO_NAMES[name]), description=description)


va_neus = _specification("va-neus", "va-plugin: view-adaptive NeuS (per-view branches, attention fusion, three "
                                    "phases) on a CPU hash-grid SDF")
va_ngp = _specification("va-ngp", "va-plugin: view-adaptive InstantNGP-style density field (CPU hash grid)")
va_plugin_neus = _specification("va-plugin-neus", "va-plugin: NeuS on a CPU hash-grid SDF (no tiny-cuda-nn)")
