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


def _call(fn: Callable[..., Any], args: tuple, kwargs: dict) -> None:
    fn(*args, **kwargs)


@dataclass
class _Job:
    fn: Callable[..., Any]
    args: tuple
    kwargs: dict
    future: Future | None


class Drawer:
    """Runs ``submit``-ted jobs in worker processes (``workers``, default
    :func:`worker_count`; 0: here, at once). Use as a context manager, or call
    :meth:`finish`; an exception in a job is raised by :meth:`finish`."""

    def __init__(self, workers: int | None = None) -> None:
        n = worker_count() if workers is None else workers
        self._pool = (
            ProcessPoolExecutor(max_workers=n, mp_context=multiprocessing.get_context("fork"))
            if n > 0
            else None
        )
        self._jobs: list[_Job] = []

    @property
    def parallel(self) -> bool:
        return self._pool is not None

    def submit(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
        """Run ``fn(*args, **kwargs)`` in a worker (or here, now, without one)."""
        if self._pool is not None:
            try:
                future = self._pool.submit(_call, fn, args, kwargs)
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
        try:
            for job in reversed(self._jobs):
                if job.future is None or job.future.cancel():
                    job.fn(*job.args, **job.kwargs)
                    job.future = None
            for job in self._jobs:
                if job.future is None:
                    continue
                try:
                    job.future.result()
                except BrokenProcessPool:  # the worker died (killed, out of memory): redo it
                    job.fn(*job.args, **job.kwargs)
        finally:
            self._pool.shutdown(wait=True, cancel_futures=True)
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
