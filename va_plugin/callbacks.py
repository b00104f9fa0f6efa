"""Training callbacks: how models and wrappers react to the step without knowing the trainer.

A callback gets the step and :class:`TrainingCallbackAttributes` (never the trainer) and returns the
learning-rate factors it wants, by optimizer group. The module stands on the bottom floor: the models and
the view-adaptive wrapper build callbacks, and the trainer, floors above them, runs them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

BEFORE_STEP = "before_step"
AFTER_STEP = "after_step"

LearningRateFactors = dict[str, float] | None
"""What a callback returns: ``{optimizer group: learning-rate factor}`` (kept until changed), or None."""


@dataclass(frozen=True)
class TrainingCallbackAttributes:
    """What a callback may read and use."""

    pipeline: Any  # the :class:`~va_plugin.pipelines.base.Pipeline`: data manager and model
    max_steps: int  # the step budget
    run_dir: Path  # the run folder (for files a callback writes)
    progress: bool  # whether the run shows progress (and so may print)
    announce: Callable[..., None]  # ``announce(step, message, **fields)``: a console line and a log record
    schedule_steps: int  # where the run's schedules (the adaptive phases, ...) end: see ``schedule_steps_of``


@dataclass
class TrainingCallback:
    """Calls ``fn(step, attributes)`` every ``every`` steps, before or after the optimizer step; ``fn``
    may return learning-rate factors (:data:`LearningRateFactors`)."""

    fn: Callable[[int, TrainingCallbackAttributes], LearningRateFactors]
    where: str = BEFORE_STEP
    every: int = 1

    def __call__(self, step: int, attributes: TrainingCallbackAttributes) -> LearningRateFactors:
        if step % self.every == 0:
            return self.fn(step, attributes)
        return None
