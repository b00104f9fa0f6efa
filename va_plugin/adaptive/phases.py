"""The three training phases of the paper's Sec. 3.4, switched by a trainer callback.

Phase 1 trains the shared field alone; phase 2 adds the per-view branches (the shared field at
``shared_lr_scale``); phase 3 the attention fusion. Boundaries are fractions of the step budget, so a
resumed run lands in the same phase. At the end of phase 1 the callback can ask the field's
``consistency_test`` (:func:`va_plugin.analysis.consistency.decide_skip` by default) whether the inputs
agree, and then keep the run in phase 1; after the last step ``diagnostics_writer`` writes the pictures.
Both are named by their config as ``module:function`` (the analysis sits floors above this module).
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Protocol

import torch

from va_plugin.callbacks import AFTER_STEP, BEFORE_STEP, TrainingCallback, TrainingCallbackAttributes
from va_plugin.config import resolve_reference

PRETRAIN, BRANCHES, FUSION = 1, 2, 3
PHASE_NAMES = {PRETRAIN: "global pre-training", BRANCHES: "view-adaptive branches", FUSION: "self-attention fusion"}


class PhaseOptions(Protocol):
    """The options of a phased field that its callbacks read (``ViewAdaptiveFieldConfig`` has them)."""

    pretrain_fraction: float
    branch_fraction: float
    shared_lr_scale: float
    skip_consistent_scenes: bool
    consistency_test: str
    diagnostics_writer: str
    diagnostics_scale: float


class PhasedField(Protocol):
    """What the phase callbacks read and set on a field (:class:`~va_plugin.adaptive.field.ViewAdaptiveField`
    is one; it builds its callbacks here, so this module does not import it)."""

    config: PhaseOptions
    branches: torch.nn.Module | None
    skipped: torch.Tensor  # bool [], persistent: the consistency test kept the run in phase 1

    @property
    def current_phase(self) -> int: ...

    def set_phase(self, phase: int) -> None: ...


def phase_at(step: int, schedule_steps: int, pretrain_fraction: float, branch_fraction: float) -> int:
    """Phase (1, 2 or 3) of 0-based ``step`` when the schedules end at ``schedule_steps``."""
    if step < round(pretrain_fraction * schedule_steps):
        return PRETRAIN
    if step < round((pretrain_fraction + branch_fraction) * schedule_steps):
        return BRANCHES
    return FUSION


def phase_callback(field: PhasedField) -> TrainingCallback:
    """The trainer callback that sets the field's phase; it returns the learning-rate factor of the
    shared field's optimizer groups (``shared_lr_scale`` once the branches train)."""
    cfg = field.config

    def switch(step: int, attributes: TrainingCallbackAttributes) -> dict[str, float]:
        wanted = phase_at(step, attributes.schedule_steps, cfg.pretrain_fraction, cfg.branch_fraction)
        if (field.branches is None or bool(field.skipped)
                or (wanted > PRETRAIN and field.current_phase == PRETRAIN and cfg.skip_consistent_scenes
                    and resolve_reference(cfg.consistency_test, "consistency_test")(field, attributes, step))):
            wanted = PRETRAIN
        if wanted != field.current_phase:
            field.set_phase(wanted)
            attributes.announce(step, f"phase {wanted}: {PHASE_NAMES[wanted]}", phase=wanted)
        factor = cfg.shared_lr_scale if wanted >= BRANCHES else 1.0
        return dict.fromkeys(SHARED_GROUPS, factor)  # the shared field and NeuS's inv_s

    return TrainingCallback(switch, BEFORE_STEP)


def diagnostics_callback(field: PhasedField) -> TrainingCallback:
    """After the last step, the attention heat map and the inconsistency maps go to the run folder."""

    def write(step: int, attributes: TrainingCallbackAttributes) -> None:
        if step + 1 != attributes.max_steps:
            return
        write_diagnostics = resolve_reference(field.config.diagnostics_writer, "diagnostics_writer")
        run_dir = attributes.run_dir
        try:
            written = write_diagnostics(attributes.pipeline, run_dir, field.config.diagnostics_scale,
                                        progress=attributes.progress)
        except Exception as exc:  # pictures must never cost the trained run (its checkpoint comes after)
            warnings.warn(f"the diagnostics pictures failed ({type(exc).__name__}: {exc}); the trained run is "
                          f"kept: retry with va-export diagnostics --load-dir {run_dir}", stacklevel=2)
            return
        if written:
            attributes.announce(step, "diagnostics written: " + ", ".join(Path(p).name for p in written))

    return TrainingCallback(write, AFTER_STEP)


SHARED_GROUPS = ("fields", "variance")
"""Optimizer groups of the shared model, slowed by ``shared_lr_scale`` once the branches train."""
