"""Turning a backbone's method into its view-adaptive variant (shared by ``va-neus`` and ``va-ngp``)."""

from __future__ import annotations

from collections.abc import Callable

from va_plugin.adaptive.field import ViewAdaptiveFieldConfig
from va_plugin.engine.optimizers import OptimizerConfig
from va_plugin.engine.trainer import TrainerConfig
from va_plugin.registry import MethodSpecification, Preset


def wrap_field(config: TrainerConfig, method_name: str, adaptive_lr: float | None = None,
               **options) -> TrainerConfig:
    """The backbone's field goes inside a ViewAdaptiveField; the branches + attention get their own
    optimizer group ("adaptive"), by default at the shared field's base learning rate (the paper
    trains both at 5e-4)."""
    config.method_name = method_name
    model = config.pipeline.model
    model.field = ViewAdaptiveFieldConfig(base=model.field, **options)
    lr = config.optimizers["fields"].lr if adaptive_lr is None else adaptive_lr
    config.optimizers["adaptive"] = OptimizerConfig(lr=lr)
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


def adaptive_method(backbone: MethodSpecification, method_name: str, description: str,
                    **options) -> MethodSpecification:
    """The view-adaptive variant of a registered backbone, with the backbone's presets wrapped."""
    presets: dict[str, Preset] = {
        name: Preset(f"{preset.description} (the {backbone.config.method_name} preset, wrapped)",
                     on_base_field(preset.apply))
        for name, preset in backbone.presets.items()
    }
    return MethodSpecification(config=wrap_field(backbone.make_config(), method_name, **options),
                               description=description, presets=presets)
