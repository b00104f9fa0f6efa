"""Timing a training run: where a step's time goes (the stage markers of :mod:`va_plugin.utils.stages`
around a trained run's next steps), the mean of logged per-ray counts, and the time to reach the final
accuracy on a curve of checkpoints (``benchmarks/run_speed.py``)."""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from torch import nn

from va_plugin.adaptive.attention import ViewAttention
from va_plugin.engine.metrics_log import training_records
from va_plugin.fields.encodings.hash_grid import HashGridEncoding
from va_plugin.fields.encodings.positional import PositionalEncoding
from va_plugin.utils.stages import recording, stage, time_modules

STAGES = ("data", "sampling", "encoding", "mlp", "sdf_gradient", "rendering", "backward", "optimizer", "health",
          "callbacks")
"""The named stages of a step, in the order of the tables (``health``: the trainer's finite-value checks
and snapshots; ``callbacks``: occupancy-grid updates, phase switches); ``other`` is what none covers."""
CD_FACTOR = 1.1
"""Time to accuracy: the first checkpoint from which the CD stays within this factor of the run's final CD."""


def instrument(model: nn.Module) -> list[object]:
    """Time the model's encodings as ``encoding`` and its network layers (linear layers, activations,
    the view attention) as ``mlp``; returns the hook handles."""
    encodings = [m for m in model.modules() if isinstance(m, (PositionalEncoding, HashGridEncoding))]
    networks = [m for m in model.modules() if isinstance(m, (nn.Linear, ViewAttention))
                or type(m).__module__ == nn.ReLU.__module__]
    return time_modules(encodings, "encoding") + time_modules(networks, "mlp")


def stage_breakdown(trainer, warmup: int, steps: int) -> dict[str, Any]:
    """Median seconds per :data:`STAGES` stage (exclusive, and inclusive) of ``steps`` training steps after
    ``warmup`` more, continuing the trained run of ``trainer``; on CUDA each stage boundary synchronizes."""
    synchronize = trainer.device.type == "cuda"
    handles = instrument(trainer.model)
    totals: list[float] = []
    per_stage: dict[str, list[float]] = {name: [] for name in (*STAGES, "other")}
    inclusive: dict[str, list[float]] = {name: [] for name in STAGES}
    try:
        with recording(synchronize) as recorder:
            for index in range(warmup + steps):
                recorder.reset()
                with stage("step"):
                    trainer.run_step()
                if index < warmup:
                    continue
                totals.append(recorder.inclusive["step"])
                per_stage["other"].append(recorder.exclusive["step"])
                for name in STAGES:
                    per_stage[name].append(recorder.exclusive.get(name, 0.0))
                    inclusive[name].append(recorder.inclusive.get(name, 0.0))
    finally:
        for handle in handles:
            handle.remove()
    return {"step_seconds": statistics.median(totals),
            "stages": {name: statistics.median(v) for name, v in per_stage.items()},
            "inclusive": {name: statistics.median(v) for name, v in inclusive.items()},
            "timed_steps": steps, "warmup_steps": warmup, "synchronized": synchronize,
            "step_seconds_all": [round(t, 5) for t in totals]}


def logged_means(run_dir: Path, keys: Sequence[str]) -> dict[str, float | None]:
    """Mean over the run's training log lines of each key (None when the method does not log it)."""
    records = training_records(run_dir)
    out: dict[str, float | None] = {}
    for key in keys:
        values = [r[key] for r in records if key in r]
        out[key] = round(statistics.fmean(values), 3) if values else None
    return out


def time_to_reach(curve: Sequence[dict[str, Any]], factor: float = CD_FACTOR) -> dict[str, Any]:
    """The first checkpoint from which the CD stays within ``factor`` of the last one's (every later
    checkpoint too: CD is not monotone during training, and an early smooth blob near the visual hull
    can score close to the final CD by chance), and the first checkpoint that touches it at all."""
    final = curve[-1].get("cd") if curve else None
    if final is None or not math.isfinite(final):
        return {"train_seconds": None, "step": None, "target_cd": None, "first_touch_seconds": None}
    target = factor * final
    inside = [p.get("cd") is not None and math.isfinite(p["cd"]) and p["cd"] <= target for p in curve]
    start = len(inside) - 1
    while start > 0 and inside[start - 1]:
        start -= 1
    first = inside.index(True)
    return {"train_seconds": curve[start]["train_seconds"], "step": curve[start]["step"], "target_cd": target,
            "first_touch_seconds": curve[first]["train_seconds"], "first_touch_step": curve[first]["step"]}
