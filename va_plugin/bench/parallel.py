"""Benchmark rows in worker processes (``--jobs N``): up to N rows train and evaluate at the same time.

N ``spawn`` workers, each with ``torch.set_num_threads(threads)``, take one row at a time through a pipe
and send back the finished row or its exception; a worker serves several rows, so its start-up is paid
once. Rows are handed out in plan order; only the main process writes the result store and reports.

An interrupt makes every running row save a checkpoint and stop. A worker acts on the first interrupt of
a row only (a second cannot cut its checkpoint short) and ignores interrupts between rows; a row handed
out just before sees the ``stopping`` event and does not start. A worker whose main process was killed
(no chance to interrupt it) interrupts its own row the same way and ends.
"""

from __future__ import annotations

import os
import pickle
import signal
import time
import traceback
import warnings
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from multiprocessing import get_context
from multiprocessing.connection import wait
from pathlib import Path
from typing import Any

import torch

from va_plugin.bench.presets import EvalSettings
from va_plugin.bench.rows import RowSpec, run_row
from va_plugin.errors import one_line_warning
from va_plugin.utils.interrupts import interrupt_when_orphaned

STOP_SECONDS = 120.0
"""How long interrupted rows get to save their checkpoints before their workers are terminated."""
CLOSE_SECONDS = 30.0
"""How long an idle worker gets to exit."""


@dataclass
class RowTask:
    """Everything a worker needs to train and evaluate one row (the config is the fingerprinted one)."""

    index: int
    row: RowSpec
    config: Any
    scene_dir: Path
    evaluation: EvalSettings
    fingerprint: str


class RemoteTraceback(Exception):
    """The traceback of an exception raised in a worker (attached as the re-raised exception's cause)."""

    def __str__(self) -> str:
        return "\n" + str(self.args[0])


# -- in the worker processes ------------------------------------------------------------------------------
def _interrupt_once(signum, frame) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise KeyboardInterrupt


def _serve(conn, stopping, threads: int, parent: int) -> None:
    """A worker's life: rows from ``conn`` until None (or the main process ``parent`` is gone), each
    answered with ("done", result), ("interrupted",) or ("error", exception, traceback text)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked by the main process while starting
    interrupt_when_orphaned(parent)
    warnings.showwarning = one_line_warning
    torch.set_num_threads(threads)
    while True:
        try:
            task = conn.recv()
        except EOFError:
            return
        if task is None:
            return
        answer = _run(task, stopping)
        try:
            conn.send(answer)
        except OSError:  # the main process is gone
            return


def _run(task: RowTask, stopping) -> tuple:
    signal.signal(signal.SIGINT, _interrupt_once)
    try:
        if stopping.is_set():
            raise KeyboardInterrupt
        result = run_row(task.row, task.config, task.scene_dir, task.evaluation, task.fingerprint)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        return ("done", result)
    except KeyboardInterrupt:
        return ("interrupted",)
    except BaseException as exc:  # everything goes back to the main process
        try:
            pickle.dumps(exc)
        except Exception:
            exc = RuntimeError(f"{type(exc).__name__}: {exc}")
        return ("error", exc, traceback.format_exc())
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


# -- in the main process --------------------------------------------------------------------------------------
class _Worker:
    def __init__(self, context, stopping, threads: int, number: int) -> None:
        self.conn, child = context.Pipe()
        self.process = context.Process(target=_serve, args=(child, stopping, threads, os.getpid()), daemon=True,
                                       name=f"bench-worker-{number}")
        # started with SIGINT blocked (the mask survives exec) so an interrupt during its imports cannot
        # kill it; _serve unblocks it and _run turns it on for each row.
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            self.process.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        child.close()
        self.task: RowTask | None = None

    def receive(self) -> tuple:
        """The answer to the row in hand; an error naming the process when it ended without one."""
        try:
            return self.conn.recv()
        except (EOFError, OSError):
            self.process.join()
            return ("error", RuntimeError(f"{self.process.name} ended while running row {self.task.index + 1} "
                                          f"({self.task.row.key}), exit code {self.process.exitcode}"), "")
        finally:
            self.task = None

    def close(self) -> None:
        """Let an idle worker end; terminate one still running a row (it had its chance in _stop)."""
        if self.task is None and self.process.is_alive():
            try:
                self.conn.send(None)
                self.process.join(CLOSE_SECONDS)
            except OSError:
                pass
        self.conn.close()
        if self.process.is_alive():
            self.process.terminate()
        self.process.join()


def run_in_processes(tasks: Sequence[RowTask], jobs: int, threads: int, on_start: Callable[[RowTask], None],
                     on_done: Callable[[RowTask, dict[str, Any]], None],
                     on_error: Callable[[RowTask], None]) -> None:
    """Run ``tasks`` in up to ``jobs`` processes, calling ``on_start`` when a row is handed out and
    ``on_done`` with each finished row. A row that raised goes to ``on_error``, the others are stopped and
    its exception is raised here; an interrupt raises KeyboardInterrupt once the running rows stopped."""
    if not tasks:
        return
    context = get_context("spawn")
    stopping = context.Event()
    workers: list[_Worker] = []
    waiting = deque(tasks)

    def hand_out() -> None:
        for worker in workers:
            if worker.task is None and waiting:
                worker.task = waiting.popleft()
                on_start(worker.task)
                worker.conn.send(worker.task)

    try:
        workers.extend(_Worker(context, stopping, threads, number + 1) for number in range(min(jobs, len(tasks))))
        hand_out()
        while any(worker.task is not None for worker in workers):
            busy = {worker.conn: worker for worker in workers if worker.task is not None}
            answers = [(busy[conn].task, busy[conn].receive()) for conn in wait(list(busy))]
            answers.sort(key=lambda answer: answer[1][0] != "done")  # keep what finished before raising
            if answers[-1][1][0] == "done":
                hand_out()  # the next rows start before the reports are rewritten
            for task, message in answers:
                if message[0] == "done":
                    on_done(task, message[1])
                elif message[0] == "interrupted":
                    raise KeyboardInterrupt
                else:
                    on_error(task)
                    _, error, text = message
                    raise error from (RemoteTraceback(text) if text else None)
            hand_out()
    except BaseException:
        stopping.set()
        _stop(workers, on_done)
        raise
    finally:
        for worker in workers:
            worker.close()


def _stop(workers: list[_Worker], on_done: Callable[[RowTask, dict[str, Any]], None]) -> None:
    """Interrupt the running rows and wait up to STOP_SECONDS for them (rows that finish meanwhile are
    kept); a second interrupt stops the waiting (the caller terminates what is left)."""
    busy = {worker.conn: worker for worker in workers if worker.task is not None}
    for worker in busy.values():
        if worker.process.is_alive():
            os.kill(worker.process.pid, signal.SIGINT)
    deadline = time.monotonic() + STOP_SECONDS
    while busy and time.monotonic() < deadline:
        for conn in wait(list(busy), timeout=max(0.0, deadline - time.monotonic())):
            worker = busy.pop(conn)
            task = worker.task
            try:
                message = worker.receive()
            except Exception:  # an answer cut short by the interrupt: that row is lost (and resumable)
                continue
            if message[0] == "done":
                on_done(task, message[1])
