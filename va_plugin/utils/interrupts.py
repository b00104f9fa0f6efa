"""Holding back Ctrl-C while code that swallows it runs, SIGTERM taken like Ctrl-C, and both turned into
a request that training serves at the end of a step.

Some imports (trimesh, open3d) catch a KeyboardInterrupt and carry on broken; inside
:func:`interrupt_deferred` a SIGINT only sets a flag, raised when the block ends. Inside
:func:`terminate_as_interrupt` SIGTERM (``kill``, batch time limits) raises KeyboardInterrupt, so it
takes Ctrl-C's way out (a checkpoint is saved, workers are interrupted and waited for). Inside
:func:`signals_as_requests` (the training loop) the first SIGINT or SIGTERM only asks the loop to stop
when the step ends, and :func:`signals_held` keeps them from cutting a checkpoint's write short;
:func:`signal_plan` reads the test hook that sends them at chosen steps. A worker
process calls :func:`interrupt_when_orphaned` so that its main process's death stops it as Ctrl-C would.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

EXIT_INTERRUPTED = 130
"""Exit status of a command stopped by Ctrl-C or SIGTERM (128 + SIGINT), after it saved what it had."""


@contextlib.contextmanager
def interrupt_deferred() -> Iterator[None]:
    """Run the block with SIGINT held back, then raise KeyboardInterrupt if one came meanwhile.

    Does nothing off the main thread (signal handlers can only be set there) or when SIGINT is not
    Python's default handler (ignored, as in background jobs, or handled by someone else)."""
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield
        return
    received = []
    signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if received:
        raise KeyboardInterrupt


@contextlib.contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """Run the block with SIGTERM raising KeyboardInterrupt (a second SIGTERM ends the process at once).

    Does nothing off the main thread or when SIGTERM already has a handler other than the default."""
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL):
        yield
        return

    def handler(signum, frame) -> None:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _takeable_signals() -> dict[int, Any]:
    """SIGINT and SIGTERM with their dispositions, where a block may take them over: a Python handler, or
    SIGTERM's default (an ignored signal, or SIGINT left to the system, stays as it is)."""
    current = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)}
    return {signum: handler for signum, handler in current.items()
            if callable(handler) or (signum == signal.SIGTERM and handler is signal.SIG_DFL)}


@contextlib.contextmanager
def signals_as_requests(request: Callable[[int], None]) -> Iterator[None]:
    """Run the block with SIGINT and SIGTERM calling ``request(signum)`` instead of interrupting it, so the
    caller can stop where its state is whole (a training step's end). A second one of them gets the
    handling they had before the block: Ctrl-C's KeyboardInterrupt at once, SIGTERM's end of the process
    (or the handler set, e.g. :func:`terminate_as_interrupt`'s).

    A signal ignored (SIG_IGN, as in background jobs) stays ignored; SIGINT without Python's handlers
    (SIG_DFL) is left alone. Does nothing off the main thread (signal handlers can only be set there)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = _takeable_signals()
    taken = list(previous)
    received: list[int] = []

    def handler(signum, frame) -> None:
        if received:  # the second one: no more waiting for the block
            _hand_on(signum, frame, previous[signum])
            return
        received.append(signum)
        request(signum)

    for signum in taken:
        signal.signal(signum, handler)
    try:
        yield
    finally:
        for signum in taken:
            if signal.getsignal(signum) is handler:  # not when the handler handed on changed it meanwhile
                signal.signal(signum, previous[signum])


@contextlib.contextmanager
def signals_held(hand_on: bool = True) -> Iterator[None]:
    """Run the block (a checkpoint being written) with SIGINT and SIGTERM only noted, so that no signal
    cuts it short: an exception raised inside ``torch.save`` would surface as torch's own error, a
    traceback. Once the block is done, a signal that came meanwhile is handed to the handler in place
    before the block (``hand_on``), or dropped when the caller stops anyway (a second Ctrl-C while the
    checkpoint of the first is written).

    Signals ignored or left to the system (SIGINT without Python's handler) are left alone; does nothing
    off the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = _takeable_signals()
    held = list(previous)
    received: list[int] = []
    for signum in held:
        signal.signal(signum, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        for signum in held:
            signal.signal(signum, previous[signum])
    if hand_on and received:
        _hand_on(received[0], None, previous[received[0]])


def _hand_on(signum: int, frame, handler) -> None:
    """Handle ``signum`` as ``handler`` (a previous disposition) would have."""
    if callable(handler):
        handler(signum, frame)
    elif handler is signal.SIG_DFL:
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)


ORPHAN_POLL_SECONDS = 1.0
"""How often :func:`interrupt_when_orphaned` looks for its main process."""
ORPHAN_GRACE_SECONDS = 120.0
"""How long an orphaned worker gets, once interrupted, to save its checkpoint and end by itself."""


def interrupt_when_orphaned(parent: int, poll_seconds: float = ORPHAN_POLL_SECONDS,
                            grace_seconds: float = ORPHAN_GRACE_SECONDS) -> threading.Thread:
    """Watch from a daemon thread for the process ``parent`` to end (this process re-parented to another),
    then send this process SIGINT, as Ctrl-C would (a training run saves a checkpoint at the end of its
    step and stops), and end it if it is still alive ``grace_seconds`` later. For worker processes whose
    main process may be killed without a chance to stop them."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_seconds)
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(grace_seconds)
        os._exit(130)

    thread = threading.Thread(target=watch, name="orphan-watch", daemon=True)
    thread.start()
    return thread


SIGNAL_POINTS = ("start", "mid", "end")
"""Where in a step :func:`signal_plan`'s signals are sent."""


def signal_plan(text: str | None) -> dict[tuple[int, str], int]:
    """The test hook's plan (``VA_TEST_SIGNALS``): ``"12:INT,20:TERM@start"`` -> ``{(12, "mid"): SIGINT,
    (20, "start"): SIGTERM}``, signals a training run sends itself during the given 1-based step, at its
    ``start`` (before the callbacks), ``mid`` (after the backward pass, the default) or ``end`` (after the
    callbacks). Empty or None: no plan."""
    plan: dict[tuple[int, str], int] = {}
    for item in (text or "").replace(" ", "").split(","):
        if not item:
            continue
        step, _, rest = item.partition(":")
        name, _, where = rest.partition("@")
        signum = signal.Signals.__members__.get("SIG" + name.upper().removeprefix("SIG"))
        if not step.isdigit() or signum is None or where not in ("", *SIGNAL_POINTS):
            raise ValueError(f"VA_TEST_SIGNALS item {item!r} is not STEP:SIGNAL[@start|mid|end]")
        plan[(int(step), where or "mid")] = int(signum)
    return plan
