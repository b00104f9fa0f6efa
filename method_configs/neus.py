"""The ``neus`` method: NeuS on a hash-grid SDF field, sized for 2 CPU cores.

The default field is the hash-grid SDF (:class:`HashSDFFieldConfig`): a multiresolution hash encoding
with levels opening coarse to fine, a one-layer SDF MLP and a view-independent color MLP. A
positional-encoding network (a 4 x 128 SDF MLP, 500 steps) is the ``mlp`` preset; ``accurate`` is the
paper's 4 x 256 network.
"""

from __future__ import annotations

from va_plugin.data.datamanager import DataManagerConfig
from va_plugin.engine.optimizers import OptimizerConfig, SchedulerConfig
from va_plugin.engine.trainer import TrainerConfig
from va_plugin.fields.hash_sdf_field import HashSDFFieldConfig
from va_plugin.fields.sdf_field import SDFFieldConfig
from va_plugin.models.neus import NeuSModelConfig
from va_plugin.pipelines.base import PipelineConfig
from va_plugin.registry import MethodSpecification, Preset


def neus_config() -> TrainerConfig:
    """The default NeuS run on a 4-view object."""
    return TrainerConfig(
        method_name="neus",
        pipeline=PipelineConfig(
            datamanager=DataManagerConfig(rays_per_batch=512, foreground_fraction=0.5),
            # the crossings prior (shrinks outlines, fills dents) on 64 lines a step, and a floor under inv_s
            # rising to 800
            model=NeuSModelConfig(field=HashSDFFieldConfig(), n_samples=32, n_importance=32, up_sample_steps=2,
                                  crossings_weight=0.05, crossings_rays=64, inv_s_floor=800.0),
        ),
        # inv_s has its own learning rate, so that it sharpens within the budget
        optimizers={"fields": OptimizerConfig(lr=1e-2), "variance": OptimizerConfig(lr=2e-2)},
        scheduler=SchedulerConfig(warmup_steps=100, final_fraction=0.05),
        max_steps=2000,
        # the schedules end at 2000 steps whatever the budget: a longer run continues at the final values
        schedule_steps=2000,
        # the run ends with the mean of its last 10% of steps' weights, not the last step's noisy draw
        average_fraction=0.1,
    )


def _mlp(config: TrainerConfig) -> None:
    """The positional-encoding NeuS (4 x 128 SDF MLP, 500 steps), without the crossings prior or the inv_s floor."""
    config.pipeline.model.field = SDFFieldConfig(sdf_width=128, sdf_layers=4, color_width=128, color_layers=2,
                                                 geo_feature_dim=64)
    config.pipeline.model.crossings_weight = 0.0
    config.pipeline.model.inv_s_floor = 0.0
    config.optimizers["fields"].lr = 2e-3
    config.optimizers["variance"].lr = 2e-3
    config.max_steps = config.schedule_steps = 500


def _fast(config: TrainerConfig) -> None:
    config.max_steps = config.schedule_steps = 500
    config.pipeline.datamanager.rays_per_batch = 256
    config.pipeline.model.n_samples = 24
    config.pipeline.model.n_importance = 24


def _accurate(config: TrainerConfig) -> None:
    """The paper's network (4 x 256 shared MLP) with more samples and steps."""
    config.pipeline.model.field = SDFFieldConfig(sdf_width=256, sdf_layers=4, color_width=128, color_layers=2,
                                                 geo_feature_dim=256)
    config.max_steps = config.schedule_steps = 6000
    config.pipeline.datamanager.rays_per_batch = 1024
    config.pipeline.model.n_samples = 64
    config.pipeline.model.n_importance = 64
    config.pipeline.model.up_sample_steps = 4
    config.optimizers["fields"].lr = 5e-4
    config.optimizers["variance"].lr = 5e-4
    config.pipeline.model.inv_s_floor = 0.0  # the floor is set for the hash-grid field only


neus = MethodSpecification(
    config=neus_config(),
    description="NeuS surface reconstruction (hash-grid SDF field, up-sampling, eikonal + mask losses)",
    presets={
        "fast": Preset("500 steps, fewer rays and samples: a rough mesh quickly", _fast),
        "mlp": Preset("the positional-encoding SDF network (4x128), 500 steps", _mlp),
        "accurate": Preset("the paper's 4x256 network, 128 samples per ray, 6000 steps", _accurate),
    },
)
