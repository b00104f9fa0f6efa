"""The ``neus`` method: NeuS with a positional-encoding SDF network, sized for 2 CPU cores."""

from __future__ import annotations

from va_plugin.data.datamanager import DataManagerConfig
from va_plugin.engine.optimizers import OptimizerConfig, SchedulerConfig
from va_plugin.engine.trainer import TrainerConfig
from va_plugin.fields.sdf_field import SDFFieldConfig
from va_plugin.models.neus import NeuSModelConfig
from va_plugin.pipelines.base import PipelineConfig
from va_plugin.registry import MethodSpecification, Preset


def neus_config() -> TrainerConfig:
    """The default NeuS run: about 4 minutes of training on 2 CPU cores for a 4-view object."""
    return TrainerConfig(
        method_name="neus",
        pipeline=PipelineConfig(
            datamanager=DataManagerConfig(rays_per_batch=512, foreground_fraction=0.5),
            model=NeuSModelConfig(field=SDFFieldConfig(sdf_width=128, sdf_layers=4, color_width=128,
                                                       color_layers=2, geo_feature_dim=64),
                                  n_samples=32, n_importance=32, up_sample_steps=2),
        ),
        optimizers={"fields": OptimizerConfig(lr=2e-3)},
        scheduler=SchedulerConfig(warmup_steps=100, final_fraction=0.05),
        max_steps=500,
    )


def _fast(config: TrainerConfig) -> None:
    config.max_steps = 250
    config.pipeline.datamanager.rays_per_batch = 256
    config.pipeline.model.n_samples = 24
    config.pipeline.model.n_importance = 24


def _accurate(config: TrainerConfig) -> None:
    """The paper's network (4 x 256 shared MLP) with more samples and steps."""
    config.max_steps = 6000
    config.pipeline.datamanager.rays_per_batch = 1024
    config.pipeline.model.field.sdf_width = 256
    config.pipeline.model.field.geo_feature_dim = 256
    config.pipeline.model.n_samples = 64
    config.pipeline.model.n_importance = 64
    config.pipeline.model.up_sample_steps = 4
    config.optimizers["fields"].lr = 5e-4


neus = MethodSpecification(
    config=neus_config(),
    description="NeuS surface reconstruction (SDF field, up-sampling, eikonal + mask losses)",
    presets={
        "fast": Preset("fewer rays, samples and steps: a rough mesh quickly", _fast),
        "accurate": Preset("the paper's 4x256 network, 128 samples per ray, 6000 steps", _accurate),
    },
)
