import textwrap

import pytest

from va_plugin.errors import ConfigError
from va_plugin.registry import MethodSpecification, discover_methods, get_method


def test_builtin_methods_are_discovered(no_env_methods):
    methods = discover_methods()
    assert "neus" in methods
    assert all(isinstance(m, MethodSpecification) and m.description for m in methods.values())


def test_entry_points_list_the_builtin_methods():
    from importlib import metadata

    names = {ep.name for ep in metadata.entry_points(group="va_plugin.methods")}
    assert "neus" in names, "reinstall the package (pip install -e .) so its entry points are registered"


def test_environment_variable_adds_a_method(tmp_path, monkeypatch):
    (tmp_path / "my_methods.py").write_text(textwrap.dedent("""
        from method_configs.neus import neus_config
        from va_plugin.registry import MethodSpecification
        mine = MethodSpecification(config=neus_config(), description="a third-party variant")
    """))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("VA_PLUGIN_METHODS", "my-neus=my_methods:mine")
    assert get_method("my-neus").description == "a third-party variant"


@pytest.mark.parametrize("value, message", [
    ("broken", "name=module:attribute"),
    ("x=no_such_module_here:thing", "cannot import"),
    ("x=va_plugin.registry:ENV_VAR", "not a MethodSpecification"),
])
def test_bad_environment_entries(monkeypatch, value, message):
    monkeypatch.setenv("VA_PLUGIN_METHODS", value)
    with pytest.raises(ConfigError, match=message):
        discover_methods()


def test_unknown_method_and_preset(no_env_methods):
    with pytest.raises(ConfigError, match="unknown method"):
        get_method("nope")
    with pytest.raises(ConfigError, match="unknown preset"):
        get_method("neus").make_config("turbo")


def test_presets_change_copies_only():
    spec = get_method("neus")
    fast = spec.make_config("fast")
    assert fast.max_steps < spec.config.max_steps
    assert spec.make_config().max_steps == spec.config.max_steps


def test_the_builtin_methods_are_listed_once_and_registered_as_entry_points(no_env_methods):
    from importlib import metadata

    from method_configs import BUILTIN_METHODS

    registered = {ep.name: ep.value for ep in metadata.entry_points(group="va_plugin.methods")}
    assert all(registered.get(name) == reference for name, reference in BUILTIN_METHODS.items()), \
        "reinstall the package (pip install -e .): setup.py registers method_configs.BUILTIN_METHODS"
    assert set(BUILTIN_METHODS) <= set(discover_methods())


def test_every_default_and_preset_ends_its_schedules_at_its_own_budget(no_env_methods):
    """A method's default and each preset set ``schedule_steps`` to their own ``max_steps`` (or leave it 0,
    the budget itself): a preset that lengthened the budget but kept the default's horizon (``accurate``)
    would spend its extra steps at the final learning rate instead of spreading its schedules over them
    (a shorter one is safe either way, the horizon being ``min(max_steps, schedule_steps)``)."""
    for name, spec in discover_methods().items():
        for preset in [None, *spec.presets]:
            config = spec.make_config(preset)
            assert config.schedule_steps in (0, config.max_steps), (name, preset, config.schedule_steps,
                                                                    config.max_steps)
