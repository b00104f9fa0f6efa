"""Fused CPU kernels of the hash encoding (``hash_kernel.cpp``), built on first use.

The PyTorch path of :mod:`hash_grid` runs a few dozen tensor operations per lookup; these kernels do a
lookup, its pull-back to the points and their gradients in one pass each, with the work split across
CPU threads. They serve float32 points on CPU that need no gradient themselves (a training step's
samples, probes, rendering and mesh extraction); everything else (other dtypes, GPUs, gradients w.r.t.
the points, double backward) takes the PyTorch path, which is also the reference the tests hold these
kernels to.

The extension is compiled once per machine with ``torch.utils.cpp_extension`` (a C++ compiler and
ninja are needed; about a minute) and cached in torch's extension folder. If it cannot be built, a
warning says why and the PyTorch path is used. ``VA_PLUGIN_HASH_KERNEL=0`` turns the kernels off.
The build is named by a digest of the source and the flags, and compiles a copy of the source kept
beside it: checkouts of the package at different paths share one build, and a changed source gets a
build of its own instead of rebuilding another checkout's.

Builds are serialised by an advisory lock (``va_hash_grid.build-lock`` in the extension folder, held with
``flock``, which the system releases when its holder dies). torch's own ``lock`` file in the build folder
outlives a killed build and makes every later build wait for it forever; whoever holds the advisory lock
knows no live build owns such a file, removes it and says so. A build that waits longer than
``VA_PLUGIN_HASH_KERNEL_WAIT`` seconds (default 600) for another process gives up with a warning and the
PyTorch path is used.
"""

from __future__ import annotations

import hashlib
import os
import sys
import threading
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import torch
from torch.autograd.function import once_differentiable

from va_plugin.utils.files import replace_atomic

try:
    import fcntl
except ImportError:  # not POSIX: builds take no advisory lock
    fcntl = None

SOURCE = Path(__file__).with_name("hash_kernel.cpp")
NAME = "va_hash_grid"
# Built for the machine it runs on (vector instructions across points); no fused multiply-adds, so the
# encoding keeps the PyTorch path's rounding; OpenMP for the threads torch uses.
CFLAGS = ("-O3", "-march=native", "-ffp-contract=off", "-fopenmp")
ENV_SWITCH = "VA_PLUGIN_HASH_KERNEL"
ENV_WAIT = "VA_PLUGIN_HASH_KERNEL_WAIT"
DEFAULT_WAIT_SECONDS = 600.0
BUILD_LOCK = f"{NAME}.build-lock"

_lock = threading.Lock()
_state: dict = {}


def kernels_enabled() -> bool:
    """Whether the environment allows the kernels (``VA_PLUGIN_HASH_KERNEL`` unset, or not 0/false/no/off)."""
    return os.environ.get(ENV_SWITCH, "1").strip().lower() not in ("0", "false", "no", "off")


def load_kernels(verbose: bool = False):
    """The compiled operators (``torch.ops.va_hash_grid``), building them on the first call; ``None``
    when they are switched off or cannot be built (a warning says why, once)."""
    if not kernels_enabled():
        return None
    with _lock:
        if "ops" not in _state:
            _state["ops"] = _build(verbose)
    return _state["ops"]


def _build(verbose: bool):
    try:
        from torch.utils import cpp_extension

        root = extensions_root(cpp_extension.get_default_build_root())
        with build_lock(root, wait_seconds()) as holder:
            if holder is None:
                warnings.warn(f"the fused CPU hash-grid kernels were not built: another process has held "
                              f"{root / BUILD_LOCK} for {wait_seconds():g} s; using the slower PyTorch path "
                              f"(set {ENV_WAIT} to wait longer)", RuntimeWarning, stacklevel=3)
                return None
            remove_stale_locks(root)
            name, source = staged_source(root)
            if not _built_before(root, name):
                print("compiling the hash grid's CPU kernels (once per machine, about a minute)", file=sys.stderr,
                      flush=True)
            cpp_extension.load(name=name, sources=[str(source)], extra_cflags=list(CFLAGS),
                               extra_ldflags=["-fopenmp"], is_python_module=False, verbose=verbose)
        return torch.ops.va_hash_grid
    except Exception as error:  # a missing compiler or ninja, a read-only cache folder, ...
        first_line = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        warnings.warn(f"the fused CPU hash-grid kernels could not be built ({first_line}); using the slower "
                      f"PyTorch path. Set {ENV_SWITCH}=0 to skip the attempt.", RuntimeWarning, stacklevel=3)
        return None


