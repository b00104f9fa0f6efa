"""Up-front memory checks: an impossible request is one line naming the largest value that fits."""

import subprocess
import sys

import numpy as np
import pytest
from conftest import tiny_trained_run

from va_plugin.cli import eval as eval_cli
from va_plugin.cli import export as export_cli
from va_plugin.errors import ConfigError
from va_plugin.utils import memory
from va_plugin.utils.memory import small_numpy_pages

GIB = 2**30


@pytest.fixture
def eight_gib(monkeypatch):
    monkeypatch.setattr(memory, "available_bytes", lambda: 10 * GIB)  # 8 GiB usable


def test_available_memory_is_positive():
    assert memory.available_bytes() > 0


def test_largest_mesh_resolution_named_fits_and_one_more_does_not(eight_gib):
    with pytest.raises(ConfigError, match="--resolution 100000 needs about") as info:
        memory.check_mesh_resolution(100000)
    largest = int(str(info.value).rsplit(" ", 1)[1])
    memory.check_mesh_resolution(largest)
    with pytest.raises(ConfigError):
        memory.check_mesh_resolution(largest + 1)
    assert 300 < largest < 500  # 8 GiB / 128 B per voxel: 406^3


def test_largest_render_scale_named_fits(eight_gib):
    with pytest.raises(ConfigError, match=r"--scale 100 \(25600x25600 pixels per view\)") as info:
        memory.check_render_size(256, 256, 100)
    largest = float(str(info.value).rsplit(" ", 1)[1])
    memory.check_render_size(256, 256, largest)
    with pytest.raises(ConfigError):
        memory.check_render_size(256, 256, largest + 0.02)


def test_largest_texture_named_is_a_power_of_two_that_fits(eight_gib):
    with pytest.raises(ConfigError, match="--texture-size 8192 with 16 views") as info:
        memory.check_texture_memory(8192, 16)
    largest = int(str(info.value).rsplit(" ", 1)[1])
    assert largest & (largest - 1) == 0
    memory.check_texture_memory(largest, 16)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return tiny_trained_run(tmp_path_factory, resolution=24, steps=1)


@pytest.mark.parametrize("main, argv, message", [
    (export_cli.main, ["mesh", "--resolution", "100000"], "the largest that fits is --resolution "),
    (export_cli.main, ["render", "--scale", "10000"], "the largest that fits is --scale "),
    (export_cli.main, ["render", "--turntable-resolution", "10000000"], "largest that fits is --turntable-resolution"),
    (export_cli.main, ["diagnostics", "--scale", "10000"], "the largest that fits is --scale "),
    (eval_cli.main, ["--mesh-resolution", "100000"], "the largest that fits is --mesh-resolution "),
    (eval_cli.main, ["--image-scale", "10000"], "the largest that fits is --image-scale "),
])
def test_commands_refuse_requests_that_cannot_fit(run, main, argv, message, capsys):
    before = sorted(p.name for p in run.rglob("*"))
    argv = (argv[:1] + ["--load-dir", str(run)] + argv[1:] if main is export_cli.main
            else ["--load-dir", str(run), *argv])
    code = main(argv + ["--device", "cpu"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: ") and message in err[0], err
    assert sorted(p.name for p in run.rglob("*")) == before  # nothing written


_FAULTS_SCRIPT = """
import resource, sys, torch
from va_plugin.utils.memory import keep_freed_memory
applied = keep_freed_memory() if sys.argv[1] == "keep" else None
for _ in range(3):
    torch.empty(10 << 20).fill_(1.0)  # 40 MB, freed at once
faults = []
for _ in range(20):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    torch.empty(10 << 20).fill_(1.0)
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(applied, *faults)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a glibc malloc setting")
def test_keep_freed_memory_stops_page_faults_for_repeated_temporaries():
    """A 40 MB tensor allocated and freed 20 times: fresh pages from the system each time by default
    (above glibc's largest automatic mmap threshold, 32 MB), mostly reused once freed memory is kept (one
    process each: the setting is process-wide)."""
    counts = {}
    for mode in ("default", "keep"):
        out = subprocess.run([sys.executable, "-c", _FAULTS_SCRIPT, mode], capture_output=True, text=True,
                             check=True).stdout.split()
        counts[mode] = (out[0], sorted(int(n) for n in out[1:]))
    if counts["keep"][0] != "True":
        pytest.skip("this C library has no mallopt (not glibc)")
    # by default every allocation faults all its pages in (10,240 with 4 kB pages, fewer with transparent
    # huge pages); kept, most allocations fault nothing (now and then one still grows the heap, or the
    # system takes pages back), so the median allocation is compared
    default, keep = (counts[mode][1][10] for mode in ("default", "keep"))
    assert default >= 20 and keep * 4 < default, counts


def _hugepage_advice(toggle) -> bool:
    """numpy's current setting (the toggle answers with the one it replaces)."""
    current = toggle(True)
    toggle(current)
    return current


def test_small_numpy_pages_turns_numpy_hugepage_advice_off_and_back(monkeypatch):
    toggle = getattr(np._core.multiarray, "_set_madvise_hugepage", None)
    if toggle is None:
        pytest.skip("this numpy has no hugepage setting")
    monkeypatch.delenv("NUMPY_MADVISE_HUGEPAGE", raising=False)
    before = toggle(True)
    try:
        with small_numpy_pages():
            assert _hugepage_advice(toggle) is False
            assert float(np.ones(2 << 20, np.float32).sum()) == 2 << 20  # large arrays still work
        assert _hugepage_advice(toggle) is True
        with pytest.raises(RuntimeError), small_numpy_pages():
            raise RuntimeError("inside")
        assert _hugepage_advice(toggle) is True  # restored after an error too

        @small_numpy_pages()
        def inside() -> bool:
            return _hugepage_advice(toggle)

        assert inside() is False and _hugepage_advice(toggle) is True
        monkeypatch.setenv("NUMPY_MADVISE_HUGEPAGE", "1")  # the user's own choice is left alone
        with small_numpy_pages():
            assert _hugepage_advice(toggle) is True
    finally:
        toggle(before)
