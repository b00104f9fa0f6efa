"""The host trainer: optimizers per parameter group, schedules, callbacks, logs and checkpoints."""

from __future__ import annotations

import json
import math
import os
import pickle
import random
import signal
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from tqdm import tqdm

from va_plugin.callbacks import AFTER_STEP, BEFORE_STEP, TrainingCallback, TrainingCallbackAttributes
from va_plugin.config import InstantiateConfig, to_dict, validate_config
from va_plugin.engine.averaging import WeightAverage
from va_plugin.engine.health import OK, SKIP, HealthConfig, TrainingGuard, check_usable
from va_plugin.engine.metrics_log import METRICS_FILE, append_record, read_records, write_records
from va_plugin.engine.optimizers import OptimizerConfig, SchedulerConfig
from va_plugin.errors import CheckpointError, ConfigError, OutputError, VAError
from va_plugin.fields.encodings.hash_kernel import denormals_flushed
from va_plugin.pipelines.base import PipelineConfig
from va_plugin.utils.device import pick_device
from va_plugin.utils.files import DISK_FULL, NOT_WRITABLE, output_error, replace_atomic, write_atomic
from va_plugin.utils.interrupts import signal_plan, signals_as_requests, signals_held
from va_plugin.utils.memory import keep_freed_memory
from va_plugin.utils.progress import progress_bar
from va_plugin.utils.stages import stage, timed

CHECKPOINT_DIR = "checkpoints"
CHECKPOINT_GLOB = "step-*.ckpt"
UNREADABLE_SUFFIX = ".unreadable"
"""Added to the name of a checkpoint a resume skipped as unreadable (kept, but no longer a checkpoint)."""
SIGNALS_ENV = "VA_TEST_SIGNALS"
"""Test hook: signals a run sends itself at chosen steps (see :func:`va_plugin.utils.interrupts.signal_plan`)."""


@dataclass
class TrainerConfig(InstantiateConfig):
    """Everything a training run needs: the method's pipeline, its optimizers and the run's options."""

    _target: type = field(default_factory=lambda: Trainer)
    method_name: str = "unnamed"
    """Registered name of the method (checked when resuming)."""
    preset_name = "default"  # no annotation, so not a field: no part of the config's digest or its file
    """The preset the config was built from (``va_plugin.api.build_config`` sets it; the run folder's
    manifest names it)."""
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    """Data manager and model."""
    optimizers: dict[str, OptimizerConfig] = field(
        default_factory=lambda: {"fields": OptimizerConfig(), "variance": OptimizerConfig()})
    """One optimizer config per parameter group the model reports."""
    scheduler: SchedulerConfig = field(default_factory=SchedulerConfig)
    """Learning-rate schedule shared by every group."""
    max_steps: int = 2000
    """Training steps (the step budget)."""
    schedule_steps: int = 0
    """Steps over which every schedule runs (learning rate, grid levels, priors' starts, annealing, the
    adaptive phases); 0: ``max_steps``. A shorter budget compresses the schedules; a longer one trains
    past ``schedule_steps`` at their final values (see :func:`schedule_steps_of`)."""
    average_fraction: float = 0.0
    """Share of ``max_steps``, at the end of the run, over which the weights are averaged: the run ends with
    the mean of the parameters after each of those steps instead of the last step's (0: the last step's)."""
    seed: int = 42
    """Seed of every random generator (the paper's 42)."""
    device: str = "auto"
    """"auto" (CUDA when present), "cpu" or "cuda[:N]"."""
    output_dir: Path = Path("outputs/run")
    """Run folder: config, metrics log, checkpoints and exports."""
    checkpoint_every: int = 500
    """Steps between checkpoints (one is always written at the end)."""
    keep_checkpoints: int = 2
    """How many recent checkpoints to keep."""
    log_every: int = 25
    """Steps between lines of the metrics log."""
    eval_every: int = 0
    """Steps between renders of the held-out views (0: only at the end)."""
    eval_views: int = 2
    """Held-out views rendered by the periodic evaluation."""
    num_threads: int = 0
    """CPU threads for torch (0: torch's default)."""
    progress: bool = True
    """Show a progress bar."""
    health: HealthConfig = field(default_factory=HealthConfig)
    """What counts as a bad step (non-finite, blow-up) and how the run recovers from it."""

    def validate(self, prefix: str = "") -> None:
        """What the field-by-field range rules do not cover (see :func:`~va_plugin.config.validate_config`)."""
        if self.max_steps < 1:
            raise ConfigError(f"max_steps must be at least 1, got {self.max_steps}")
        if self.schedule_steps < 0:
            raise ConfigError(f"schedule_steps must be >= 0 (0: max_steps), got {self.schedule_steps}")
        if not (math.isfinite(self.average_fraction) and 0.0 <= self.average_fraction < 1.0):
            raise ConfigError(f"average_fraction must be in [0, 1), got {self.average_fraction}")


