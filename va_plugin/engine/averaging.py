"""The running mean of a model's parameters over the last steps of a run (weight averaging).

Near the end of a schedule the optimizer still moves the parameters from step to step, so the last step's
weights are one draw among many nearby ones. Their mean over the last steps is a steadier estimate of
the same solution.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn


class WeightAverage:
    """The mean of ``params`` over every step after ``start`` (steps done), updated in place.

    ``update(step)`` after each optimizer step; ``apply()`` copies the mean into the parameters."""

    def __init__(self, params: list[nn.Parameter], start: int) -> None:
        self.params = params
        self.start = start
        self.count = 0
        self.mean: list[torch.Tensor] | None = None

    @torch.no_grad()
    def update(self, step: int) -> None:
        """Add the parameters as they stand after ``step`` steps (nothing before ``start``)."""
        if step <= self.start:
            return
        self.count += 1
        if self.mean is None:
            self.mean = [p.detach().clone() for p in self.params]
            return
        weight = 1.0 / self.count
        for mean, param in zip(self.mean, self.params):
            mean.lerp_(param.detach(), weight)  # mean += (param - mean) / count

    def after_step(self, done: int, last: int, model: Any) -> None:
        """After the optimizer step that makes ``done`` steps: :meth:`update`, and after step ``last`` the
        mean replaces the weights, with ``model``'s step schedules (e.g. the inv_s floor) set for them."""
        self.update(done)
        if done == last and self.apply():
            model.restore_step(done - 1)

    @torch.no_grad()
    def apply(self) -> bool:
        """Copy the mean into the parameters; False (nothing changed) before any step was averaged."""
        if self.mean is None:
            return False
        for mean, param in zip(self.mean, self.params):
            param.copy_(mean)
        return True

    def state_dict(self) -> dict[str, Any]:
        return {"start": self.start, "count": self.count,
                "mean": None if self.mean is None else [m.clone() for m in self.mean]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.count = int(state.get("count", 0))
        mean = state.get("mean")
        if mean is None:
            self.mean = None
            return
        if len(mean) != len(self.params) or any(m.shape != p.shape for m, p in zip(mean, self.params)):
            raise ValueError("the averaged weights do not fit the model's parameters")
        self.mean = [m.to(device=p.device, dtype=p.dtype).clone() for m, p in zip(mean, self.params)]
