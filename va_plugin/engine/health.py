"""Keeping a training run alive: bad steps are skipped, blow-ups rolled back, divergence reported.

The trainer asks a :class:`TrainingGuard` about every step:

* a non-finite loss or gradient: the step is skipped;
* a loss term far above its running level, non-finite parameters after an update, too many skips in
  a row, or inv_s (NeuS's sharpness) collapsed below ``inv_s_collapse`` of its peak or saturated at
  ``inv_s_saturation``: the last good state (kept every ``snapshot_every`` steps, and only while inv_s
  holds ``snapshot_inv_s_fraction`` of its peak) is restored and the learning rates lowered;
* inv_s below its start value after the warm-up: a divergence warning.

Each kind of event warns once; the counts go to ``metrics.jsonl``. A run that still blows up after
``max_restores`` restores stops with :class:`TrainingDiverged`. The guard only reads the loss, so
healthy runs are unchanged.
"""

from __future__ import annotations

import copy
import math
import warnings
from dataclasses import dataclass
from typing import Any

import torch

from va_plugin.config import Checked
from va_plugin.errors import ConfigError, VAError
from va_plugin.rays import RayBundle
from va_plugin.utils.stages import timed

OK, SKIP, RESTORE = "ok", "skip", "restore"
SNAPSHOT_IS_CHECKPOINT = "the checkpoint's own state"
"""A checkpoint's ``health.snapshot`` when the last good state is the state the checkpoint holds."""


class TrainingDiverged(VAError):
    """Training kept blowing up although the guard lowered the learning rate."""


class UnusableModel(VAError):
    """Training finished, but the model does not render the object the masks show."""


@dataclass
class HealthConfig(Checked):
    """When a step counts as bad, and what the trainer does about it."""

    spike_factor: float = 20.0
    """A loss term above ``spike_factor`` times its running level (and above ``spike_floor``) is a
    blow-up (0: no blow-up test)."""
    spike_floor: float = 2.0
    """Losses below this never count as a blow-up."""
    snapshot_every: int = 10
    """Steps between in-memory copies of the last good state."""
    lr_backoff: float = 0.5
    """Factor applied to every learning rate at each restore."""
    max_skips_in_a_row: int = 5
    """Consecutive skipped (non-finite) steps after which the last good state is restored."""
    max_restores: int = 20
    """Restores after which training stops with a clear error."""
    inv_s_tolerance: float = 0.5
    """inv_s counts as below its start when it falls more than this fraction under it."""
    inv_s_collapse: float = 0.05
    """inv_s below this fraction of its peak is a collapse, rolled back like a blow-up (0: never)."""
    snapshot_inv_s_fraction: float = 0.5
    """The last good state is refreshed only while inv_s is at least this fraction of its peak (0:
    always), so a collapse rolls back to before the fall."""
    inv_s_saturation: float = 1e5
    """inv_s at or above this is saturated, rolled back like a blow-up (0: never)."""
    min_foreground_opacity: float = 0.2
    """Mean foreground opacity a trained model must reach, else :class:`UnusableModel` (0: no check)."""
    final_check_after: int = 100
    """Runs shorter than this many steps skip that check."""

    def validate(self, prefix: str = "") -> None:
        if not (0.0 < self.lr_backoff < 1.0):
            raise ConfigError(f"health.lr_backoff must be in (0, 1), got {self.lr_backoff}")
        if self.snapshot_every < 1 or self.max_skips_in_a_row < 1 or self.max_restores < 0:
            raise ConfigError("health.snapshot_every and health.max_skips_in_a_row must be at least 1, "
                              "health.max_restores at least 0")
        if self.spike_factor < 0 or self.spike_floor < 0 or self.inv_s_tolerance < 0 or self.inv_s_collapse < 0 \
                or self.inv_s_saturation < 0 or not 0 <= self.snapshot_inv_s_fraction < 1:
            raise ConfigError("health.spike_factor, health.spike_floor, health.inv_s_tolerance, "
                              "health.inv_s_collapse and health.inv_s_saturation must be >= 0, "
                              "health.snapshot_inv_s_fraction in [0, 1)")