def schedule_steps_of(config: TrainerConfig) -> int:
    """The step at which a run's schedules end: ``min(max_steps, schedule_steps)``, or ``max_steps`` when
    ``schedule_steps`` is 0."""
    steps, schedule = int(config.max_steps), int(config.schedule_steps)
    return min(steps, schedule) if schedule > 0 else steps


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % (2 ** 32))
    torch.manual_seed(seed)


class _WriteRecorder:
    """A file handle that keeps the OSError of a failed write, which ``torch.save`` turns into a bare
    RuntimeError."""

    def __init__(self, handle) -> None:
        self.handle, self.error = handle, None

    def write(self, data) -> int:
        try:
            return self.handle.write(data)
        except OSError as exc:
            self.error = exc
            raise

    def flush(self) -> None:
        self.handle.flush()


def _torch_save(obj: Any, handle) -> None:
    recorder = _WriteRecorder(handle)
    try:
        torch.save(obj, recorder)
    except RuntimeError:
        if recorder.error is not None:  # the disk's error, not torch's wrapper of it
            raise recorder.error from None
        raise


def atomic_save(obj: Any, path: Path) -> None:
    """Write to a temporary file in the same folder, then rename: never a half-written file in place, and
    no temporary file left when the write fails (a full disk raises its OSError)."""
    replace_atomic(Path(path), lambda handle: _torch_save(obj, handle))


def list_checkpoints(run_dir: Path) -> list[Path]:
    """Checkpoints of a run, oldest first."""
    return sorted((Path(run_dir) / CHECKPOINT_DIR).glob(CHECKPOINT_GLOB))


def make_adam(param_groups) -> torch.optim.Optimizer:
    """Adam over ``param_groups``, on the fused kernel (one pass over each tensor) for CPU and CUDA
    floating-point parameters; anything else takes the default loop."""
    params = [p for group in param_groups for p in group["params"]]
    fusable = bool(params) and all(p.is_floating_point() and p.device.type in ("cpu", "cuda") for p in params)
    if fusable:
        try:
            return torch.optim.Adam(param_groups, fused=True)
        except (RuntimeError, TypeError, ValueError):  # a torch build without the fused kernel
            pass
    return torch.optim.Adam(param_groups)


def _transpose_stale_moments(optimizer: torch.optim.Optimizer) -> None:
    """Transpose optimizer moments saved for a matrix parameter in the transposed layout (a hash table
    checkpointed entry-major, now stored feature-major), so that a resumed run steps as before."""
    for group in optimizer.param_groups:
        for param in group["params"]:
            for name, value in optimizer.state.get(param, {}).items():
                if (torch.is_tensor(value) and value.dim() == 2 and value.shape != param.shape
                        and value.shape == param.shape[::-1]):
                    optimizer.state[param][name] = value.t().contiguous()


class RemovedOption:
    """Stands in, in a loaded checkpoint's config, for an option class this version no longer has."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        pass

    def __setstate__(self, state: Any) -> None:
        pass


_RIGGED_GENERATORS = ("SyncDreamer", "Zero123pp", "Wonder3D")
"""Generators whose hand-written parsers became rig files: their runs' configs load under the new classes."""


