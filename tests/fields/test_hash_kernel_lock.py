"""The kernel build never hangs on a lock: torch's ``lock`` file left by a killed build is removed with a
note, and a build that another live process holds too long gives up to the PyTorch path with one warning.
torch's compiler is replaced by a stand-in that fails where torch would wait forever (no real build)."""

import os
import signal
import subprocess
import sys
import time

import pytest
from torch.utils import cpp_extension

from va_plugin.fields.encodings import hash_kernel

fcntl = pytest.importorskip("fcntl")


@pytest.fixture
def extensions(tmp_path, monkeypatch):
    """A fresh extension folder, and a stand-in for ``cpp_extension.load`` that records its calls."""
    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path))
    calls = []

    def load(name, **kwargs):
        # torch's FileBaton sleeps while a build folder's lock exists: a stale one would be a hang
        locks = [p for p in tmp_path.rglob("lock") if p.parent.name.startswith(hash_kernel.NAME)]
        assert not locks, f"torch would wait forever on {locks}"
        calls.append(name)

    monkeypatch.setattr(cpp_extension, "load", load)
    return tmp_path, calls


def stale_locks(root):
    """torch's lock files in both layouts of the extension folder (``TORCH_EXTENSIONS_DIR`` and the default's
    per-Python subfolder), as a killed build leaves them."""
    locks = [root / hash_kernel.NAME / "lock", root / "py311_cpu" / hash_kernel.NAME / "lock"]
    for lock in locks:
        lock.parent.mkdir(parents=True)
        lock.touch()
    return locks


def test_a_lock_left_by_a_killed_build_is_removed_with_a_note(extensions, capsys):
    root, calls = extensions
    locks = stale_locks(root)
    # the builder that left them was killed while holding the build lock: the system released it
    holder = subprocess.Popen([sys.executable, "-c", (
        "import fcntl, os, sys, time\n"
        f"fd = os.open({str(root / hash_kernel.BUILD_LOCK)!r}, os.O_RDWR | os.O_CREAT)\n"
        "fcntl.flock(fd, fcntl.LOCK_EX)\n"
        "print('held', flush=True)\n"
        "time.sleep(60)\n")], stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "held"
    os.kill(holder.pid, signal.SIGKILL)
    holder.wait(10)
    holder.stdout.close()
    assert hash_kernel._build(verbose=False) is not None
    assert calls == [hash_kernel.build_name(hash_kernel.SOURCE.read_bytes())]
    assert not any(lock.exists() for lock in locks)
    err = capsys.readouterr().err
    for lock in locks:
        assert f"removed {lock}, left by an interrupted build of the hash grid's CPU kernels" in err
    assert (root / hash_kernel.BUILD_LOCK).read_text().strip() == str(os.getpid())


def test_a_build_another_process_holds_too_long_falls_back(extensions, monkeypatch, capsys):
    root, calls = extensions
    monkeypatch.setenv(hash_kernel.ENV_WAIT, "0.4")
    live = root / hash_kernel.build_name(hash_kernel.SOURCE.read_bytes()) / "lock"  # the live builder's: not ours
    live.parent.mkdir()
    live.touch()
    fd = os.open(root / hash_kernel.BUILD_LOCK, os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)  # another open file: flock excludes it as it would another process
    try:
        started = time.monotonic()
        with pytest.warns(RuntimeWarning, match=r"another process has held .*va_hash_grid.build-lock for 0.4 s; "
                                                r"using the slower PyTorch path \(set VA_PLUGIN_HASH_KERNEL_WAIT"):
            assert hash_kernel._build(verbose=False) is None
        assert 0.4 <= time.monotonic() - started < 5
    finally:
        os.close(fd)
    assert calls == [] and live.exists()
    assert capsys.readouterr().err.splitlines() == [
        f"waiting (up to 0.4 s) for another process that builds the hash grid's CPU kernels "
        f"({root / hash_kernel.BUILD_LOCK})"]


def test_the_wait_comes_from_the_environment(monkeypatch):
    monkeypatch.setenv(hash_kernel.ENV_WAIT, "12.5")
    assert hash_kernel.wait_seconds() == 12.5
    monkeypatch.setenv(hash_kernel.ENV_WAIT, "soon")
    assert hash_kernel.wait_seconds() == hash_kernel.DEFAULT_WAIT_SECONDS


def test_checkouts_at_different_paths_share_one_build(tmp_path, monkeypatch):
    """The build compiles a copy of the source whose path depends on the source alone: a second checkout
    (the same source elsewhere) gets the same name and path, and the copy is not rewritten (its age would
    make ninja rebuild); a changed source gets a build of its own."""
    root = tmp_path / "extensions"
    text = hash_kernel.SOURCE.read_bytes()
    names = []
    for checkout in ("a", "b"):
        source = tmp_path / checkout / "hash_kernel.cpp"
        source.parent.mkdir()
        source.write_bytes(text)
        monkeypatch.setattr(hash_kernel, "SOURCE", source)
        names.append(hash_kernel.staged_source(root))
        if checkout == "a":
            first_write = names[0][1].stat().st_mtime_ns
            time.sleep(0.01)
    assert names[0] == names[1] and names[0][1].read_bytes() == text
    assert names[0][1].stat().st_mtime_ns == first_write
    assert names[0][1].parent.parent == root and names[0][0].startswith(hash_kernel.NAME + "_")
    changed = tmp_path / "c" / "hash_kernel.cpp"
    changed.parent.mkdir()
    changed.write_bytes(text + b"// changed\n")
    monkeypatch.setattr(hash_kernel, "SOURCE", changed)
    other, staged = hash_kernel.staged_source(root)
    assert other != names[0][0] and staged.read_bytes() == changed.read_bytes()
    assert names[0][1].read_bytes() == text  # the first build's copy is left alone
