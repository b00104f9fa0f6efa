"""Who runs a batch's jobs. Both engines run the same function, :func:`va_plugin.batch.job.run_object`,
and hand each finished record to ``on_done`` in the main process, which alone writes the manifest.

- ``local``: one worker runs the jobs in this process; N run them in a pool of N ``spawn`` processes
  that ignore Ctrl-C and end themselves when this process is gone. A worker that dies fails the objects
  in flight (the pool cannot tell them apart); the others go on in a fresh pool.
- ``ray``: one Ray task per object with ``num_cpus`` = threads per job (and ``num_gpus`` when asked);
  ``address`` joins a running cluster, none starts a local instance with ``workers x threads`` CPUs.
"""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from queue import Empty
from typing import Any

from va_plugin.batch.job import ObjectJob, failed_record, run_object
from va_plugin.errors import ConfigError
from va_plugin.utils.interrupts import interrupt_when_orphaned

OnDone = Callable[[dict[str, Any]], None]
ENGINES = ("local", "ray")


# -- local ----------------------------------------------------------------------------------------------
def _start_worker(parent: int, started) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # the batch gone: end at once, before a resumed batch trains the same run folder
    interrupt_when_orphaned(parent, grace_seconds=0.0)
    global _STARTED
    _STARTED = started


_STARTED = None


def _run_in_worker(job: ObjectJob) -> dict[str, Any]:
    _STARTED.put(job.name)
    return run_object(job)


def run_local(jobs: Sequence[ObjectJob], workers: int, on_done: OnDone) -> None:
    """Run ``jobs`` in this process (``workers`` 1) or in a pool of ``workers`` processes."""
    if workers <= 1:
        for job in jobs:
            on_done(run_object(job))
        return
    remaining: list[ObjectJob] = list(jobs)
    while remaining:
        remaining = _run_pool(remaining, workers, on_done)


def _drain(queue) -> set:
    names = set()
    while True:
        try:
            names.add(queue.get(timeout=0.01))
        except Empty:
            return names


def _run_pool(jobs: list[ObjectJob], workers: int, on_done: OnDone) -> list[ObjectJob]:
    """Run ``jobs`` in one pool; the jobs left to run when a worker died (none when all finished)."""
    context = get_context("spawn")
    started = context.Queue()
    pool = ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=context,
                               initializer=_start_worker, initargs=(os.getpid(), started))
    futures = {pool.submit(_run_in_worker, job): job for job in jobs}
    finished, in_flight = set(), set()
    try:
        pending = set(futures)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            in_flight |= _drain(started)  # read as it comes: a full queue would hold its workers at exit
            for future in done:
                try:
                    record = future.result()
                except BrokenProcessPool:
                    continue
                finished.add(futures[future].name)
                on_done(record)
        lost = [job for job in jobs if job.name not in finished]
        if not lost:
            return []
        in_flight = (in_flight | _drain(started)) - finished
        for job in lost:
            if job.name in in_flight:
                on_done(failed_record(job, "the worker process running it died (out of memory, or killed); "
                                           "rerun with --resume --retry-failed"))
        return [job for job in lost if job.name not in in_flight]
    except BaseException:
        for future in futures:
            future.cancel()
        for process in list(getattr(pool, "_processes", {}).values()):
            process.terminate()  # in-flight objects resume from their checkpoints with --resume
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


# -- ray ------------------------------------------------------------------------------------------------
def import_ray():
    try:
        import ray
    except ImportError:
        raise ConfigError("--engine ray needs Ray: pip install 'va-plugin[ray]' (or pip install ray)") from None
    return ray


def run_ray(jobs: Sequence[ObjectJob], on_done: OnDone, address: str | None = None, workers: int = 1,
            threads: int = 1, gpus: float = 0.0) -> None:
    """One Ray task per job on the cluster at ``address``, or on a local instance started here."""
    ray = import_ray()
    options = {"include_dashboard": False, "configure_logging": False, "log_to_driver": False}
    if address:
        ray.init(address=address, **options)
    else:
        # Ray's default worker niceness (15) starves the jobs on a busy machine
        ray.init(num_cpus=workers * threads, num_gpus=None if gpus else 0,
                 _system_config={"worker_niceness": 0}, **options)
    pending: dict[Any, ObjectJob] = {}
    try:
        task = ray.remote(run_object).options(num_cpus=threads, num_gpus=gpus, max_retries=1)
        pending.update({task.remote(job): job for job in jobs})
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                job = pending.pop(ref)
                try:
                    record = ray.get(ref)
                except Exception as exc:  # the task's worker or node died: record it, go on
                    record = failed_record(job, f"Ray: {type(exc).__name__}: {str(exc).strip().splitlines()[0]}")
                on_done(record)
    except BaseException:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
    finally:
        ray.shutdown()
