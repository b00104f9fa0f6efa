"""Every config is checked in one pass (``validate_config``), however it was built: by ``--set``, by the
Python API, or by hand before ``setup()``."""

import pytest
from conftest import tiny_config

from va_plugin.config import validate_config
from va_plugin.errors import ConfigError
from va_plugin.registry import discover_methods


def test_every_method_and_preset_passes_its_own_checks():
    for spec in discover_methods().values():
        for preset in (None, *spec.presets):
            validate_config(spec.make_config(preset))


@pytest.mark.parametrize("change, message", [
    (lambda c: setattr(c.pipeline.model, "n_samples", 0), "option pipeline.model.n_samples must be positive"),
    (lambda c: setattr(c.pipeline.model, "eikonal_weight", -1.0), "pipeline.model.eikonal_weight must be >= 0"),
    (lambda c: setattr(c.optimizers["fields"], "lr", -1e-3), "optimizers.fields.lr must be >= 0"),
    (lambda c: setattr(c.scheduler, "final_fraction", 2.0), r"scheduler.final_fraction must be in \[0, 1\]"),
    (lambda c: setattr(c, "max_steps", 0), "option max_steps must be positive"),
    (lambda c: setattr(c.optimizers["fields"], "eps", 0.0), "optimizers.fields.eps must be a finite number > 0"),
])
def test_a_config_changed_by_hand_is_refused_at_setup(tiny_scene, tmp_path, change, message):
    config = tiny_config("neus", tiny_scene, tmp_path)
    change(config)
    with pytest.raises(ConfigError, match=message):
        config.setup()
    assert not (tmp_path / "checkpoints").exists()


def test_a_view_adaptive_cross_field_rule_is_checked_by_key(tiny_scene, tmp_path):
    config = tiny_config("va-neus", tiny_scene, tmp_path)
    config.pipeline.model.field.attention_heads = 3  # attention_dim 64 is no multiple of 3
    with pytest.raises(ConfigError, match="multiple of attention_heads"):
        validate_config(config)
