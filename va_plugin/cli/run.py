"""Loading a finished (or interrupted) run back: its config, pipeline and trained weights."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Dict, Optional, Tuple

from va_plugin.engine.trainer import load_checkpoint, schedule_horizon
from va_plugin.errors import CheckpointError
from va_plugin.pipelines.base import Pipeline
from va_plugin.utils.device import pick_device


def load_run(run_dir: Path, device: Optional[str] = None) -> Tuple[Pipeline, Dict[str, Any]]:
    """The pipeline of a run folder with its newest readable checkpoint loaded, and that checkpoint."""
    state = load_checkpoint(Path(run_dir), map_location="cpu")
    config = state.get("config_object")
    if config is None:
        raise CheckpointError(f"{state['path']} carries no config; it was not written by va-train")
    bad = [name for name, value in state["model"].items()
           if hasattr(value, "is_floating_point") and value.is_floating_point() and not bool(value.isfinite().all())]
    if bad:
        raise CheckpointError(f"{state['path']} holds NaN or infinite values ({bad[0]}{' and more' if len(bad) > 1 else ''}): "
                              "the run diverged; retrain it (or resume from a checkpoint before the divergence)")
    config = copy.deepcopy(config)
    torch_device = pick_device(device if device is not None else "auto")
    pipeline = config.pipeline.setup(device=torch_device, max_steps=schedule_horizon(config))
    try:
        pipeline.model.load_state_dict(state["model"])
    except RuntimeError as exc:
        raise CheckpointError(f"{state['path']} does not fit its own config ({str(exc).splitlines()[0]})") from None
    pipeline.model.update_step(int(state["step"]))
    pipeline.model.eval()
    return pipeline, state

