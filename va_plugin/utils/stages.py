"""Wall time per named stage of a training step (the speed benchmark's breakdown, issue 9).

Code marks its stages with ``with stage("sampling"): ...`` or the ``@timed("sampling")`` decorator, and
:func:`time_modules` can time every call of chosen submodules (encodings, MLP layers) through forward
hooks. Nothing is recorded unless a :func:`recording` is open: a marker then costs one global lookup.

Times are *exclusive*: a stage opened inside another is subtracted from the outer one (an encoding
evaluated during sampling counts as encoding, not as sampling), so the stages of a step add up to at
most the step's wall time. Inclusive times (a stage with everything nested in it) are kept as well.
With ``synchronize=True`` (CUDA) the device is synchronized at every stage boundary, so that a stage is
charged for the kernels it launched; this slows the step a little, so time steps for throughput with
recording off.
"""

from __future__ import annotations

import functools
import time
from collections import defaultdict
from contextlib import contextmanager
from typing import Callable, Dict, Iterable, Iterator, List, Optional

import torch

_recorder: Optional["StageRecorder"] = None


class StageRecorder:
    """Accumulated seconds per stage name, exclusive and inclusive, since the last :meth:`reset`."""

    def __init__(self, synchronize: bool = False) -> None:
        self.synchronize = synchronize
        self.exclusive: Dict[str, float] = defaultdict(float)
        self.inclusive: Dict[str, float] = defaultdict(float)
        self._stack: List[list] = []  # [name, start, seconds spent in nested stages]

    def _now(self) -> float:
        if self.synchronize:
            torch.cuda.synchronize()
        return time.perf_counter()

    def push(self, name: str) -> None:
        self._stack.append([name, self._now(), 0.0])

    def pop(self, name: str) -> None:
        end = self._now()
        if all(frame[0] != name for frame in self._stack):
            return  # opened before recording began
        while self._stack:  # a stage left open by an exception inside it is closed here too
            opened, start, nested = self._stack.pop()
            elapsed = end - start
            self.exclusive[opened] += elapsed - nested
            if all(frame[0] != opened for frame in self._stack):  # a stage nested in itself counts once
                self.inclusive[opened] += elapsed
            if self._stack:
                self._stack[-1][2] += elapsed
            if opened == name:
                return

    def reset(self) -> None:
        self.exclusive.clear()
        self.inclusive.clear()
        self._stack.clear()


@contextmanager
def stage(name: str) -> Iterator[None]:
    """Charge the time of the block to stage ``name`` (a no-op unless recording)."""
    recorder = _recorder
    if recorder is None:
        yield
        return
    recorder.push(name)
    try:
        yield
    finally:
        recorder.pop(name)


def timed(name: str) -> Callable[[Callable], Callable]:
    """Decorator: every call of the function is charged to stage ``name`` (a no-op unless recording)."""

    def wrap(function: Callable) -> Callable:
        @functools.wraps(function)
        def wrapper(*args, **kwargs):
            if _recorder is None:
                return function(*args, **kwargs)
            with stage(name):
                return function(*args, **kwargs)

        return wrapper

    return wrap


@contextmanager
def recording(synchronize: bool = False) -> Iterator[StageRecorder]:
    """Turn the markers on for the duration of the block; yields the recorder holding the times."""
    global _recorder
    if _recorder is not None:
        raise RuntimeError("stage recording is already on")
    _recorder = StageRecorder(synchronize)
    try:
        yield _recorder
    finally:
        _recorder = None


def time_modules(modules: Iterable[torch.nn.Module], name: str) -> List[object]:
    """Charge every forward call of ``modules`` to stage ``name`` (while recording); returns the hook
    handles, whose ``remove()`` takes the hooks off again."""
    handles = []
    for module in modules:
        handles.append(module.register_forward_pre_hook(lambda *_: _push(name)))
        handles.append(module.register_forward_hook(lambda *_: _pop(name)))
    return handles


def _push(name: str) -> None:
    if _recorder is not None:
        _recorder.push(name)


def _pop(name: str) -> None:
    if _recorder is not None:
        _recorder.pop(name)