class _Unpickler(pickle.Unpickler):
    """Unpickles checkpoints of earlier versions: a renamed class is found under its new name, a va_plugin
    class that is gone becomes :class:`RemovedOption`."""

    RENAMED: ClassVar[dict[tuple[str, str], tuple[str, str]]] = {
        ("va_plugin.data.foreground", "ColourKey"): ("va_plugin.data.foreground", "ColorKey"),
        **{("va_plugin.data.dataparsers.generators", f"{name}DataParserConfig"):
           ("va_plugin.data.dataparsers.rigged", f"{name}DataParserConfig") for name in _RIGGED_GENERATORS},
        **{("va_plugin.data.dataparsers.generators", f"{name}DataParser"):
           ("va_plugin.data.dataparsers.rigged", "RigDataParser") for name in _RIGGED_GENERATORS}}
    """(module, class) of an earlier version -> where that class is now."""

    def find_class(self, module: str, name: str) -> Any:
        module, name = self.RENAMED.get((module, name), (module, name))
        try:
            return super().find_class(module, name)
        except (ImportError, AttributeError):
            if module.split(".")[0] in ("va_plugin", "method_configs"):
                return RemovedOption
            raise


class _TolerantPickle:
    """``torch.load``'s ``pickle_module`` with :class:`_Unpickler`."""

    Unpickler = _Unpickler
    load = staticmethod(lambda file, **kw: _Unpickler(file, **kw).load())
    __name__ = "pickle"


def checkpoint_step(path: Path) -> int | None:
    """The step in a checkpoint's name (``step-0000012.ckpt`` -> 12), None for another name."""
    digits = Path(path).name.removeprefix("step-").removesuffix(".ckpt")
    return int(digits) if digits.isdigit() else None


def load_checkpoint(run_dir: Path, map_location: Any = "cpu", set_aside: bool = False) -> dict[str, Any]:
    """The newest readable checkpoint of a run; falls back to older ones when the newest is corrupt (with
    a warning). ``set_aside``: rename the unreadable ones skipped to ``NAME.unreadable`` (a resumed run
    writes those steps again, and must not count them as checkpoints when it prunes old ones)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise CheckpointError(f"run folder not found: {run_dir}")
    candidates = list_checkpoints(run_dir)
    if not candidates:
        raise CheckpointError(f"{run_dir} holds no checkpoint (expected {CHECKPOINT_DIR}/{CHECKPOINT_GLOB})")
    problems, skipped = [], []
    for path in reversed(candidates):
        try:
            state = torch.load(path, map_location=map_location, weights_only=False, pickle_module=_TolerantPickle)
            if not isinstance(state, dict) or "model" not in state or "step" not in state:
                raise ValueError("not a va-plugin checkpoint")
        except Exception as exc:  # a corrupt file can raise nearly anything while unpickling
            detail = str(exc).strip().splitlines()[0][:80] if str(exc).strip() else ""
            problems.append(f"{path.name} ({type(exc).__name__}{': ' + detail if detail else ''})")
            skipped.append(path)
            continue
        if problems:
            aside = ""
            if set_aside and _set_aside(skipped):
                aside = f" (renamed to *{UNREADABLE_SUFFIX})"
            warnings.warn(f"skipped unreadable checkpoint(s): {'; '.join(problems)}{aside}; using {path.name}",
                          stacklevel=2)
        state["path"] = str(path)
        return state
    raise CheckpointError(f"no readable checkpoint in {run_dir} (corrupt, truncated, or not written by va-train): "
                          f"{'; '.join(problems)}")


def _set_aside(paths: list[Path]) -> bool:
    """Rename ``paths`` to ``NAME.unreadable``; False when one could not be renamed."""
    done = True
    for path in paths:
        try:
            path.replace(path.with_name(path.name + UNREADABLE_SUFFIX))
        except OSError:
            done = False
    return done


class TrainingInterrupted(KeyboardInterrupt):
    """Training stopped by Ctrl-C, SIGTERM or a stop request (:meth:`Trainer.request_stop`, ``stop``).

    ``saved``: the stop came at the end of step ``step``, where ``checkpoint`` was written: the run
    continues exactly from there. Not ``saved``: a second signal (or an interrupt raised inside a step)
    left step ``step + 1`` unfinished, and nothing was written; ``checkpoint`` is the newest one on disk
    (None: none yet), which the run continues from. ``cause``: the signal's name, or "request"."""

    def __init__(self, step: int, checkpoint: Path | None, saved: bool = True, cause: str = "") -> None:
        if saved:
            text = f"interrupted at step {step}; saved {checkpoint}"
        else:
            older = f"the newest checkpoint is {checkpoint}" if checkpoint is not None else "no checkpoint yet"
            text = f"interrupted during step {step + 1}, which was left unfinished ({older})"
        super().__init__(text)
        self.step, self.checkpoint, self.saved, self.cause = step, checkpoint, saved, cause


