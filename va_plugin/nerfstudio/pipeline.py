"""The pipeline of the va methods in nerfstudio: our Pipeline (data manager + model) behind nerfstudio's.

Training steps go as ``va-train``'s do: the same rays, the same losses, the learning rates set before each
step by our schedule (warm-up, cosine) times the factors our callbacks ask for (the view-adaptive phases
slow the shared field), denormal floats flushed during each step on the CPU. Beside nerfstudio's own
checkpoint the run folder gets one in our format (``checkpoints/step-N.ckpt``), so that ``va-export``,
``va-eval`` and ``va-recon``'s tools read a nerfstudio run like one of ``va-train``.
"""

from __future__ import annotations

import contextlib
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import tyro
from nerfstudio.configs.base_config import InstantiateConfig
from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.pipelines.base_pipeline import Pipeline
from nerfstudio.utils.rich_utils import CONSOLE

from va_plugin.cli.common import EXIT_USER_ERROR
from va_plugin.config import to_dict
from va_plugin.engine.averaging import WeightAverage
from va_plugin.engine.metrics_log import append_record
from va_plugin.engine.optimizers import OptimizerConfig, SchedulerConfig
from va_plugin.engine.trainer import CHECKPOINT_DIR, TrainerConfig, atomic_save, list_checkpoints
from va_plugin.errors import ConfigError, VAError
from va_plugin.fields.encodings.hash_kernel import denormals_flushed
from va_plugin.nerfstudio.datamanager import VAGeneratorDataManagerConfig
from va_plugin.nerfstudio.model import VAModelConfig
from va_plugin.pipelines.base import Pipeline as VAPipelineCore
from va_plugin.pipelines.base import PipelineConfig as VAPipelineCoreConfig

BEFORE, AFTER = TrainingCallbackLocation.BEFORE_TRAIN_ITERATION, TrainingCallbackLocation.AFTER_TRAIN_ITERATION


@dataclass
class VAPipelineConfig(InstantiateConfig):
    """A va-plugin data manager and model, trained on our schedules."""

    _target: type = field(default_factory=lambda: VAPipeline)
    datamanager: VAGeneratorDataManagerConfig = field(default_factory=VAGeneratorDataManagerConfig)
    """Where training rays come from."""
    model: VAModelConfig = field(default_factory=VAModelConfig)
    """What renders them."""
    scheduler: SchedulerConfig = field(default_factory=SchedulerConfig)
    """Learning-rate schedule shared by every optimizer group (base rates: --optimizers.NAME.optimizer.lr)."""
    schedule_steps: int = 0
    """Steps over which every schedule runs (learning rate, grid levels, the view-adaptive phases); 0: the
    trainer's --max-num-iterations. A longer budget trains on at the schedules' final values."""
    max_steps: tyro.conf.Suppress[int] = 0
    """The trainer's --max-num-iterations (copied by VATrainerConfig)."""
    average_fraction: float = 0.0
    """Share of the steps, at the end of the run, over which the weights are averaged: the run ends with the
    mean of the parameters after each of those steps (0: the last step's), as va-train's option."""

    def resolved_schedule_steps(self) -> int:
        """``min(max_steps, schedule_steps)``, or ``max_steps`` when ``schedule_steps`` is 0 (as va-train)."""
        steps = max(int(self.max_steps), 1)
        return min(steps, int(self.schedule_steps)) if self.schedule_steps > 0 else steps


