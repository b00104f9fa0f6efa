"""Up-front memory estimates for sizes the user picks (a marching-cubes grid, a render scale, a texture
size): an impossible request is refused with the largest value that fits. And :func:`keep_freed_memory`,
the allocator setting that training on CPU runs under, and :func:`small_numpy_pages`, the page setting
that the export's large arrays are made under."""

from __future__ import annotations

import contextlib
import ctypes
import math
import os
import sys

import numpy as np

from va_plugin.errors import ConfigError

GRID_BYTES_PER_VOXEL = 128
"""Peak bytes per grid point of mesh extraction (field values, masks, marching cubes' own copies)."""
RENDER_BYTES_PER_PIXEL = 512
"""Peak bytes per pixel of a render (indices, rays, outputs, the resized target, the written pair)."""
TRAIN_BYTES_PER_PIXEL = 32
"""Bytes per training pixel held while the views are loaded and resized (image, mask, the resize's copies)."""
TRAIN_BYTES_PER_SAMPLE = 4096
"""Peak bytes per ray sample of a training step, backward and eikonal included (measured: 2.1 KB for ngp,
2.7 KB for neus, 3.4 KB for the view-adaptive wrapper)."""
TRAIN_BASE_BYTES = 1 << 30
"""The training process without its batch and views (torch, the model, open3d and trimesh)."""
BAKE_BYTES_PER_TEXEL = 96
BAKE_BYTES_PER_TEXEL_VIEW = 40
"""Texture baking: bytes per texel, and per texel and view."""
USABLE_SHARE = 0.8
"""Share of the available memory a request may plan to use (the rest is for the process around it)."""
HEAP_BLOCK_LIMIT = 256 << 20
"""Blocks up to this size come from malloc's heap under :func:`keep_freed_memory` (glibc: M_MMAP_THRESHOLD)."""
HEAP_KEEP_LIMIT = 1 << 30
"""Free memory at the heap's top that malloc keeps before returning it to the system (M_TRIM_THRESHOLD)."""
_MALLOPT_TRIM_THRESHOLD, _MALLOPT_MMAP_THRESHOLD = -1, -3


def keep_freed_memory() -> bool:
    """Have glibc's malloc keep the memory that a training step frees for the next step's tensors.

    Left alone, malloc gives each tensor of a few MB fresh pages from the system and returns them when the
    tensor is freed, so every step pays page faults for the same temporaries again. Setting the mmap and
    trim thresholds high (:data:`HEAP_BLOCK_LIMIT`, :data:`HEAP_KEEP_LIMIT`) keeps them in the process;
    the peak memory is the same. Process-wide and only for glibc on Linux; returns whether it was applied
    (False elsewhere, where nothing changes)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(_MALLOPT_MMAP_THRESHOLD, HEAP_BLOCK_LIMIT)) and \
            bool(libc.mallopt(_MALLOPT_TRIM_THRESHOLD, HEAP_KEEP_LIMIT))
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return False


@contextlib.contextmanager
def small_numpy_pages():
    """Large numpy arrays made in the block (or the decorated function) get ordinary pages, not the
    transparent huge pages numpy asks Linux for from 4 MB. Where the kernel compacts memory to make each
    huge page on first touch (``defrag`` of ``madvise``, common), that fault stalls for far longer than the
    ordinary pages of the same array take; the values are the same. The earlier setting comes back at
    the end. Nothing changes where numpy has no such setting or ``NUMPY_MADVISE_HUGEPAGE`` chose one."""
    try:  # a private numpy function (numpy 2's module path), absent from some builds
        toggle = np._core.multiarray._set_madvise_hugepage
    except AttributeError:
        toggle = None
    if toggle is None or os.environ.get("NUMPY_MADVISE_HUGEPAGE"):
        yield
        return
    before = toggle(False)
    try:
        yield
    finally:
        toggle(before)


def available_bytes() -> int:
    """Memory the system can still give (``MemAvailable`` of /proc/meminfo; physical pages elsewhere)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def _gib(n: float) -> str:
    return f"{n / 2**30:.1f} GiB"