class Trainer:
    """Runs the training loop of a :class:`TrainerConfig`."""

    def __init__(self, config: TrainerConfig) -> None:
        self.config = config
        validate_config(config)
        if config.num_threads > 0:
            torch.set_num_threads(config.num_threads)
        self.device = pick_device(config.device)
        if self.device.type == "cpu":
            keep_freed_memory()  # no page faults for each step's temporaries; the same values
        seed_everything(config.seed)
        self.run_dir = Path(config.output_dir)
        self.schedule_steps = schedule_steps_of(config)
        self.pipeline = config.pipeline.setup(device=self.device, schedule_steps=self.schedule_steps)
        self.model = self.pipeline.model
        self.optimizer = self._make_optimizer()
        averaged = round(config.average_fraction * config.max_steps)
        self.average = WeightAverage(list(self.model.parameters()), config.max_steps - averaged) if averaged else None
        self.lr_multipliers: dict[str, float] = dict.fromkeys(self.group_names, 1.0)
        self.callbacks: list[TrainingCallback] = list(self.model.training_callbacks())
        self.callback_attributes = TrainingCallbackAttributes(
            pipeline=self.pipeline, max_steps=config.max_steps, run_dir=self.run_dir, progress=config.progress,
            announce=self.announce, schedule_steps=self.schedule_steps)
        self.step = 0
        self.train_seconds = 0.0
        self.guard = TrainingGuard(config.health, inv_s_start=self.model.diagnostics().get("inv_s"),
                                   grace_steps=config.scheduler.warmup_steps)
        self._stop_requested = threading.Event()
        self._signalled: int | None = None  # the signal (SIGINT, SIGTERM) the loop is asked to stop for
        self._mid_step = False  # True while a step runs: its state is not whole
        self._saved_step: int | None = None  # the step of the last checkpoint written or loaded
        try:
            self._signal_plan = signal_plan(os.environ.get(SIGNALS_ENV))
        except ValueError as exc:
            raise ConfigError(str(exc)) from None

    def request_stop(self) -> None:
        """Ask the training loop (from any thread) to stop at the end of the step it is in: it writes a
        checkpoint and raises :class:`TrainingInterrupted`, as Ctrl-C does."""
        self._stop_requested.set()

    @property
    def bad_steps(self) -> int:
        """Steps skipped or rolled back so far (non-finite values, blow-ups)."""
        return self.guard.bad_steps

    # -- setup ----------------------------------------------------------------------------------
    def _make_optimizer(self) -> torch.optim.Optimizer:
        groups = self.model.get_param_groups()
        missing = sorted(set(groups) - set(self.config.optimizers))
        if missing:
            raise ConfigError(f"no optimizer configured for parameter group(s) {missing}; "
                              f"configured: {sorted(self.config.optimizers)}")
        self.group_names = [name for name in groups if groups[name]]
        param_groups = []
        for name in self.group_names:
            opt = self.config.optimizers[name]
            param_groups.append({"params": groups[name], "lr": opt.lr, "eps": opt.eps,
                                 "weight_decay": opt.weight_decay, "name": name})
        return make_adam(param_groups)

    def _set_learning_rates(self, step: int) -> None:
        factor = self.config.scheduler.factor(step, self.schedule_steps)
        for group in self.optimizer.param_groups:
            base = self.config.optimizers[group["name"]].lr
            group["lr"] = base * factor * self.lr_multipliers.get(group["name"], 1.0) * self.guard.lr_scale

    # -- checkpoints ----------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {
            "method_name": self.config.method_name,
            "step": self.step,
            "train_seconds": self.train_seconds,
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "lr_multipliers": dict(self.lr_multipliers),
            **({"average": self.average.state_dict()} if self.average is not None else {}),
            "health": self.guard.state_dict(step=self.step),
            "datamanager": self.pipeline.datamanager.state_dict(),
            "rng": {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate(),
                    "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None},
            "config": to_dict(self.config),
            "config_object": self.config,
        }

    def save_checkpoint(self) -> Path:
        """Write ``checkpoints/step-N.ckpt`` and drop those beyond ``keep_checkpoints``. On a full disk the
        old ones that go anyway make room for one more try; a write that fails raises
        :class:`~va_plugin.errors.OutputError`, and the earlier checkpoints stay as they were."""
        path = self.run_dir / CHECKPOINT_DIR / f"step-{self.step:07d}.ckpt"
        keep = max(1, self.config.keep_checkpoints)
        state = self.state_dict()
        try:  # a signal during the write waits for its end; once the run is stopping, a second one is moot
            with signals_held(hand_on=self._signalled is None):
                try:
                    atomic_save(state, path)
                except OSError as exc:
                    if exc.errno not in DISK_FULL or not self._drop_old_checkpoints(max(1, keep - 1), but=path):
                        raise
                    atomic_save(state, path)
        except OSError as exc:
            raise self._write_error(exc, path) from None
        self._saved_step = self.step
        self._drop_old_checkpoints(keep)
        for stale in path.parent.glob(CHECKPOINT_GLOB + ".tmp"):  # left by a run killed mid-write
            stale.unlink(missing_ok=True)
        return path

    def _drop_old_checkpoints(self, keep: int, but: Path | None = None) -> bool:
        """Delete all but the ``keep`` newest checkpoints (never ``but``); whether one was deleted."""
        old = [p for p in list_checkpoints(self.run_dir) if p != but][:-keep]
        for path in old:
            path.unlink(missing_ok=True)
        return bool(old)

    def _write_error(self, exc: OSError, path: Path | None = None) -> OutputError:
        """The one-line error of a failed write during training: what failed, and what is kept."""
        try:
            kept = list_checkpoints(self.run_dir)
        except OSError:
            kept = []
        newest = (f"the newest checkpoint, {kept[-1]} (step {checkpoint_step(kept[-1])}), is kept" if kept
                  else "no checkpoint was written yet")
        return output_error(exc, path, f", then continue with --resume; training stopped at step {self.step}, "
                                       f"{newest}")

    def load_state(self, state: dict[str, Any]) -> None:
        if state.get("method_name") != self.config.method_name:
            raise CheckpointError(f"checkpoint {state.get('path')} is of method {state.get('method_name')!r}, "
                                  f"not {self.config.method_name!r}")
        try:
            self.model.load_state_dict(state["model"])
            self.optimizer.load_state_dict(state["optimizer"])
            _transpose_stale_moments(self.optimizer)
            if self.average is not None:
                self.average.load_state_dict(state.get("average", {}))
        except (RuntimeError, ValueError, KeyError) as exc:
            first = str(exc).strip().splitlines()[0]
            raise CheckpointError(f"checkpoint {state.get('path')} does not fit this config ({first})") from None
        self.step = int(state["step"])
        # the model's step schedules (e.g. the open grid levels) as they stood when the checkpoint was
        # written, at the last step run: a finished run reopened without a step renders as it did
        self.model.restore_step(max(self.step - 1, 0))
        self.train_seconds = float(state.get("train_seconds", 0.0))
        self.lr_multipliers.update(state.get("lr_multipliers", {}))
        self.guard.load_state_dict(state.get("health", {}), self.step, self.model, self.optimizer)
        self.pipeline.datamanager.load_state_dict(state["datamanager"])
        rng = state["rng"]
        torch.set_rng_state(rng["torch"])
        np.random.set_state(rng["numpy"])
        random.setstate(rng["python"])
        if rng.get("cuda") is not None and torch.cuda.is_available():
            torch.cuda.set_rng_state_all(rng["cuda"])

    def resume(self) -> bool:
        """Continue from the newest readable checkpoint of the run folder (unreadable newer ones are set
        aside, with a warning); False when there is none."""
        if not list_checkpoints(self.run_dir):
            return False
        self.load_state(load_checkpoint(self.run_dir, map_location=self.device, set_aside=True))
        self._saved_step = self.step
        try:
            self._truncate_log()
        except OSError as exc:
            raise self._write_error(exc) from None
        return True

    def _truncate_log(self) -> None:
        """Drop the log lines of steps after the resumed checkpoint, so the log reads as one run."""
        if not (self.run_dir / METRICS_FILE).is_file():
            return
        kept = []
        for entry in read_records(self.run_dir):
            try:
                step = int(entry.get("step", 0))
            except (ValueError, TypeError):
                continue
            # events are logged before their step runs (step = steps done), records after it
            if step < self.step or (step == self.step and "event" not in entry):
                kept.append(entry)
        write_records(self.run_dir, kept)

    # -- logging --------------------------------------------------------------------------------
    def log(self, record: dict[str, Any]) -> None:
        """Append one record to the run's metrics.jsonl."""
        append_record(self.run_dir, record)

    def announce(self, step: int, message: str, **fields: Any) -> None:
        """An event of the run: a console line (when the run shows progress) and a metrics.jsonl record."""
        if self.config.progress:
            tqdm.write(f"[{self.config.method_name}] step {step}: {message}")
        self.log({"step": step, "event": message, **fields})

    def _write_config(self) -> None:
        write_atomic(self.run_dir / "config.json", json.dumps(to_dict(self.config), indent=2))

    # -- the loop -------------------------------------------------------------------------------
    @timed("callbacks")
    def _run_callbacks(self, where: str) -> None:
        for callback in self.callbacks:
            if callback.where == where:
                factors = callback(self.step, self.callback_attributes)
                if factors:
                    self.lr_multipliers.update(factors)

    def _send_planned_signal(self, where: str) -> None:
        """The test hook (:data:`SIGNALS_ENV`): the signal planned for this point of this step, sent to
        this process."""
        signum = self._signal_plan.get((self.step + 1, where))
        if signum is not None:
            os.kill(os.getpid(), signum)

    def _step(self) -> dict[str, float]:
        self._set_learning_rates(self.step)
        self.optimizer.zero_grad(set_to_none=True)
        loss_dict, metrics = self.pipeline.train_step(self.step)
        loss = sum(loss_dict.values())
        params = [p for group in self.optimizer.param_groups for p in group["params"]]
        guard = self.guard
        verdict = guard.check_loss(loss, loss_dict)
        if verdict == OK:
            guard.maybe_snapshot(self.step, self.model, self.optimizer)  # these parameters gave a sane loss
            with stage("backward"):
                loss.backward()
            if self._signal_plan:
                self._send_planned_signal("mid")
            verdict = guard.check_gradients(params)
        if verdict == OK:
            with stage("optimizer"):
                self.optimizer.step()
            verdict = guard.check_parameters(params, self.model.sharpness())
        if verdict == OK:
            guard.accept(loss_dict)
        else:
            self.optimizer.zero_grad(set_to_none=True)
            if verdict == SKIP:
                guard.warn_once("skip", f"step {self.step + 1}: {guard.reason}; the step was skipped (further "
                                        "skips are counted in metrics.jsonl as bad_steps)")
            else:
                guard.restore(self.step + 1, self.model, self.optimizer)
        finite = bool(torch.isfinite(loss))
        record = {"loss": float(loss.detach()) if finite else float("nan")}
        record.update({f"loss_{k}": float(v.detach()) for k, v in loss_dict.items()})
        record.update(metrics)
        return record

    def _average(self, done: int) -> None:
        """After the optimizer step that makes ``done`` steps: the weights join their running mean, which
        replaces them after the last step (before the after-step callbacks, so that the pictures written
        there show the weights the run ends with)."""
        if self.average is not None:
            self.average.after_step(done, self.config.max_steps, self.model)

    def run_step(self) -> tuple[dict[str, Any], float]:
        """One training step with its callbacks (no logging, evaluation or checkpoint): its record and
        its wall seconds, which are added to ``train_seconds``."""
        start = time.perf_counter()
        if self._signal_plan:
            self._send_planned_signal("start")
        # values below 1e-38 count as zero during the step: off the processor's slow path (same results)
        with denormals_flushed(self.device.type == "cpu"):
            self._run_callbacks(BEFORE_STEP)
            record = self._step()
            self._average(self.step + 1)
            self._run_callbacks(AFTER_STEP)
        if self._signal_plan:
            self._send_planned_signal("end")
        elapsed = time.perf_counter() - start
        self.train_seconds += elapsed
        self.step += 1
        return record, elapsed

    def train(self, on_step: Callable[[int, int, dict[str, float]], None] | None = None,
              stop: threading.Event | Callable[[], bool] | None = None) -> dict[str, Any]:
        """Train to ``max_steps`` (from the current step); returns the final log record. ``on_step(step,
        max_steps, losses)`` is called after every step.

        Stopping: SIGINT (Ctrl-C) or SIGTERM, :meth:`request_stop`, or ``stop`` (an Event set, or a callable
        returning True; polled between steps) let the step in progress finish, then write a checkpoint and
        raise :class:`TrainingInterrupted`; the run resumed from it trains on exactly as it would have. A
        second signal aborts the step at once (nothing written: the run resumes from the newest
        checkpoint). A write that fails (full disk, read-only folder) raises
        :class:`~va_plugin.errors.OutputError`; the checkpoints written before stay."""
        cfg = self.config
        poll = stop.is_set if isinstance(stop, threading.Event) else stop
        bar = None
        try:
            self._write_config()
            if self.step == 0:
                self.pipeline.datamanager.save_mask_picture(self.run_dir)
            bar = progress_bar(total=cfg.max_steps, initial=self.step, disable=not cfg.progress,
                               dynamic_ncols=True, desc=cfg.method_name, leave=True)
            with signals_as_requests(self._on_signal):
                return self._train_steps(bar, on_step, poll)
        except TrainingInterrupted:
            raise
        except KeyboardInterrupt:
            raise self._aborted() from None
        except VAError:
            raise
        except OSError as exc:
            if exc.errno not in DISK_FULL | NOT_WRITABLE:
                raise
            raise self._write_error(exc) from None
        finally:
            self._mid_step = False
            self._signalled = None
            if bar is not None:
                bar.close()

    def _train_steps(self, bar, on_step, poll: Callable[[], bool] | None) -> dict[str, Any]:
        cfg = self.config
        record: dict[str, Any] = {}
        recent: list[float] = []
        while self.step < cfg.max_steps:
            self._stop_if_asked(poll)
            self._mid_step = True
            record, elapsed = self.run_step()
            recent = (recent + [elapsed])[-20:]
            record.update(self.model.diagnostics())
            record.update({"step": self.step, "train_seconds": round(self.train_seconds, 3),
                           "it_per_s": round(len(recent) / max(sum(recent), 1e-9), 3)})
            self.guard.observe(record)
            self._mid_step = False
            bar.update(1)
            if self.step % cfg.log_every == 0 or self.step == cfg.max_steps:
                self.log(record)
            bar.set_postfix({k: f"{record[k]:.4g}" for k in ("loss", "psnr", "inv_s") if k in record})
            if on_step is not None:
                on_step(self.step, cfg.max_steps, {k: v for k, v in record.items() if isinstance(v, float)})
            if cfg.eval_every > 0 and self.step % cfg.eval_every == 0 and self.step < cfg.max_steps:
                metrics, _ = self.pipeline.evaluate_views(cfg.eval_views)
                if metrics:
                    self.log({"step": self.step, **metrics})
            if self._scheduled_checkpoint():
                self._save_between_steps()
        self._stop_if_asked(poll)  # asked during the last step: the command stops all the same
        return record

    def _scheduled_checkpoint(self) -> bool:
        """Whether a checkpoint is due after the steps done (none before the first step)."""
        return self.step > 0 and (self.step % self.config.checkpoint_every == 0 or self.step == self.config.max_steps)

    def _save_between_steps(self) -> Path:
        """A checkpoint of the steps done, as the uninterrupted run has it here: at a scheduled one, the
        state becomes the guard's last good state first (see ``TrainingGuard.checkpointed``)."""
        if self._scheduled_checkpoint():
            self.guard.checkpointed(self.step, self.model, self.optimizer)
        return self.save_checkpoint()

    def _on_signal(self, signum: int) -> None:
        """SIGINT or SIGTERM during training (the handler of :func:`signals_as_requests`): stop at the
        step's end. Only a flag is set (the main thread may be anywhere, even in ``request_stop``)."""
        self._signalled = signum

    def _stop_if_asked(self, poll: Callable[[], bool] | None) -> None:
        """Between steps: when a signal, :meth:`request_stop` or ``poll()`` asks, write a checkpoint (unless
        this step's is written) and raise :class:`TrainingInterrupted`."""
        signalled = self._signalled
        if signalled is not None:
            cause = signal.Signals(signalled).name
        elif self._stop_requested.is_set() or (poll is not None and poll()):
            cause = "request"
        else:
            return
        path = self.run_dir / CHECKPOINT_DIR / f"step-{self.step:07d}.ckpt"
        if self._saved_step != self.step or not path.is_file():
            path = self._save_between_steps()
        self._stop_requested.clear()
        raise TrainingInterrupted(self.step, path, saved=True, cause=cause)

    def _aborted(self) -> TrainingInterrupted:
        """A KeyboardInterrupt raised in the loop: a second signal, or one raised by code (a callback, an
        ``on_step``). Between steps, when no signal came first, the state is whole and is saved; else
        nothing is written (a step cut short cannot be continued exactly) and the newest checkpoint is
        the one to resume from."""
        if not self._mid_step and self._signalled is None:
            return TrainingInterrupted(self.step, self._save_between_steps(), saved=True, cause="KeyboardInterrupt")
        try:
            newest = list_checkpoints(self.run_dir)
        except OSError:
            newest = []
        cause = signal.Signals(self._signalled).name if self._signalled is not None else "KeyboardInterrupt"
        return TrainingInterrupted(self.step, newest[-1] if newest else None, saved=False, cause=cause)


