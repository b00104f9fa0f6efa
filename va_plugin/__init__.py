"""va-plugin: generated multi-view images to a textured mesh (NeuS / InstantNGP, with the paper's view-adaptive
renderer). The Python API (:mod:`va_plugin.api`) is reachable from here: ``va_plugin.reconstruct(...)``."""

from va_plugin.utils.interrupts import interrupt_deferred

with interrupt_deferred():  # trimesh's imports swallow a Ctrl-C that lands during them (see there)
    import trimesh  # noqa: F401

API = ("reconstruct", "build_config", "train", "export_mesh", "evaluate", "render", "load_run",
       "Reconstruction", "MeshFiles", "LoadedRun", "ExportConfig", "TrainingInterrupted")
"""The names of :mod:`va_plugin.api` that ``import va_plugin`` offers."""


def __getattr__(name: str):
    """``va_plugin.reconstruct`` and the rest of :data:`API`, imported on first use (so that importing a
    submodule does not import torch and every floor above it)."""
    if name in API:
        from va_plugin import api  # lazy: the API sits on the top floors, this package's root on none

        return getattr(api, name)
    raise AttributeError(f"module 'va_plugin' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *API])
