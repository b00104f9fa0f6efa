"""Training callbacks: how models and wrappers react to the step without knowing the trainer."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

BEFORE_STEP = "before_step"
AFTER_STEP = "after_step"


@dataclass
class TrainingCallback:
    """Calls ``fn(step, trainer)`` every ``every`` steps, before or after the optimizer step."""

    fn: Callable[[int, object], None]
    where: str = BEFORE_STEP
    every: int = 1

    def __call__(self, step: int, trainer: object) -> None:
        if step % self.every == 0:
            self.fn(step, trainer)
