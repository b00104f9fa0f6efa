"""A training session in a claimed run folder, as the API runs it: the stage lines, the health warning, and
an interrupt after training turned into one that says the run is kept."""

from __future__ import annotations

import contextlib
import numbers
import threading
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from va_plugin.callbacks import TrainingCallback
from va_plugin.data.datamanager import MASK_PICTURE
from va_plugin.engine.options import QUALITIES
from va_plugin.engine.run_folder import claim_run_folder
from va_plugin.engine.trainer import TrainerConfig, TrainingInterrupted, checkpoint_step, list_checkpoints, train_run
from va_plugin.errors import ConfigError
from va_plugin.pipelines.base import Pipeline
from va_plugin.utils.arguments import check_hooks, check_kinds
from va_plugin.utils.memory import check_batch_memory
from va_plugin.utils.paths import user_path
from va_plugin.utils.threads import training_in_this_thread

Progress = Callable[[int, int, dict[str, float]], None]
"""``progress(step, total, losses)``: called after every training step."""
Stop = threading.Event | Callable[[], bool] | None
"""``stop``: training stops at the next step boundary once the Event is set or the callable returns True."""


def quiet(line: str) -> None:
    """The default ``on_message``: nothing is shown."""


def input_summary(pipeline: Pipeline, run_dir: Path) -> str | None:
    """One line about generator inputs (format, views, where the masks came from); None for scenes."""
    meta = pipeline.datamanager.train.metadata
    if "mask_source" not in meta:
        return None
    return (f"{meta['format']} input: {len(pipeline.datamanager.train)} training views, masks from the "
            f"{meta['mask_source']} (check {Path(run_dir) / MASK_PICTURE})")


def check_training_memory(config: TrainerConfig) -> None:
    """Refuse, before the views are read, a training batch that would not fit in memory (the views' own
    size is checked when they are loaded, before they are resized)."""
    check_batch_memory(config.pipeline.datamanager.rays_per_batch, config.pipeline.model.samples_per_ray())


@contextlib.contextmanager
def claimed_for_training(config: TrainerConfig, call: str, resume: bool, overwrite: bool,
                         **claim: Any) -> Iterator[bool]:
    """Refuse a batch too large for memory, then hold ``config``'s run folder for ``call`` (training in this
    thread, see :func:`~va_plugin.utils.threads.training_in_this_thread`) for the block; yields whether the
    run continues from a checkpoint (``claim``: more of :func:`claim_run_folder`'s options)."""
    check_training_memory(config)
    with training_in_this_thread(call), \
            claim_run_folder(config, resume=resume, overwrite=overwrite, preset=config.preset_name, **claim) as go_on:
        yield go_on


def train_in_folder(config: TrainerConfig, progress: Progress | None, on_message: Callable[[str], None] | None,
                    before_training: Callable[[Any], None] | None = None, header: str | None = None,
                    stop: Stop = None, callbacks: Iterable[TrainingCallback] = (),
                    resume: bool = False) -> int | None:
    """The API's training in a claimed run folder; the step the run resumed from (None for a fresh run).
    ``header``: a line said once the data has loaded (bad input stays one line: the error alone).
    ``resume``: continue from the folder's checkpoints (what :func:`claim_run_folder` allowed)."""
    run_dir = Path(config.output_dir)
    say = on_message or quiet
    trainer = config.setup()
    trainer.callbacks.extend(callbacks)
    for line in (header, input_summary(trainer.pipeline, run_dir)):
        if line:
            say(line)
    if before_training is not None:
        before_training(trainer)
    done = train_run(config, resume=resume, trainer=trainer, on_step=progress, stop=stop,
                     on_resume=lambda step: say(f"resuming {config.method_name} from step {step}"))
    health = done.trainer.guard.summary()
    if health:
        warnings.warn(health, stacklevel=3)
    return done.resumed_from


def resolve_config_paths(config: TrainerConfig) -> None:
    """The run folder and the input paths of ``config`` (one built by hand, say) made absolute, ``~``
    expanded, in place: every step of the run then reads and writes the same places."""
    config.output_dir = user_path(config.output_dir, "output_dir")
    parser = config.pipeline.datamanager.dataparser
    for name, path in parser.input_paths().items():
        if path is not None:
            setattr(parser, name, user_path(path, name))


class InterruptedAfterTraining(TrainingInterrupted):
    """Ctrl-C or SIGTERM after training ended (during the mesh, the texture, the turntable or the scores):
    the trained run is whole in its last checkpoint, and the same call with ``resume=True`` skips the
    training and does the rest."""

    def __init__(self, step: int, checkpoint: Path | None) -> None:
        super().__init__(step, checkpoint, saved=True, cause="after training")
        self.args = (f"interrupted after training (the run is kept: step {step}, {checkpoint})",)


@contextlib.contextmanager
def interrupt_after_training(run_dir: Path) -> Iterator[None]:
    """Turn an interrupt of the block (the work after training) into :class:`InterruptedAfterTraining`."""
    try:
        yield
    except TrainingInterrupted:
        raise
    except KeyboardInterrupt:
        kept = list_checkpoints(run_dir)
        raise InterruptedAfterTraining(checkpoint_step(kept[-1]) if kept else 0, kept[-1] if kept else None) from None


def check_reconstruct_options(given: Mapping[str, Any]) -> None:
    """Refuse, before any work, an argument of :func:`~va_plugin.api.reconstruct` of the wrong kind or value
    (``given``: its arguments by name, ``source`` the input's path; the export options are its
    ExportConfig's to check)."""
    check_kinds(**{name: (given[name], kinds) for name, kinds in (
        ("method", str), ("quality", str), ("data_format", str), ("resume", bool), ("overwrite", bool),
        ("show_progress", bool), ("turntable_frames", numbers.Integral), ("threads", numbers.Integral),
        ("callbacks", Iterable))})
    check_kinds(optional=True, **{name: (given[name], kinds) for name, kinds in (
        ("evaluate_options", Mapping), ("steps", numbers.Integral))})
    check_hooks(given["progress"], given["stop"], given["on_message"])
    if given["quality"] not in QUALITIES:
        raise ConfigError(f"quality {given['quality']!r} is not one of {', '.join(QUALITIES)}")
    if not given["source"].exists():
        raise ConfigError(f"input not found: {given['source']}")
    if given["turntable_frames"] < 0:
        raise ConfigError(f"--turntable-frames must be 0 or more, got {given['turntable_frames']}")
