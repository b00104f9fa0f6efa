"""Options renamed to the ``color`` spelling: an old ``--set`` key and an old checkpoint's config still work."""

import io
import pickle

import pytest

from va_plugin.config import RENAMED_OPTIONS, apply_override
from va_plugin.data.foreground import ColorKey
from va_plugin.engine.trainer import _Unpickler
from va_plugin.registry import get_method


def test_an_old_set_key_is_applied_to_the_new_option_with_a_note():
    config = get_method("va-neus").make_config()
    with pytest.warns(UserWarning, match="option shared_colour_weight is now shared_color_weight"):
        apply_override(config, "pipeline.model.field.shared_colour_weight=0.25")
    assert config.pipeline.model.field.shared_color_weight == 0.25


def test_an_old_checkpoint_config_loads_its_renamed_options():
    field = get_method("va-neus").make_config().pipeline.model.field
    state = dict(field.__dict__)
    state["consistent_colour_cast"] = state.pop("consistent_color_cast") * 2  # as a run of the old spelling wrote it
    old = type(field).__new__(type(field))
    old.__setstate__(state)
    assert old.consistent_color_cast == 2 * field.consistent_color_cast and "consistent_colour_cast" not in vars(old)


def test_an_old_class_name_unpickles_as_the_new_class():
    data = pickle.dumps(ColorKey(threshold=0.2), protocol=0).replace(b"ColorKey", b"ColourKey")
    loaded = _Unpickler(io.BytesIO(data)).load()
    assert isinstance(loaded, ColorKey) and loaded.threshold == 0.2


def test_every_old_name_has_a_new_one_that_exists():
    names = {f for spec in ("va-neus", "neus") for f in _option_names(get_method(spec).make_config())}
    names |= {"color_key"}  # a generator input's dataparser option
    assert set(RENAMED_OPTIONS.values()) <= names


def _option_names(config):
    from dataclasses import fields, is_dataclass

    for item in fields(config):
        yield item.name
        value = getattr(config, item.name)
        if is_dataclass(value):
            yield from _option_names(value)


def test_a_config_of_an_old_generator_parser_unpickles_as_its_rig_file_config():
    from va_plugin.data.dataparsers.rigged import RigDataParser, SyncDreamerDataParserConfig

    data = pickle.dumps(SyncDreamerDataParserConfig(elevation_deg=20.0), protocol=0)
    old = data.replace(b"va_plugin.data.dataparsers.rigged\nRigDataParser",
                       b"va_plugin.data.dataparsers.generators\nSyncDreamerDataParser")
    old = old.replace(b"va_plugin.data.dataparsers.rigged\nSyncDreamer",
                      b"va_plugin.data.dataparsers.generators\nSyncDreamer")
    assert old != data and b"rigged" not in old  # the stream names only the classes of the earlier version
    loaded = _Unpickler(io.BytesIO(old)).load()
    assert isinstance(loaded, SyncDreamerDataParserConfig) and loaded._target is RigDataParser
    assert loaded.elevation_deg == 20.0