def all_finite(tensors) -> bool:
    """True when no tensor (None entries skipped) holds a NaN or an infinity.

    Judged from each tensor's ``aminmax`` (NaN and inf reach the extremes): one reduction pass per tensor,
    then one test of all the extremes together (a single read back, a few operators per step)."""
    extremes = [torch.stack(torch.aminmax(t.detach()))
                for t in tensors if t is not None and t.numel() > 0]
    return not extremes or bool(torch.isfinite(torch.cat(extremes)).all())


class TrainingGuard:
    """The health state of one run; see the module docstring. Its state goes into checkpoints."""

    def __init__(self, config: HealthConfig, inv_s_start: float | None = None, grace_steps: int = 0) -> None:
        """``grace_steps``: steps (the warm-up) during which a fall of inv_s is not reported."""
        config.validate()
        self.grace_steps = max(int(grace_steps), 0)
        self.config = config
        self.levels: dict[str, float] = {}  # running level of |term| over accepted steps, per loss term
        self.lr_scale = 1.0
        self.bad_steps = 0
        self.restores = 0
        self.skips_in_a_row = 0
        self.inv_s_start = inv_s_start
        self.inv_s_peak = inv_s_start  # the highest inv_s of an accepted update (the start value before the first)
        self.inv_s_now = inv_s_start
        self.inv_s_below_start = False
        self._warned: set = set()
        self._snapshot: dict[str, Any] | None = None
        self.reason = ""  # what was wrong with the last bad step

    # -- the verdict on a step ------------------------------------------------------------------------
    @timed("health")
    def check_loss(self, loss: torch.Tensor, terms: dict[str, torch.Tensor]) -> str:
        """OK, SKIP (non-finite) or RESTORE (blow-up) for a step's loss and its terms, before backward.
        Each term is judged against its own running level; a new term sets its level."""
        if not math.isfinite(float(loss.detach())):
            return self._bad("non-finite loss")
        cfg = self.config
        if cfg.spike_factor <= 0:
            return OK
        for name, term in terms.items():
            value, level = abs(float(term.detach())), self.levels.get(name)
            if level is not None and value > max(cfg.spike_factor * level, cfg.spike_floor):
                self.bad_steps += 1
                self.reason = f"the {name} loss blew up to {value:.3g} (its running level: {level:.3g})"
                return RESTORE
        return OK

    @timed("health")
    def check_gradients(self, parameters) -> str:
        """OK or SKIP for the gradients of the step's parameters."""
        if all_finite(p.grad for p in parameters):
            return OK
        return self._bad("non-finite gradient")

    @timed("health")
    def check_parameters(self, parameters, inv_s: float | None = None) -> str:
        """OK or RESTORE after the optimizer update (non-finite parameters, or ``inv_s`` collapsed or saturated)."""
        if not all_finite(p.detach() for p in parameters):
            self.bad_steps += 1
            self.reason = "parameters turned non-finite after the update"
            return RESTORE
        if inv_s is None:
            return OK
        floor = self.config.inv_s_collapse * (self.inv_s_peak or 0.0)
        if floor > 0 and not inv_s >= floor:  # a NaN inv_s counts too
            self.bad_steps += 1
            self.reason = (f"inv_s collapsed to {inv_s:.3g} (it started at {self.inv_s_start:.3g} and reached "
                           f"{self.inv_s_peak:.3g}): the surface dissolved")
            return RESTORE
        ceiling = self.config.inv_s_saturation
        if ceiling > 0 and inv_s >= ceiling:
            self.bad_steps += 1
            self.reason = f"inv_s shot up to {inv_s:.3g} (it started at {self.inv_s_start:.3g}): the surface froze"
            return RESTORE
        self.inv_s_now = inv_s
        self.inv_s_peak = inv_s if self.inv_s_peak is None else max(self.inv_s_peak, inv_s)
        return OK

    def _bad(self, what: str) -> str:
        self.bad_steps += 1
        self.skips_in_a_row += 1
        self.reason = what
        if self.skips_in_a_row >= self.config.max_skips_in_a_row:
            self.reason = f"{what}, {self.skips_in_a_row} steps in a row"
            return RESTORE
        return SKIP

    @timed("health")
    def accept(self, terms: dict[str, torch.Tensor]) -> None:
        """A step whose update was applied: its loss terms feed their running levels."""
        for name, term in terms.items():
            value, level = abs(float(term.detach())), self.levels.get(name)
            self.levels[name] = value if level is None else 0.9 * level + 0.1 * value
        self.skips_in_a_row = 0

    # -- last good state ------------------------------------------------------------------------------
    @timed("health")
    def maybe_snapshot(self, step: int, model: torch.nn.Module, optimizer: torch.optim.Optimizer,
                       force: bool = False) -> None:
        """Keep a copy of the parameters and optimizer state every ``snapshot_every`` steps, unless inv_s
        has fallen (:meth:`_fallen`). Buffers (schedules, occupancy grids) are not rewound."""
        if force or self._snapshot is None or (step % self.config.snapshot_every == 0 and not self._fallen()):
            self._snapshot = {"step": step,
                              "parameters": {k: v.detach().clone() for k, v in model.named_parameters()},
                              "optimizer": copy.deepcopy(optimizer.state_dict())}

    def checkpointed(self, step: int, model: torch.nn.Module, optimizer: torch.optim.Optimizer) -> None:
        """A scheduled checkpoint of the state after ``step`` steps is being written: unless inv_s has
        fallen, that state becomes the last good one, and the checkpoint needs no second copy of it."""
        if not self._fallen():
            self.maybe_snapshot(step, model, optimizer, force=True)

    def _fallen(self) -> bool:
        """inv_s now below ``snapshot_inv_s_fraction`` of its peak."""
        return (self.inv_s_now is not None and self.inv_s_peak is not None
                and self.inv_s_now < self.config.snapshot_inv_s_fraction * self.inv_s_peak)

    def restore(self, step: int, model: torch.nn.Module, optimizer: torch.optim.Optimizer) -> None:
        """Go back to the last good state and lower the learning rates (or give up)."""
        self.restores += 1
        self.skips_in_a_row = 0
        if self._snapshot is None or self.restores > self.config.max_restores:
            raise TrainingDiverged(
                f"training diverged at step {step} ({self.reason}) and kept diverging after {self.restores - 1} "
                f"restores with the learning rate lowered to {self.lr_scale:.3g} of its value; lower the "
                "learning rate (e.g. --set optimizers.fields.lr=...) or check the inputs")
        with torch.no_grad():
            for name, value in model.named_parameters():
                value.copy_(self._snapshot["parameters"][name])
        optimizer.load_state_dict(copy.deepcopy(self._snapshot["optimizer"]))
        self.lr_scale *= self.config.lr_backoff
        self.warn_once("restore", f"step {step}: {self.reason}; restored the state after step {self._snapshot['step']} "
                                  f"and lowered the learning rate to {self.lr_scale:.3g} of its value (further "
                                  "restores are counted in metrics.jsonl as restores)")

    # -- divergence signs and reporting -----------------------------------------------------------
    def observe(self, record: dict[str, Any]) -> None:
        """Add the health fields to a log record; warn once when inv_s falls below its start."""
        inv_s = record.get("inv_s")
        if inv_s is not None and self.inv_s_start is not None:
            past_grace = int(record.get("step", self.grace_steps)) >= self.grace_steps
            below = past_grace and inv_s < self.inv_s_start * (1.0 - self.config.inv_s_tolerance)
            if below and not self.inv_s_below_start:
                self.warn_once("inv_s", f"step {record.get('step')}: inv_s fell to {inv_s:.4g}, below its start "
                                        f"value {self.inv_s_start:.4g}: the run is diverging (the learning rate "
                                        "may be too high)")
            self.inv_s_below_start = below
            record["inv_s_below_start"] = below
        record.update({"bad_steps": self.bad_steps, "restores": self.restores, "lr_scale": self.lr_scale})

    def warn_once(self, kind: str, message: str) -> None:
        if kind not in self._warned:
            self._warned.add(kind)
            warnings.warn(message, stacklevel=3)

    def summary(self) -> str | None:
        """One line on what went wrong during the run, or None for a clean run."""
        parts = []
        if self.bad_steps:
            parts.append(f"{self.bad_steps} bad step(s) skipped or rolled back")
        if self.restores:
            parts.append(f"{self.restores} restore(s), learning rate now {self.lr_scale:.3g} of its value")
        if self.inv_s_below_start:
            parts.append(f"inv_s ended below its start value {self.inv_s_start:.4g} (diverging: the mesh is "
                         "likely poor)")
        elif self._fallen():
            parts.append(f"inv_s ended at {self.inv_s_now:.4g}, {self.inv_s_now / self.inv_s_peak:.2f} of its peak "
                         f"{self.inv_s_peak:.4g} (the surface thinned out: check the mesh)")
        return "; ".join(parts) if parts else None

    def state_dict(self, step: int | None = None) -> dict[str, Any]:
        """The guard's state. With ``step`` (a checkpoint's), the last good state too, so a resumed run
        rolls back to where the uninterrupted one would: :data:`SNAPSHOT_IS_CHECKPOINT` when it is the
        state after ``step`` (see :meth:`checkpointed`), else a copy."""
        state = {"levels": dict(self.levels), "lr_scale": self.lr_scale, "bad_steps": self.bad_steps,
                 "restores": self.restores, "skips_in_a_row": self.skips_in_a_row, "inv_s_start": self.inv_s_start,
                 "inv_s_below_start": self.inv_s_below_start, "inv_s_peak": self.inv_s_peak,
                 "inv_s_now": self.inv_s_now, "warned": sorted(self._warned)}
        if step is not None:
            snapshot = self._snapshot
            state["snapshot"] = SNAPSHOT_IS_CHECKPOINT if snapshot is not None and snapshot["step"] == step \
                else snapshot
        return state

    def load_state_dict(self, state: dict[str, Any], step: int = 0, model: torch.nn.Module | None = None,
                        optimizer: torch.optim.Optimizer | None = None) -> None:
        """Load :meth:`state_dict`; ``step``, ``model`` and ``optimizer``: the checkpoint's step and the
        model and optimizer already loaded from it (the last good state, when it is theirs)."""
        self.levels = dict(state.get("levels", {}))
        self.lr_scale = float(state.get("lr_scale", 1.0))
        self.bad_steps = int(state.get("bad_steps", 0))
        self.restores = int(state.get("restores", 0))
        self.skips_in_a_row = int(state.get("skips_in_a_row", 0))
        self.inv_s_start = state.get("inv_s_start", self.inv_s_start)
        self.inv_s_below_start = bool(state.get("inv_s_below_start", False))
        self.inv_s_peak = state.get("inv_s_peak", self.inv_s_start)
        self.inv_s_now = state.get("inv_s_now", self.inv_s_start)
        self._warned = set(state.get("warned", []))
        snapshot = state.get("snapshot")  # None in a checkpoint of an earlier version: taken afresh
        self._snapshot = None if isinstance(snapshot, str) else snapshot
        if isinstance(snapshot, str) and snapshot == SNAPSHOT_IS_CHECKPOINT and model is not None:
            self.maybe_snapshot(step, model, optimizer, force=True)


