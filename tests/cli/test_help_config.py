"""``va-train METHOD --help-config``: every ``--set`` key of the method with its value and its docstring."""

import pytest

from va_plugin.cli.train import main
from va_plugin.config import apply_override, describe_options, field_docstrings, format_options
from va_plugin.registry import discover_methods, get_method

METHODS = sorted(discover_methods())


@pytest.mark.parametrize("method", METHODS)
def test_every_set_key_is_listed_with_its_value_and_a_description(method, capsys, no_env_methods):
    assert main([method, "--help-config"]) == 0
    text = capsys.readouterr().out
    listed = {line.split(" = ", 1)[0]: line.split(" = ", 1)[1] for line in text.splitlines()[1:]
              if " = " in line and not line.startswith(" ")}
    rows = describe_options(get_method(method).make_config())
    assert list(listed) == [key for key, _, _ in rows]
    assert {"max_steps", "seed", "optimizers.fields.lr", "pipeline.model.eval_chunk"} <= set(listed)
    assert "(no description)" not in text, "a config field without a docstring"
    fresh = get_method(method).make_config()
    for key, value in listed.items():  # each is a real --set key, and its printed value reads back
        apply_override(fresh, f"{key}={value}")
    assert format_options(fresh) == text.split("\n", 1)[1]


def test_preset_and_overrides_show_in_the_listing(capsys, no_env_methods):
    assert main(["neus", "--help-config", "--preset", "fast", "--set", "pipeline.model.eikonal_weight=0.25"]) == 0
    text = capsys.readouterr().out
    assert "pipeline.model.eikonal_weight = 0.25\n" in text
    assert f"max_steps = {get_method('neus').make_config('fast').max_steps}\n" in text


def test_docstrings_of_inherited_fields_are_found():
    from va_plugin.fields.density_field import DensityFieldConfig

    docs = field_docstrings(DensityFieldConfig)
    assert docs["n_levels"].startswith("Levels of the hash grid") and docs["hidden_width"]
