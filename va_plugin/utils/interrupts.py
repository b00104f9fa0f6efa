"""Holding back Ctrl-C while code that swallows it runs, and SIGTERM taken like Ctrl-C.

Some imports (trimesh, open3d) catch a KeyboardInterrupt and carry on broken; inside
:func:`interrupt_deferred` a SIGINT only sets a flag, raised when the block ends. Inside
:func:`terminate_as_interrupt` SIGTERM (``kill``, batch time limits) raises KeyboardInterrupt, so it
takes Ctrl-C's way out (a checkpoint is saved, workers are interrupted and waited for).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator


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
