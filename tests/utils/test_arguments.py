"""API arguments of the wrong kind are one line (a VAError naming the argument) before any work: no
TypeError from deep inside, no data read, nothing written."""

import numpy as np
import pytest

import va_plugin.api as api
from va_plugin.errors import ConfigError
from va_plugin.utils.arguments import check_kind


def test_check_kind_takes_none_only_when_optional_and_no_bool_for_an_int():
    check_kind("steps", 3, int)
    check_kind("steps", None, int, optional=True)
    for value in (True, None, "3", 3.0):
        with pytest.raises(ConfigError, match="steps must be an int"):
            check_kind("steps", value, int)


@pytest.mark.parametrize("call, message", [
    (lambda scene, out: api.reconstruct(5, out=out), "input must be a path"),
    (lambda scene, out: api.reconstruct(None, out=out), "input must be a path"),
    (lambda scene, out: api.reconstruct([str(scene)], out=out), "input must be a path"),
    (lambda scene, out: api.reconstruct(np.zeros(3), out=out), r"input must be a path \(a str or .*\), got ndarray"),
    (lambda scene, out: api.reconstruct(scene, out=123), "out must be a path"),
    (lambda scene, out: api.reconstruct(scene, out=out, method=["neus"]), "method must be a str"),
    (lambda scene, out: api.reconstruct(scene, out=out, quality=["fast"]), "quality must be a str"),
    (lambda scene, out: api.reconstruct(scene, out=out, seed="5"), "seed must be an int"),
    (lambda scene, out: api.reconstruct(scene, out=out, mesh_resolution="64"), "mesh_resolution must be an int"),
    (lambda scene, out: api.reconstruct(scene, out=out, evaluate_options=[1]), "evaluate_options must be a dict"),
    (lambda scene, out: api.reconstruct(scene, out=out, progress=5), "progress must be a function"),
    (lambda scene, out: api.reconstruct(scene, out=out, stop=5), "stop must be a threading.Event"),
    (lambda scene, out: api.reconstruct(scene, out=out, on_message=5), "on_message must be a function"),
    (lambda scene, out: api.reconstruct(scene, out=out, device=""), "--device is empty"),
    (lambda scene, out: api.build_config("neus", scene, out=out, overrides=5), "overrides must be"),
    (lambda scene, out: api.train(5), "config must be a TrainerConfig"),
    (lambda scene, out: api.train(api.build_config("neus", scene, out=out), progress=5), "progress must be"),
    (lambda scene, out: api.train(api.build_config("neus", scene, out=out), stop=5), "stop must be"),
    (lambda scene, out: api.export_mesh(None), "run must be a path"),
    (lambda scene, out: api.export_mesh(out, output=5), "output must be"),
    (lambda scene, out: api.evaluate(5), "run must be a path"),
    (lambda scene, out: api.load_run(["x"]), "run must be a path"),
    (lambda scene, out: api.render(out, 5), "out_dir must be a path"),
])
def test_a_wrong_kind_is_one_line_before_any_work(call, message, tiny_scene, tmp_path):
    out = tmp_path / "out"
    with pytest.raises(ConfigError, match=message) as raised:
        call(tiny_scene, out)
    assert "\n" not in str(raised.value)
    assert not out.exists()  # refused before the folder was made or the data read

