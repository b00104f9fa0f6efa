"""The same steps under both trainers: the loss terms of the first steps of a ``va-train`` config and of
its nerfstudio config, run in this process as each command runs them (same seed, same batches)."""

from __future__ import annotations

from typing import Any

from nerfstudio.scripts.train import _set_random_seed

from va_plugin.engine.trainer import TrainerConfig


def va_train_losses(config: TrainerConfig, steps: int) -> list[dict[str, float]]:
    """Each step's loss terms under our trainer (``config`` trains ``steps`` steps)."""
    trainer = config.setup()
    losses = []
    for _ in range(steps):
        record, _ = trainer.run_step()
        losses.append({key.removeprefix("loss_"): value for key, value in record.items() if key.startswith("loss_")})
    return losses


def ns_train_losses(config: Any, steps: int) -> list[dict[str, float]]:
    """Each step's loss terms under nerfstudio's trainer, set up as ns-train sets it up (``config``: a
    nerfstudio ``TrainerConfig``; its budget becomes ``steps``)."""
    return ns_train(config, steps)[0]


def ns_train(config: Any, steps: int) -> tuple[list[dict[str, float]], Any]:
    """:func:`ns_train_losses` and the trained nerfstudio trainer (its ``pipeline.va`` is our pipeline)."""
    config.max_num_iterations = config.pipeline.max_steps = steps
    _set_random_seed(config.machine.seed)
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    losses = []
    step_losses = trainer.pipeline.get_train_loss_dict

    def recorded(step: int):
        outputs, loss_dict, metrics = step_losses(step)
        losses.append({key: float(value.detach()) for key, value in loss_dict.items()})
        return outputs, loss_dict, metrics

    trainer.pipeline.get_train_loss_dict = recorded
    trainer.train()
    return losses, trainer


def largest_difference(ours: list[dict[str, float]], theirs: list[dict[str, float]]) -> float:
    """The largest relative difference ``|a - b| / max(|a|, 1e-12)`` over every step and loss term (inf when
    the steps or terms differ)."""
    if [sorted(o) for o in ours] != [sorted(t) for t in theirs]:
        return float("inf")
    return max((abs(o[k] - t[k]) / max(abs(o[k]), 1e-12) for o, t in zip(ours, theirs, strict=True) for k in o),
               default=0.0)