def budget() -> float:
    return USABLE_SHARE * available_bytes()


def _refuse(option: str, value, need: float, room: float, largest, what: str = "") -> None:
    raise ConfigError(f"{option} {value}{what} needs about {_gib(need)} of memory and {_gib(room)} can be used "
                      f"here; the largest that fits is {option} {largest}")


def check_mesh_resolution(resolution: int, option: str = "--resolution") -> None:
    """Refuse a marching-cubes grid whose extraction would not fit in memory."""
    need, room = float(resolution) ** 3 * GRID_BYTES_PER_VOXEL, budget()
    if need > room:
        _refuse(option, resolution, need, room, int((room / GRID_BYTES_PER_VOXEL) ** (1.0 / 3.0)))


def check_render_size(width: int, height: int, scale: float, option: str = "--scale") -> None:
    """Refuse rendering ``width x height`` images at ``scale`` when one view would not fit in memory."""
    need, room = float(width) * height * scale * scale * RENDER_BYTES_PER_PIXEL, budget()
    if need > room:
        largest = math.floor(100.0 * math.sqrt(room / (RENDER_BYTES_PER_PIXEL * width * height))) / 100.0
        _refuse(option, f"{scale:g}", need, room, f"{largest:g}",
                f" ({round(width * scale)}x{round(height * scale)} pixels per view)")


def check_image_side(side: int, option: str) -> None:
    """Refuse rendering ``side x side`` images when one would not fit in memory."""
    need, room = float(side) ** 2 * RENDER_BYTES_PER_PIXEL, budget()
    if need > room:
        _refuse(option, side, need, room, int(math.sqrt(room / RENDER_BYTES_PER_PIXEL)))


def check_view_memory(n_views: int, width: int, height: int, scale: float,
                      option: str = "pipeline.datamanager.dataparser.image_scale") -> None:
    """Refuse loading ``n_views`` views of ``width x height`` at ``scale`` when they would not fit in memory."""
    pixels = float(n_views) * width * height
    need, room = TRAIN_BASE_BYTES + pixels * scale * scale * TRAIN_BYTES_PER_PIXEL, budget()
    if need > room:
        largest = math.floor(100.0 * math.sqrt(max(room - TRAIN_BASE_BYTES, 0.0) /
                                               (pixels * TRAIN_BYTES_PER_PIXEL))) / 100.0
        _refuse(option, f"{scale:g}", need, room, f"{largest:g}",
                f" ({n_views} views of {round(width * scale)}x{round(height * scale)} pixels)")


def check_batch_memory(rays: int, samples_per_ray: int, option: str = "pipeline.datamanager.rays_per_batch") -> None:
    """Refuse a training batch of ``rays`` rays of ``samples_per_ray`` samples that would not fit in memory."""
    per_ray = float(samples_per_ray) * TRAIN_BYTES_PER_SAMPLE
    need, room = TRAIN_BASE_BYTES + rays * per_ray, budget()
    if need > room:
        _refuse(option, rays, need, room, int(max(room - TRAIN_BASE_BYTES, 0.0) // per_ray),
                f" ({samples_per_ray} samples a ray)")


def check_texture_memory(size: int, n_views: int, option: str = "--texture-size") -> None:
    """Refuse a texture bake that would not fit in memory (the largest power of two that fits is named)."""
    per_texel = BAKE_BYTES_PER_TEXEL + BAKE_BYTES_PER_TEXEL_VIEW * n_views
    need, room = float(size) ** 2 * per_texel, budget()
    if need > room:
        largest = 2 ** math.floor(math.log2(max(math.sqrt(room / per_texel), 1.0)))
        _refuse(option, size, need, room, largest, f" with {n_views} views")
