"""Every config is checked in one pass (``validate_config``), however it was built: by ``--set``, by the
Python API, or by hand before ``setup()``."""

import pytest
from conftest import tiny_config

from va_plugin.api import build_config
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


@pytest.mark.parametrize("text", ["0,0.5,1", "[0, 0.5, 1]", "(0,0.5,1)", "0 0.5 1", " [0,0.5,1] "])
def test_a_list_is_read_in_each_documented_form(text):
    config = build_config("neus", overrides=[f"pipeline.datamanager.dataparser.background={text}"])
    background = config.pipeline.datamanager.dataparser.background
    assert background == (0.0, 0.5, 1.0) and all(type(v) is float for v in background)


@pytest.mark.parametrize("overrides, message", [
    ({"pipeline.datamanager.dataparser.background": [1, 1]}, "background takes 3 values"),
    ({"pipeline.datamanager.dataparser.background": (0, 0, -0.1)}, r"background must be in \[0, 1\]"),
    (["pipeline.datamanager.dataparser.background=red"], "background takes 3 values"),
    ({"pipeline.model": 5}, r"pipeline.model is a group of options, not a value; set one of its keys, e.g. "
                            r"pipeline.model.\w+=VALUE"),
    ({"optimizers": "adam"}, "optimizers is a group of options"),
    ({"seed": 2**32}, "option seed must be an integer from 0 to 4294967295"),
])
def test_lists_groups_and_seeds_through_the_api(overrides, message):
    with pytest.raises(ConfigError, match=message):
        build_config("neus", overrides=overrides)


@pytest.mark.parametrize("change, message", [
    (lambda c: setattr(c, "seed", -5), "option seed must be an integer"),
    (lambda c: setattr(c, "seed", 1.5), "option seed must be an integer"),
    (lambda c: setattr(c.pipeline.datamanager.dataparser, "background", (1.0, 2.0, 1.0)), r"must be in \[0, 1\]"),
])
def test_values_set_by_hand_are_checked_too(change, message):
    config = build_config("neus")
    change(config)
    with pytest.raises(ConfigError, match=message):
        validate_config(config)
