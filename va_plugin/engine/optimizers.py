"""Optimizer and learning-rate schedule configs, keyed by parameter group."""

from __future__ import annotations

import math
from dataclasses import dataclass

from va_plugin.config import Checked
from va_plugin.errors import ConfigError


@dataclass
class OptimizerConfig(Checked):
    """Adam for one parameter group."""

    lr: float = 5e-4
    """Base learning rate of the group."""
    eps: float = 1e-15
    """Adam's epsilon (fp32 only: fp16 would round it to 0)."""
    weight_decay: float = 0.0
    """L2 weight decay."""

    def validate(self, prefix: str = "") -> None:
        """Refuse settings that would train backwards or not at all (a negative rate is gradient ascent);
        ``prefix``: the group's key (``optimizers.fields.``)."""
        if not (math.isfinite(self.lr) and self.lr >= 0.0):
            raise ConfigError(f"{prefix}lr must be a finite number >= 0, got {self.lr}")
        if not (math.isfinite(self.eps) and self.eps > 0.0):
            raise ConfigError(f"{prefix}eps must be a finite number > 0, got {self.eps}")
        if not (math.isfinite(self.weight_decay) and self.weight_decay >= 0.0):
            raise ConfigError(f"{prefix}weight_decay must be a finite number >= 0, got {self.weight_decay}")


@dataclass
class SchedulerConfig(Checked):
    """Linear warm-up, then cosine decay to ``final_fraction`` of the base rate."""

    warmup_steps: int = 100
    """Steps of linear warm-up from 0."""
    final_fraction: float = 0.05
    """Learning rate at the last step, as a fraction of the base rate."""

    def validate(self, prefix: str = "scheduler.") -> None:
        if self.warmup_steps < 0:
            raise ConfigError(f"{prefix}warmup_steps must be >= 0, got {self.warmup_steps}")
        if not (math.isfinite(self.final_fraction) and 0.0 <= self.final_fraction <= 1.0):
            raise ConfigError(f"{prefix}final_fraction must be in [0, 1], got {self.final_fraction}")

    def factor(self, step: int, schedule_steps: int) -> float:
        if self.warmup_steps > 0 and step < self.warmup_steps:
            return (step + 1) / self.warmup_steps
        span = max(1, schedule_steps - self.warmup_steps)
        progress = min(1.0, max(0.0, (step - self.warmup_steps) / span))
        cosine = 0.5 * (1.0 + math.cos(math.pi * progress))
        return self.final_fraction + (1.0 - self.final_fraction) * cosine
