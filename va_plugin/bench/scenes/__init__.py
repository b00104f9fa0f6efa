"""Benchmark scenes: procedural objects, textured meshes and Google Scanned Objects on the SyncDreamer rig,
with controlled, seeded view inconsistency (see :mod:`va_plugin.bench.scenes.inconsistency`)."""

from va_plugin.bench.scenes.builder import (
    SCENE_VERSION,
    build_procedural_scene,
    build_scene,
    cache_dir,
    default_scene,
    ensure_default_scene,
)
from va_plugin.bench.scenes.figure import inputs_figure
from va_plugin.bench.scenes.inconsistency import KINDS, LEVELS, InconsistencySpec
from va_plugin.bench.scenes.shapes import list_objects

__all__ = [
    "KINDS",
    "LEVELS",
    "SCENE_VERSION",
    "InconsistencySpec",
    "build_procedural_scene",
    "build_scene",
    "cache_dir",
    "default_scene",
    "ensure_default_scene",
    "inputs_figure",
    "list_objects",
]