def flush_denormals(on: bool = True) -> bool:
    """Treat float values below 1.2e-38 (denormals) as zero in every CPU operation of this process, in the
    calling thread and in each thread of torch's pool (``on=False``: back to IEEE behaviour). Arithmetic on
    denormals takes the processor's slow path: a softplus far from the surface, where exp(beta z)
    underflows, runs several times slower without this. Process-wide until switched off: use
    :func:`denormals_flushed` around the work instead. Without the kernels only the calling thread is
    switched (``torch.set_flush_denormal``). Returns whether the processor supports it."""
    ops = load_kernels()
    if ops is not None:
        return bool(ops.flush_denormals(on))
    return bool(torch.set_flush_denormal(on))


_flush_lock = threading.Lock()
_flush_depth = 0  # how many denormals_flushed blocks are open


@contextmanager
def denormals_flushed(enabled: bool = True) -> Iterator[None]:
    """Within the block, :func:`flush_denormals` is on; after the outermost such block, off again (IEEE
    behaviour), so that code outside runs as it expects (scipy's KD-tree crashes on some inputs with
    denormals flushed). Blocks nest: an inner one leaves the flushing on for the rest of the outer one.
    ``enabled=False``: nothing changes (GPU work)."""
    global _flush_depth
    if not enabled:
        yield
        return
    with _flush_lock:
        if _flush_depth == 0:
            flush_denormals(True)
        _flush_depth += 1
    try:
        yield
    finally:
        with _flush_lock:
            _flush_depth -= 1
            if _flush_depth == 0:
                flush_denormals(False)


def wait_seconds() -> float:
    """How long a build waits for another process's build (``VA_PLUGIN_HASH_KERNEL_WAIT``, default 600 s)."""
    try:
        return max(0.0, float(os.environ.get(ENV_WAIT, DEFAULT_WAIT_SECONDS)))
    except ValueError:
        return DEFAULT_WAIT_SECONDS


def extensions_root(default_root: str) -> Path:
    """torch's extension folder: ``TORCH_EXTENSIONS_DIR``, else its default (``~/.cache/torch_extensions``)."""
    return Path(os.environ.get("TORCH_EXTENSIONS_DIR") or default_root)


@contextmanager
def build_lock(root: Path, timeout: float) -> Iterator[int | None]:
    """Hold the advisory build lock of ``root`` (waiting at most ``timeout`` seconds for another holder):
    yields this process's id, or None when the lock stayed taken. Without ``fcntl`` (not POSIX) there is
    no lock to take and the build goes ahead."""
    if fcntl is None:
        yield os.getpid()
        return
    root.mkdir(parents=True, exist_ok=True)
    fd = os.open(root / BUILD_LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        deadline, said = time.monotonic() + timeout, False
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    yield None
                    return
                if not said:
                    print(f"waiting (up to {timeout:g} s) for another process that builds the hash grid's CPU "
                          f"kernels ({root / BUILD_LOCK})", file=sys.stderr, flush=True)
                    said = True
                time.sleep(0.2)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())  # who builds, for a curious reader
        try:
            yield os.getpid()
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def build_name(text: bytes) -> str:
    """The extension's name for kernel source ``text``: :data:`NAME` and a digest of the source and the flags."""
    digest = hashlib.sha256(text + "\0".join(CFLAGS).encode()).hexdigest()[:12]
    return f"{NAME}_{digest}"


def staged_source(root: Path) -> tuple[str, Path]:
    """The extension's name (:func:`build_name`) and the copy of :data:`SOURCE` it is compiled from,
    ``root/<name>-source/hash_kernel.cpp``: a path that depends on the source and not on where the package
    lies. Written (atomically) only when missing or different, so an existing build stays up to date."""
    text = SOURCE.read_bytes()
    name = build_name(text)
    staged = root / f"{name}-source" / SOURCE.name
    try:
        current = staged.read_bytes()
    except OSError:
        current = None
    if current != text:
        replace_atomic(staged, lambda handle: handle.write(text))
    return name, staged


def remove_stale_locks(root: Path) -> list[Path]:
    """Remove torch's ``lock`` files of this extension's build folders under ``root`` (call with the build
    lock held: no live build owns them, they are left by a build that was killed), each with a note."""
    removed = []
    for lock in sorted({*root.glob(f"{NAME}*/lock"), *root.glob(f"*/{NAME}*/lock")}):
        try:
            lock.unlink()
        except FileNotFoundError:
            continue
        print(f"removed {lock}, left by an interrupted build of the hash grid's CPU kernels", file=sys.stderr,
              flush=True)
        removed.append(lock)
    return removed