@torch.no_grad()
def foreground_opacity(pipeline, max_rays: int = 1024) -> float | None:
    """Mean opacity the model renders (canonical path) on up to ``max_rays`` of the training views'
    foreground pixels, evenly spread over them; None when the input has no masks."""

    datamanager = pipeline.datamanager
    foreground = datamanager._foreground_pixels()
    if foreground is None:
        return None
    pick = torch.linspace(0, foreground.numel() - 1, min(max_rays, foreground.numel())).round().long()
    flat = foreground[pick].to(datamanager.device)
    height, width = datamanager.images.shape[1:3]
    views, within = flat // (height * width), flat % (height * width)
    origins, directions = datamanager.cameras.generate_rays(views, within // width, within % width)
    rays = RayBundle(origins, directions, torch.full_like(views, -1))
    opacity = pipeline.model.render_rays(rays, keys=("accumulation",))["accumulation"]
    return float(opacity.float().mean())


def check_usable(pipeline, config: HealthConfig, steps: int) -> float | None:
    """Raise :class:`UnusableModel` when a run of at least ``config.final_check_after`` steps renders less
    than ``config.min_foreground_opacity`` on the foreground; the opacity measured (None: not checked)."""
    if config.min_foreground_opacity <= 0 or steps < config.final_check_after:
        return None
    opacity = foreground_opacity(pipeline)
    if opacity is not None and not opacity >= config.min_foreground_opacity:
        raise UnusableModel(
            f"the trained model renders almost nothing where the masks show the object (mean opacity "
            f"{opacity:.2f} on the foreground, below {config.min_foreground_opacity}): the run failed; "
            "check the masks, or lower the learning rates (--set optimizers.fields.lr=...) and train again")
    return opacity
