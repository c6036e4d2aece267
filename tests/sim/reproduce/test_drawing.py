"""The reproduction's figure drawer: jobs run in a forked worker or here, all of them, and a
job's exception reaches the caller."""

from __future__ import annotations

import os

import pytest

from sim.reproduce.drawing import Drawer, worker_count


def _write(path, text):
    path.write_text(f"{text} {os.getpid()}")


def _fail(message):
    raise ValueError(message)


@pytest.mark.parametrize("workers", [0, 1])
def test_every_job_runs_once(tmp_path, workers):
    if workers and worker_count() == 0:
        pytest.skip("no fork on this platform")
    paths = [tmp_path / f"{k}.txt" for k in range(6)]
    with Drawer(workers) as drawer:
        assert drawer.parallel == bool(workers)
        for k, p in enumerate(paths):
            drawer.submit(_write, p, k)
    pids = set()
    for k, p in enumerate(paths):
        text, pid = p.read_text().split()
        assert text == str(k)
        pids.add(int(pid))
    if not workers:
        assert pids == {os.getpid()}


def test_a_job_that_fails_raises_in_the_caller(tmp_path):
    with pytest.raises(ValueError, match="bad figure"):
        with Drawer(1 if worker_count() else 0) as drawer:
            drawer.submit(_write, tmp_path / "a.txt", 1)
            drawer.submit(_fail, "bad figure")


def _die(parent_pid, path):
    if os.getpid() != parent_pid:
        os._exit(9)  # a worker killed mid-job (out of memory, kill -9)
    path.write_text("redone here")


def test_jobs_of_a_worker_that_died_are_done_here(tmp_path):
    if worker_count() == 0:
        pytest.skip("no fork on this platform")
    paths = [tmp_path / f"{k}.txt" for k in range(3)]
    with Drawer(1) as drawer:
        drawer.submit(_die, os.getpid(), tmp_path / "died.txt")
        for k, p in enumerate(paths):
            drawer.submit(_write, p, k)
    for k, p in enumerate(paths):
        text, _ = p.read_text().split()
        assert text == str(k)
    assert (tmp_path / "died.txt").read_text() == "redone here"
