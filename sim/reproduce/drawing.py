"""Draw the reproduction's figures (and write its files) in a second process while this one
simulates.

About half of ``turntable-sim reproduce`` used to be matplotlib drawing and saving PNGs, one
after the other, after the simulations they show. A :class:`Drawer` hands each figure to a
worker process as soon as its runs are done, so the drawing overlaps the simulations that
follow; at :meth:`Drawer.finish` this process draws, newest first, whatever the worker has
not started, so both cores are busy to the end. The worker is forked (it starts with
matplotlib and the results already in memory); where ``fork`` is not available, or only
one core is, everything is drawn here, in order, as before.

A job is a module-level function and its arguments (they travel to the worker pickled);
what it returns is dropped (a ``Figure`` is not worth sending back). If the worker cannot
start or dies (killed, out of memory), this process does its jobs.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

__all__ = ["Drawer", "worker_count"]


def worker_count() -> int:
    """Worker processes worth starting: the cores this process may use, less its own (at
    most 3; 0 without ``fork``)."""
    if "fork" not in multiprocessing.get_all_start_methods():
        return 0
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(0, min(cores - 1, 3))


# Which jobs someone has started, shared with the forked worker (it inherits these: they
# exist before the first job forks it). The worker and this process claim a job before
# running it, so each runs once, with no Future.cancel() racing the pool's own bookkeeping.
_MAX_JOBS = 4096
_claims: Any = None
_claims_lock: Any = None


def _claim(slot: int) -> bool:
    """Claim job ``slot`` for the calling process; False if it was taken."""
    # A worker killed inside this critical section would leave the lock held: wait a
    # little, then take the job anyway (running it twice is harmless, never is not).
    locked = _claims_lock.acquire(timeout=5.0)
    try:
        taken = bool(_claims[slot])
        _claims[slot] = 1
        return not taken
    finally:
        if locked:
            _claims_lock.release()


def _call(slot: int, fn: Callable[..., Any], args: tuple, kwargs: dict) -> None:
    if _claim(slot):
        fn(*args, **kwargs)


@dataclass
class _Job:
    fn: Callable[..., Any]
    args: tuple
    kwargs: dict
    future: Future | None
    here: bool = False  # run by this process


class Drawer:
    """Runs ``submit``-ted jobs in worker processes (``workers``, default
    :func:`worker_count`; 0: here, at once). Use as a context manager, or call
    :meth:`finish`; an exception in a job is raised by :meth:`finish`. One drawer at a
    time per process (the job claims are module-wide)."""

    def __init__(self, workers: int | None = None) -> None:
        global _claims, _claims_lock
        n = worker_count() if workers is None else workers
        self._pool = None
        if n > 0:
            ctx = multiprocessing.get_context("fork")
            _claims, _claims_lock = ctx.RawArray("b", _MAX_JOBS), ctx.Lock()
            self._pool = ProcessPoolExecutor(max_workers=n, mp_context=ctx)
        self._jobs: list[_Job] = []

    @property
    def parallel(self) -> bool:
        return self._pool is not None

    def submit(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
        """Run ``fn(*args, **kwargs)`` in a worker (or here, now, without one)."""
        if self._pool is not None and len(self._jobs) < _MAX_JOBS:
            try:
                future = self._pool.submit(_call, len(self._jobs), fn, args, kwargs)
            except (OSError, BrokenProcessPool):  # no worker could start (fork refused)
                future = None
            self._jobs.append(_Job(fn, args, kwargs, future))
            return
        fn(*args, **kwargs)

    def finish(self) -> None:
        """Run here what no worker has started (newest first: a worker takes the oldest),
        then wait for the rest; raises the first job's exception, if any."""
        if self._pool is None:
            return
        broken = False
        try:
            for slot in reversed(range(len(self._jobs))):
                job = self._jobs[slot]
                if _claim(slot) or job.future is None:
                    job.fn(*job.args, **job.kwargs)
                    job.here = True
            for job in self._jobs:
                if job.here or job.future is None:
                    continue
                try:
                    job.future.result()
                except BrokenProcessPool:  # the worker died (killed, out of memory): redo it
                    broken = True
                    job.fn(*job.args, **job.kwargs)
        finally:
            # Drop the jobs this process took before they are sent to the worker; not once
            # the pool is broken (its manager thread is failing the same futures then).
            self._pool.shutdown(wait=True, cancel_futures=not broken)
            self._pool = None
            self._jobs = []

    def __enter__(self) -> Drawer:
        return self

    def __exit__(self, exc_type: Any, *_: Any) -> None:
        if exc_type is None:
            self.finish()
        elif self._pool is not None:  # the run failed: drop what is queued, stop the worker
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
