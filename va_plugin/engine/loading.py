"""A trained run folder read back (:func:`load_run`), and the lock a command holds while it writes into one."""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from va_plugin.engine.run_folder import writing_into_run
from va_plugin.engine.trainer import TrainerConfig, load_checkpoint, schedule_steps_of
from va_plugin.errors import CheckpointError
from va_plugin.pipelines.base import Pipeline
from va_plugin.utils.device import pick_device
from va_plugin.utils.paths import user_path


@dataclass
class LoadedRun:
    """A run folder read back: its pipeline (trained weights loaded, eval mode) and newest checkpoint."""

    path: Path
    pipeline: Pipeline
    state: dict[str, Any]

    @property
    def config(self) -> TrainerConfig:
        return self.state["config_object"]

    def parts(self) -> tuple[Pipeline, dict[str, Any]]:
        """(pipeline, checkpoint state), for ``pipeline, state = load_run(run).parts()``."""
        return self.pipeline, self.state


def load_run(run: str | Path | LoadedRun, device: str | None = None) -> LoadedRun:
    """The run folder's pipeline with its newest readable checkpoint loaded (a :class:`LoadedRun` passes
    through as it is)."""
    if isinstance(run, LoadedRun):
        return run
    run = user_path(run, "run")
    state = load_checkpoint(run, map_location="cpu")
    config = state.get("config_object")
    if config is None:
        raise CheckpointError(f"{state['path']} carries no config; it was not written by va-train")
    bad = [name for name, value in state["model"].items()
           if isinstance(value, torch.Tensor) and value.is_floating_point() and not bool(value.isfinite().all())]
    if bad:
        raise CheckpointError(f"{state['path']} holds NaN or infinite values ({bad[0]}"
                              f"{' and more' if len(bad) > 1 else ''}): the run diverged; retrain it (or resume "
                              "from a checkpoint before the divergence)")
    config = copy.deepcopy(config)
    torch_device = pick_device(device if device is not None else "auto")
    pipeline = config.pipeline.setup(device=torch_device, schedule_steps=schedule_steps_of(config))
    try:
        pipeline.model.load_state_dict(state["model"])
    except RuntimeError as exc:
        raise CheckpointError(f"{state['path']} does not fit its own config ({str(exc).splitlines()[0]})") from None
    # the schedules of the run's last trained step, as the trainer left them (no parameter is touched)
    pipeline.model.restore_step(max(int(state["step"]) - 1, 0))
    pipeline.model.eval()
    return LoadedRun(run, pipeline, state)


def run_path(run: str | Path | LoadedRun) -> Path:
    """The folder of ``run`` (a path taken with ``~`` expanded and resolved)."""
    return run.path if isinstance(run, LoadedRun) else user_path(run, "run")


def locks_run(function: Callable[..., Any]) -> Callable[..., Any]:
    """Hold the run folder's lock (:func:`~va_plugin.engine.run_folder.writing_into_run`) while ``function``
    writes into it; a run that another process is training or exporting is refused."""

    @functools.wraps(function)
    def locked(run: str | Path | LoadedRun, *args: Any, **kwargs: Any) -> Any:
        if not isinstance(run, LoadedRun):
            run = user_path(run, "run")
        with writing_into_run(run_path(run)):
            return function(run, *args, **kwargs)

    return locked
