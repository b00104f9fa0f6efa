"""ExportConfig: the one source of the export defaults, and its one-line refusals."""

import pytest

from va_plugin.errors import ConfigError, VAError
from va_plugin.export.config import ExportConfig


def test_keywords_that_are_given_override_the_config_and_none_keeps_it():
    base = ExportConfig(texture_size=256, frame="training")
    export = ExportConfig.of(base, texture_size=None, mesh_resolution=64, faces=None)
    assert (export.texture_size, export.mesh_resolution, export.frame, export.faces) == (256, 64, "training", None)
    assert ExportConfig.of() == ExportConfig()


@pytest.mark.parametrize(("options", "message"), [
    ({"fusion": "median"}, "--fusion must be one of robust, mean"),
    ({"texture": False, "faces": 1000}, "--faces sets the face count of the textured mesh"),
    ({"texture_size": 1000}, "--texture-size must be a power of two"),
    ({"mesh_resolution": 4}, "--mesh-resolution must be at least 8, got 4"),
    ({"frame": "sideways"}, "--frame must be one of upright, training"),
    ({"mesh_resolution": "64"}, "mesh_resolution must be an int"),
])
def test_an_option_that_cannot_work_is_one_line(options, message):
    with pytest.raises(VAError, match=message):
        ExportConfig.of(**options).validate()


def test_a_texture_size_is_not_checked_without_a_texture_and_unknown_options_are_refused():
    ExportConfig(texture=False, texture_size=1000).validate()
    with pytest.raises(ConfigError, match="unknown export option 'resolution'"):
        ExportConfig.of(resolution=64)
    with pytest.raises(ConfigError, match="export must be an ExportConfig"):
        ExportConfig.of({"texture_size": 64})