# The kernels index a level's table with 32-bit integers.
MAX_HASHMAP_SIZE = 2**31


def _built_before(root: Path, name: str) -> bool:
    """Whether torch's extension folder holds a build of ``name`` (a heuristic for the message)."""
    return any(root.glob(f"{name}/{name}*.so")) or any(root.glob(f"*/{name}/{name}*.so"))


def usable(x01: torch.Tensor, table: torch.Tensor, hashmap_size: int) -> bool:
    """Whether a lookup of points ``x01`` in ``table`` (levels of at most ``hashmap_size`` entries) can run
    on the kernels: float32 on CPU, no gradient w.r.t. the points, and the kernels built."""
    return (x01.device.type == "cpu" and table.device.type == "cpu" and x01.dtype == torch.float32
            and table.dtype == torch.float32 and not x01.requires_grad and hashmap_size <= MAX_HASHMAP_SIZE
            and load_kernels() is not None)


def _level_args(levels) -> tuple:
    return (levels.resolutions, levels.multipliers.contiguous(), levels.offsets, int(levels.n_dense),
            int(levels.hashmap_size))


class _Pending:
    """Pull-back gradients ``(g, gd)`` waiting for their encoding's backward, which folds them into the
    same scatter into the table (one pass over the table instead of one per function)."""

    def __init__(self) -> None:
        self.pulls: list[tuple[torch.Tensor, torch.Tensor]] = []


class _Encode(torch.autograd.Function):
    """The encoding ``[n, L * F]`` of points ``x01 [n, 3]``; the table's gradient from a single scatter
    that also takes the pending pull-back gradients."""

    @staticmethod
    def forward(ctx, x01, table, levels, pending):
        ctx.levels, ctx.pending = levels, pending
        ctx.save_for_backward(x01, table)
        return load_kernels().encode(x01.contiguous(), table, *_level_args(levels))

    @staticmethod
    @once_differentiable
    def backward(ctx, grad):
        x01, table = ctx.saved_tensors
        pulls = ctx.pending.pulls if ctx.pending is not None else []
        if not ctx.needs_input_grad[1]:
            pulls.clear()
            return None, None, None, None
        ops, args = load_kernels(), _level_args(ctx.levels)
        g, gd = pulls.pop() if pulls else (None, None)
        grad_table = ops.table_grad(x01, table, grad.contiguous(), g, gd, *args)
        while pulls:
            g, gd = pulls.pop()
            grad_table += ops.table_grad(x01, table, None, g, gd, *args)
        return None, grad_table, None, None


class _Pullback(torch.autograd.Function):
    """``d/d x01`` ``[n, 3]`` of the derivative ``g [n, L * F]`` w.r.t. an encoding; differentiable in ``g``
    and (through the encoding's backward, which takes ``encoded`` as a dependency) in the table."""

    @staticmethod
    def forward(ctx, x01, table, g, encoded, levels, pending):
        ctx.levels, ctx.pending = levels, pending
        ctx.save_for_backward(x01, table, g)
        ctx.encoded_shape = encoded.shape
        return load_kernels().pullback(x01, table, g.contiguous(), *_level_args(levels))

    @staticmethod
    @once_differentiable
    def backward(ctx, gd):
        x01, table, g = ctx.saved_tensors
        gd = gd.contiguous()
        grad_g = None
        if ctx.needs_input_grad[2]:
            grad_g = load_kernels().pullback_grad_g(x01, table, gd, *_level_args(ctx.levels))
        grad_encoded = None
        if ctx.needs_input_grad[1]:
            ctx.pending.pulls.append((g.contiguous(), gd))
            # A zero gradient for the encoding makes sure its backward, which does the scatter, runs.
            grad_encoded = gd.new_zeros(ctx.encoded_shape)
        return None, None, grad_g, grad_encoded, None, None


def encode(x01: torch.Tensor, table: torch.Tensor, levels) -> torch.Tensor:
    """The encoding ``[n, L * F]``, differentiable in ``table``."""
    return _Encode.apply(x01, table, levels, None)


def encode_with_pullback(x01: torch.Tensor, table: torch.Tensor, levels):
    """As :func:`hash_grid.encode_with_pullback`, on the kernels."""
    pending = _Pending()
    encoded = _Encode.apply(x01, table, levels, pending)

    def pullback(grad_encoded: torch.Tensor) -> torch.Tensor:
        return _Pullback.apply(x01, table, grad_encoded, encoded, levels, pending)

    return encoded, pullback
