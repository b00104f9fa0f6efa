"""The ``va-neus`` method: NeuS with the paper's view-adaptive renderer wrapped around its field."""

from __future__ import annotations

from typing import Callable

from method_configs.neus import _accurate, _fast, neus_config
from va_plugin.adaptive.field import ViewAdaptiveFieldConfig
from va_plugin.engine.optimizers import OptimizerConfig
from va_plugin.engine.trainer import TrainerConfig
from va_plugin.registry import MethodSpecification, Preset


def wrap_field(config: TrainerConfig, method_name: str, **options) -> TrainerConfig:
    """Turn a backbone's config into its view-adaptive variant: the field goes inside a
    ViewAdaptiveField and the branches + attention get their own optimizer group, at the shared
    field's base learning rate (the paper trains both at 5e-4)."""
    config.method_name = method_name
    model = config.pipeline.model
    model.field = ViewAdaptiveFieldConfig(base=model.field, **options)
    config.optimizers["adaptive"] = OptimizerConfig(lr=config.optimizers["fields"].lr)
    return config


def on_base_field(preset: Callable[[TrainerConfig], None]) -> Callable[[TrainerConfig], None]:
    """A backbone preset applied to a view-adaptive config (it sees the wrapped field as the field)."""

    def apply(config: TrainerConfig) -> None:
        wrapper = config.pipeline.model.field
        config.pipeline.model.field = wrapper.base
        try:
            preset(config)
        finally:
            config.pipeline.model.field = wrapper

    return apply


def va_neus_config() -> TrainerConfig:
    return wrap_field(neus_config(), "va-neus")


va_neus = MethodSpecification(
    config=va_neus_config(),
    description="view-adaptive NeuS: per-view branches + self-attention fusion, three training phases",
    presets={
        "fast": Preset("the neus fast preset, wrapped", on_base_field(_fast)),
        "accurate": Preset("the neus accurate preset (the paper's network), wrapped", on_base_field(_accurate)),
    },
)
