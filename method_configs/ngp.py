"""The ``ngp`` method: an InstantNGP-style hash-grid density field with an occupancy grid, sized for 2 CPU cores."""

from __future__ import annotations

from va_plugin.data.datamanager import DataManagerConfig
from va_plugin.engine.optimizers import OptimizerConfig, SchedulerConfig
from va_plugin.engine.trainer import TrainerConfig
from va_plugin.fields.density_field import DensityFieldConfig
from va_plugin.models.ngp import NGPModelConfig
from va_plugin.pipelines.base import PipelineConfig
from va_plugin.registry import MethodSpecification, Preset


def ngp_config() -> TrainerConfig:
    """The default NGP run on a 4-view object (view-independent color, coarse-to-fine levels)."""
    return TrainerConfig(
        method_name="ngp",
        pipeline=PipelineConfig(
            datamanager=DataManagerConfig(rays_per_batch=512, foreground_fraction=0.5),
            # view-independent color and levels opening coarse to fine (few views overfit otherwise)
            model=NGPModelConfig(field=DensityFieldConfig(direction_frequencies=-1, coarse_to_fine_fraction=0.3),
                                 n_samples=96),
        ),
        optimizers={"fields": OptimizerConfig(lr=1e-2)},
        scheduler=SchedulerConfig(warmup_steps=50, final_fraction=0.05),
        max_steps=1000,
        # the schedules end at 1000 steps whatever the budget: a longer run continues at the final values
        schedule_steps=1000,
    )


def _fast(config: TrainerConfig) -> None:
    config.max_steps = config.schedule_steps = 300
    config.pipeline.datamanager.rays_per_batch = 256


def _accurate(config: TrainerConfig) -> None:
    """InstantNGP's full-size grid (16 levels up to 2048, 2^19 entries), more rays, samples and steps."""
    config.max_steps = config.schedule_steps = 4000
    config.pipeline.datamanager.rays_per_batch = 1024
    config.pipeline.model.n_samples = 192
    field = config.pipeline.model.field
    field.n_levels, field.log2_hashmap_size, field.max_resolution = 16, 19, 2048


ngp = MethodSpecification(
    config=ngp_config(),
    description="InstantNGP-style density field (hash grid, occupancy grid, early ray termination, mask loss)",
    presets={
        "fast": Preset("fewer rays and steps: a rough mesh quickly", _fast),
        "accurate": Preset("InstantNGP's full-size hash grid, 192 samples per ray, 4000 steps", _accurate),
    },
)
