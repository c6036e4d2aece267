"""Every Python snippet in the README runs as written (issue #15 §5), each in a fresh
interpreter from the repository's root, as a reader would paste it; every shell command it
quotes is accepted by the command line as written and names files that exist (below).

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
import shlex
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


def shell_commands() -> list[tuple[int, list[str]]]:
    """(line number, argv) of every command of the README's ```sh blocks and of the
    subcommand table's examples: continuation lines joined, comments dropped, ``&&`` and
    ``|`` split into their commands."""
    text = README.read_text(encoding="utf-8")
    blocks = [
        (text.count("\n", 0, m.start()) + 2, m.group(1))
        for m in re.finditer(r"^```sh\n(.*?)^```", text, re.M | re.S)
    ]
    blocks += [
        (text.count("\n", 0, m.start()) + 1, m.group(1).replace("\\|", "|"))
        for m in re.finditer(r"^\| `\w+` \| .* \| `(turntable-sim [^`]*)` \|$", text, re.M)
    ]
    out = []
    for first, block in blocks:
        lines = block.replace("\\\n", " ").splitlines()
        for k, line in enumerate(lines):
            words = shlex.split(line, comments=True)
            command: list[str] = []
            for word in [*words, "&&"]:
                if word in ("&&", "|"):
                    if command:
                        out.append((first + k, command))
                    command = []
                else:
                    command.append(word)
    return out


COMMANDS = shell_commands()


def test_the_readme_quotes_shell_commands():
    assert sum(argv[0] == "turntable-sim" for _, argv in COMMANDS) >= 30


@pytest.mark.parametrize(("line", "argv"), COMMANDS, ids=[f"line{n}" for n, _ in COMMANDS])
def test_readme_command_is_accepted(line, argv, capsys):
    """Every ``turntable-sim`` command the README quotes is accepted by the command line
    parser as written (every option exists and takes the values given), and every file of
    the repository it names exists. The commands are not run: most need a board on a
    device the README makes up (/dev/pts/3), or minutes; tests/test_cli.py runs each
    subcommand. ``python3 SCRIPT`` names a script of the repository that exists."""
    from sim.cli import build_parser

    if argv[0] == "python3":
        if argv[1] == "-m":
            return  # pip and pytest
        assert (ROOT / argv[1]).is_file(), f"README.md line {line}: no {argv[1]}"
        return
    assert argv[0] == "turntable-sim", f"README.md line {line}: {argv}"
    for word in argv[1:]:
        if word.startswith(("bench_configs/", "docs/")):
            assert (ROOT / word).exists(), f"README.md line {line}: no {word}"
    try:
        build_parser().parse_args(argv[1:])
    except SystemExit as exc:
        assert exc.code == 0, f"README.md line {line}: {argv}\n{capsys.readouterr().err}"


def test_the_csv_columns_list_every_state_and_fault_code():
    """README's CSV table names every `State` and `Fault` code the log's integer columns hold
    (it went stale when THERMAL and the bus faults were added)."""
    from serial_protocol.messages import Fault, State

    text = README.read_text(encoding="utf-8")
    for column, enum in (("state", State), ("fault", Fault)):
        row = re.search(rf"^\| `{column}` \| code \| `{enum.__name__}`: (.*) \|$", text, re.M)
        assert row, f"README.md: no `{column}` row in the CSV table"
        listed = re.findall(r"(\d+) ([A-Z_]+)", row.group(1))
        assert [(int(c), n) for c, n in listed] == [(int(m), m.name) for m in enum], column
