"""Every Python snippet in the README runs as written (issue #15 §5), each in a fresh
interpreter from the repository's root, as a reader would paste it.

A snippet that talks to a board uses the port the README has ``serve`` make for it
(``turntable-sim serve --pty --link /tmp/turntable``): the test starts that server first. The
link path is fixed by the README, so concurrent test runs on the machine take turns on it
(a lock file beside it).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
BOARD_LINK = "/tmp/turntable"


def snippets() -> list[tuple[int, str]]:
    """(line number, code) of every ```python block of the README."""
    text = README.read_text(encoding="utf-8")
    out = []
    for m in re.finditer(r"^```python\n(.*?)^```", text, re.M | re.S):
        out.append((text.count("\n", 0, m.start()) + 1, m.group(1)))
    return out


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}


@contextlib.contextmanager
def _board() -> Iterator[None]:
    """``turntable-sim serve --pty --link /tmp/turntable`` for the snippet's lifetime."""
    with open(BOARD_LINK + ".test-lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one test run at a time owns the README's path
        with contextlib.suppress(FileNotFoundError):
            os.unlink(BOARD_LINK)  # a stale link of a killed run
        proc = subprocess.Popen(
            [sys.executable, "-m", "sim.cli", "serve", "--pty", "--link", BOARD_LINK],
            env=_env(),
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            proc.stdout.readline()  # the address: printed once the board is up
            deadline = time.monotonic() + 60
            while not os.path.islink(BOARD_LINK) and time.monotonic() < deadline:
                time.sleep(0.05)
            assert os.path.islink(BOARD_LINK), proc.stderr.read() if proc.poll() else ""
            yield
        finally:
            proc.terminate()
            proc.communicate(timeout=60)


SNIPPETS = snippets()


def test_the_readme_has_python_snippets():
    assert len(SNIPPETS) >= 4


@pytest.mark.parametrize(("line", "code"), SNIPPETS, ids=[f"line{n}" for n, _ in SNIPPETS])
def test_readme_snippet_runs_as_written(line, code):
    needs_board = BOARD_LINK in code
    with _board() if needs_board else contextlib.nullcontext():
        done = subprocess.run(
            [sys.executable, "-c", code],
            env=_env(),
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=300,
        )
    assert done.returncode == 0, f"README.md line {line}:\n{code}\n{done.stderr}"
    assert "Traceback" not in done.stderr