@dataclass
class TrainedRun:
    """What :func:`train_run` leaves: the trainer (with its pipeline), the last log record, and the step
    the run resumed from (None for a fresh run)."""

    trainer: Trainer
    record: dict[str, Any]
    resumed_from: int | None


def train_run(config: TrainerConfig, resume: bool = True, trainer: Trainer | None = None,
              on_resume: Callable[[int], None] | None = None,
              on_step: Callable[[int, int, dict[str, float]], None] | None = None,
              stop: threading.Event | Callable[[], bool] | None = None) -> TrainedRun:
    """Train a run folder to its budget: the one way every command and benchmark trains a run.

    With ``resume``, continue from the newest checkpoint in ``config.output_dir`` (calling
    ``on_resume(step)`` first). Ctrl-C, SIGTERM or ``stop`` (see :meth:`Trainer.train`) end the step in
    progress, write a checkpoint and raise :class:`TrainingInterrupted`; a model that renders nothing on
    the foreground raises :class:`~va_plugin.engine.health.UnusableModel`. ``trainer``: one already set up
    from ``config``; ``on_step``: see :meth:`Trainer.train`."""
    trainer = config.setup() if trainer is None else trainer
    resumed_from = trainer.step if resume and trainer.resume() else None
    if resumed_from is not None and on_resume is not None:
        on_resume(resumed_from)
    record = trainer.train(on_step, stop=stop)
    check_usable(trainer.pipeline, config.health, trainer.step)
    return TrainedRun(trainer, record, resumed_from)
