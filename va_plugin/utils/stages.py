"""Wall time per named stage of a training step (the speed benchmark's breakdown).

Code marks stages with ``with stage("sampling"): ...`` or ``@timed("sampling")``; :func:`time_modules`
times chosen submodules through forward hooks. Nothing is recorded unless a :func:`recording` is open.
Times are *exclusive* (nested stages are subtracted from the outer one); inclusive times are kept too.
``synchronize=True`` (CUDA) synchronizes at every stage boundary, so a stage is charged for its kernels.
"""

from __future__ import annotations

import functools
import time
from collections import defaultdict
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager

import torch

_recorder: StageRecorder | None = None


class StageRecorder:
    """Accumulated seconds per stage name, exclusive and inclusive, since the last :meth:`reset`."""

    def __init__(self, synchronize: bool = False) -> None:
        self.synchronize = synchronize
        self.exclusive: dict[str, float] = defaultdict(float)
        self.inclusive: dict[str, float] = defaultdict(float)
        self._stack: list[list] = []  # [name, start, seconds spent in nested stages]

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


def time_modules(modules: Iterable[torch.nn.Module], name: str) -> list[object]:
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
