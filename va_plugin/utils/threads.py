"""Torch and threads: small ops on one CPU thread, and a warning when two trainings share a process."""

from __future__ import annotations

import threading
import warnings
from collections.abc import Iterator
from contextlib import contextmanager

import torch


@contextmanager
def single_thread() -> Iterator[None]:
    """Run torch on one thread: many small ops are slower threaded (much slower on a busy machine, where
    the threads wait for each other), and results stay fixed."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


_TRAINING: dict[int, list] = {}
"""Thread id -> [the call training in it, whether another thread trained meanwhile]."""
_TRAINING_LOCK = threading.Lock()


@contextmanager
def training_in_this_thread(call: str) -> Iterator[None]:
    """Mark ``call`` as training in this thread for the block. Two runs at once in two threads of one
    process share torch's global state (its random generator, its thread count), so neither gives the
    results it gives alone: each of them says so with a warning (the one starting second at once, the
    other when it ends)."""
    me = threading.get_ident()
    with _TRAINING_LOCK:
        nested = me in _TRAINING
        others = [entry for ident, entry in _TRAINING.items() if ident != me]
        if not nested:
            _TRAINING[me] = [call, bool(others)]
        for entry in others:
            entry[1] = True
    advice = ("torch's random generator and thread count are shared by the threads of a process, so its results "
              "differ from the same call run alone; run one at a time, or each in its own process (as va-batch "
              "does)")
    if others and not nested:
        warnings.warn(f"{call} started while {others[0][0]} trains in another thread: {advice}", stacklevel=6)
    try:
        yield
    finally:
        if not nested:
            with _TRAINING_LOCK:
                entry = _TRAINING.pop(me)
            if entry[1] and not others:
                warnings.warn(f"{call} trained while another call trained in another thread: {advice}",
                              stacklevel=6)