class VAPipeline(Pipeline):
    """Our pipeline (``va``, kept out of the module tree so that each weight is saved once) behind
    nerfstudio's; ``datamanager`` and ``model`` wrap its parts."""

    config: VAPipelineConfig

    def __init__(self, config: VAPipelineConfig, device: str | torch.device = "cpu", test_mode: str = "val",
                 world_size: int = 1, local_rank: int = 0, grad_scaler: Any = None, **kwargs: Any) -> None:
        super().__init__()
        self.config, self.test_mode, self.world_size, self.local_rank = config, test_mode, world_size, local_rank
        try:
            self._build(torch.device(device), grad_scaler)
        except VAError as exc:  # bad input or options: one line and exit status 2, as our commands do
            print(f"error: {exc}", file=sys.stderr)
            raise SystemExit(EXIT_USER_ERROR) from None
        self._flush = contextlib.ExitStack()
        self._method = "va"
        self._run_dir: Path | None = None

    def _build(self, device: torch.device, grad_scaler: Any) -> None:
        config, test_mode, world_size, local_rank = self.config, self.test_mode, self.world_size, self.local_rank
        if not 0.0 <= config.average_fraction < 1.0:
            raise ConfigError(f"--pipeline.average-fraction must be in [0, 1), got {config.average_fraction}")
        self.schedule_steps = config.resolved_schedule_steps()
        self.datamanager = config.datamanager.setup(device=device, test_mode=test_mode, world_size=world_size,
                                                    local_rank=local_rank)
        va_config = VAPipelineCoreConfig(datamanager=self.datamanager.va_config, model=config.model.va)
        # built in va-train's order (data, then the model's random initialisation)
        va = VAPipelineCore(va_config, device, self.schedule_steps, datamanager=self.datamanager.va)
        object.__setattr__(self, "va", va)  # not a submodule: the weights live once, under _model
        self._model = config.model.setup(scene_box=self.datamanager.train_dataset.scene_box,
                                         num_train_data=va.datamanager.num_train_views, metadata={},
                                         device=device, grad_scaler=grad_scaler, va_model=va.model)
        self._model.to(device)

    # -- training -------------------------------------------------------------------------------
    def get_train_loss_dict(self, step: int):
        ray_bundle, batch = self.datamanager.next_train(step)
        outputs = self._model(ray_bundle)
        loss_dict = self.model.get_loss_dict(outputs, batch)
        metrics = self.model.get_metrics_dict(outputs, batch)
        return outputs, loss_dict, metrics

    def get_param_groups(self) -> dict[str, list[torch.nn.Parameter]]:
        return self.model.get_param_groups()

    def announce(self, step: int, message: str, **fields: Any) -> None:
        """An event of the run (a phase switch): a console line and a record in the run's metrics.jsonl."""
        CONSOLE.print(f"[{self._method}] step {step}: {message}", markup=False, highlight=False)
        if self._run_dir is not None:
            append_record(self._run_dir, {"step": step, "event": message, **fields})

    def get_training_callbacks(self, training_callback_attributes: TrainingCallbackAttributes
                               ) -> list[TrainingCallback]:
        """Denormals flushed for the step, our model's callbacks, the learning rates; after the step the
        flush ends, and our checkpoint follows nerfstudio's."""
        trainer = training_callback_attributes.trainer
        self._method, self._run_dir = trainer.config.method_name, Path(trainer.base_dir)
        optimizers = training_callback_attributes.optimizers
        cpu = self.va.device.type == "cpu"

        def flush_on(step: int) -> None:
            self._flush.enter_context(denormals_flushed(cpu))

        def flush_off(step: int) -> None:
            self._flush.close()

        def learning_rates(step: int) -> None:
            factor = self.config.scheduler.factor(step, self.schedule_steps)
            for name, optimizer in optimizers.optimizers.items():
                rate = optimizers.config[name]["optimizer"].lr * factor * self.model.lr_factors.get(name, 1.0)
                for group in optimizer.param_groups:
                    group["lr"] = rate

        def save(step: int) -> None:
            every = trainer.config.steps_per_save
            if every > 0 and step > 0 and step % every == 0:
                self.save_va_checkpoint(trainer, step)

        def save_last(step: int) -> None:
            self.save_va_checkpoint(trainer, step)

        max_steps = trainer.config.max_num_iterations
        averaged = round(self.config.average_fraction * max_steps)
        average = WeightAverage(list(self.va.model.parameters()), max_steps - averaged) if averaged else None

        def average_weights(step: int) -> None:  # after the optimizer step of 0-based ``step``
            average.after_step(step + 1, max_steps, self.va.model)

        # after a step the average comes first: the model's after-step callbacks see the weights it ends with
        return [TrainingCallback([BEFORE], flush_on),
                *([TrainingCallback([AFTER], average_weights)] if average is not None else []),
                *self.model.get_training_callbacks(training_callback_attributes),
                TrainingCallback([BEFORE], learning_rates),
                TrainingCallback([AFTER], flush_off),
                TrainingCallback([AFTER], save),
                TrainingCallback([TrainingCallbackLocation.AFTER_TRAIN], save_last)]

    # -- our checkpoint -------------------------------------------------------------------------
    def va_trainer_config(self, trainer: Any) -> TrainerConfig:
        """The run as va-train would have configured it (what our tools read back)."""
        ns = trainer.config
        optimizers = {name: OptimizerConfig(lr=entry["optimizer"].lr, eps=entry["optimizer"].eps,
                                            weight_decay=getattr(entry["optimizer"], "weight_decay", 0.0))
                      for name, entry in ns.optimizers.items()}
        return TrainerConfig(method_name=ns.method_name, pipeline=self.va.config, optimizers=optimizers,
                             scheduler=self.config.scheduler, max_steps=ns.max_num_iterations,
                             schedule_steps=self.schedule_steps, average_fraction=self.config.average_fraction,
                             seed=ns.machine.seed,
                             output_dir=Path(trainer.base_dir), checkpoint_every=max(ns.steps_per_save, 1))

    def save_va_checkpoint(self, trainer: Any, step: int) -> Path:
        """``RUN/checkpoints/step-N.ckpt`` (N: steps done, ``step + 1``) in our format, the older one removed."""
        config = self.va_trainer_config(trainer)
        done = step + 1
        path = Path(trainer.base_dir) / CHECKPOINT_DIR / f"step-{done:07d}.ckpt"
        atomic_save({"method_name": config.method_name, "step": done, "model": self.va.model.state_dict(),
                     "config": to_dict(config), "config_object": config, "saved_at": time.time()}, path)
        for old in list_checkpoints(Path(trainer.base_dir))[:-1]:
            old.unlink(missing_ok=True)
        return path

    # -- loading and evaluation -----------------------------------------------------------------
    def load_pipeline(self, loaded_state: dict[str, Any], step: int) -> None:
        state = {key.removeprefix("module."): value for key, value in loaded_state.items()}
        self.model.update_to_step(step)
        self.load_state_dict(state)

    def get_eval_image_metrics_and_images(self, step: int):
        metrics, renders = self.va.evaluate_views(1)
        images = {"img": torch.cat([renders[0]["target"], renders[0]["rgb"]], dim=1)} if renders else {}
        return {**metrics, "num_rays": self.va.datamanager.train.cameras.width ** 2}, images

    def get_average_eval_image_metrics(self, step: int | None = None, output_path: Path | None = None,
                                       get_std: bool = False) -> dict[str, float]:
        metrics, _ = self.va.evaluate_views()
        return metrics
