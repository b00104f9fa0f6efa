"""One path resolution for every path a user gives: ``~`` expanded, then resolved; what cannot be a path
is one line."""

import os
from pathlib import Path

import pytest

from va_plugin.errors import ConfigError
from va_plugin.utils.paths import user_path, within


def test_a_tilde_is_the_home_folder_and_the_result_is_absolute(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.chdir(tmp_path)
    assert user_path("~/userx", "--out") == tmp_path / "home" / "userx"
    assert user_path(Path("a/../b"), "--out") == tmp_path / "b"
    assert within("mesh.glb", tmp_path / "run", "output") == tmp_path / "run" / "mesh.glb"
    assert within("~/m.glb", tmp_path / "run", "output") == tmp_path / "home" / "m.glb"
    assert not (tmp_path / "~").exists()


def test_symbolic_links_are_followed_and_a_loop_is_one_line(tmp_path):
    (tmp_path / "real").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "real")
    assert user_path(tmp_path / "link" / "run", "--out") == tmp_path / "real" / "run"
    os.symlink(tmp_path / "b", tmp_path / "a")
    os.symlink(tmp_path / "a", tmp_path / "b")
    with pytest.raises(ConfigError, match=r"--out .* loop of symbolic links"):
        user_path(tmp_path / "a", "--out")


@pytest.mark.parametrize("value, message", [
    (5, "got int"), (None, "got None"), (["x"], "got list"), (b"x", "got bytes"), ("", "is empty"),
    ("  ", "is empty"), ("a\0b", "NUL"), ("~no-such-user-85/x", "names no user"),
])
def test_what_is_no_path_is_one_line(value, message):
    with pytest.raises(ConfigError, match=message) as raised:
        user_path(value, "out")
    assert str(raised.value).startswith("out") and "\n" not in str(raised.value)
