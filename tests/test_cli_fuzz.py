"""CLI fuzz (issues #11 §5, #15 §4): generated argument vectors over every subcommand, run
in-process through ``sim.cli.main``. Every vector ends with status 0 (done), 1 (monitor: the
link failed during the work) or 2 (one line naming the bad argument, file or value): never a
traceback, never the internal-error status 70.

The vectors are drawn from the parser itself (every option of every subcommand, its values
from pools of good, edge and bad tokens, missing and unknown arguments), over files made
here: a short experiment, its log.csv, a raw capture, README.md, folders, missing and
unwritable paths. Valid vectors really run (a 0.2 s experiment, a 0.2 s ``serve``, a monitor
on ``sim://``, decode, plot, replay, ports). Two bodies are replaced by recorders, because a
valid vector would run for minutes: ``reproduce``'s pipeline and ``tune``'s optimisation
(everything before them, the argument and file checks, the output folder, runs for real;
``tests/sim/commands/test_tune.py`` and ``tests/sim/reproduce`` run the bodies).

``TURNTABLE_CLI_FUZZ=N`` changes the number of vectors (default 600).
"""

from __future__ import annotations

import argparse
import faulthandler
import os
import random
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import pytest

from sim import cli

ROOT = Path(__file__).resolve().parents[1]
N_VECTORS = int(os.environ.get("TURNTABLE_CLI_FUZZ", "600"))
SEED = int(os.environ.get("TURNTABLE_CLI_FUZZ_SEED", "15"))

NUMBERS = ["0", "1", "2", "0.5", "10", "100", "990", "3000", "-1", "-0.5", "1e9", "3e6", "1e40",
           "nan", "inf", "-inf", "99999", "65536", "0x10", "abc", "", " ", "1,5",
           "1e-320"]  # fmt: skip
#: Values that are right for an option (by position for options of several values): drawn
#: more than half of the time, so that many vectors run for real.
GOOD = {
    "baud": ["460800", "115200"],
    "move": ["10", "-5", "90"],
    "v_max": ["100", "990"],
    "a_max": ["148", "1000"],
    "j_max": ["0", "500"],
    "interrupt": [["0.05", "0.1"], ["10", "-20"]],
    "stop": ["0.05", "0.1"],
    "gains": [["velocity", "position", "current"], ["0.05", "10"], ["1.5", "0"], ["0"]],
    "limits": [["990", "500"], ["148", "1000"], ["5", "4"], ["30", "10"]],
    "telemetry": ["1", "0", "10"],
    "ack_timeout": ["0.1", "0.05"],
    "retries": ["0", "1", "3"],
    "plot_window": ["5", "10"],
    "plot_fps": ["25"],
    "seed": ["0", "1", "7"],
    "tick_hz": ["500", "1000"],
    "can_base_id": ["0x100", "256"],
    "time_scale": ["4", "100"],
    "popsize": ["2", "10"],
    "maxiter": ["0", "4"],
    "bound_factor": ["4", "2"],
    "dpi": ["50", "110"],
    "current_limit": ["5"],
    "speed": ["inf", "100"],
    "duration": ["0.05", "0.1", "0.2"],
    "profile": ["trapezoid", "step"],
    "jog": ["20", "-50"],
    "jog_accel": ["500", "148"],
    "jog_timeout": ["0", "200"],
}
SMALL_DURATIONS = ["0.05", "0.1", "0.2", "0", "-1", "nan", "inf", "x"]
TEXT = ["x", "", "velocity", "current", "position", "trapezoid", "jerk", "a=b", "-", "é", "\x00"]


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, list[str]]:
    """Paths the vectors use, grouped by what they are."""
    from sim.config import load_experiment
    from sim.csvlog import write_csv
    from sim.loop import run

    d = tmp_path_factory.mktemp("cli_fuzz")
    exp = d / "short.toml"
    exp.write_text(
        'bench = "paper_bench.toml"\nduration_s = 0.2\n[[command]]\nt_s = 0.0\n'
        'type = "move"\ntarget_deg = 5.0\nv_max_dps = 100.0\na_max_dps2 = 1000.0\n'
    )
    result = run(load_experiment(exp), seed=0)
    log_csv = write_csv(result.log, d / "log.csv")
    capture = d / "capture.bin"
    capture.write_bytes(result.pc_bytes)
    (d / "latin1.toml").write_bytes(b'title = "b\xe9nch"\n')
    (d / "empty.bin").write_bytes(b"")
    (d / "folder").mkdir()
    # Copies only: a vector may write to any path it is given (--capture, -o, --out), and
    # nothing of the repository may be overwritten by the fuzz.
    readme = str(d / "README.md")
    Path(readme).write_text((ROOT / "README.md").read_text(encoding="utf-8"), encoding="utf-8")
    bench = str(d / "paper_bench.toml")
    Path(bench).write_text((ROOT / "bench_configs" / "paper_bench.toml").read_text())
    missing = str(d / "missing.toml")
    bad_dirs = [str(d / "folder"), "/proc/no/such", readme + "/x", str(d)]
    return {
        "experiment": [str(exp), str(exp), readme, missing, str(d / "latin1.toml"), str(d)],
        "bench": [bench, bench, str(exp), readme, missing, str(d / "latin1.toml")],
        "data": [str(log_csv), str(capture), readme, missing, str(d / "empty.bin"), str(d)],
        "capture": [str(capture), str(capture), readme, missing, str(d / "empty.bin")],
        "out_dir": [str(d / "out" / "a"), str(d / "out" / "b"), readme, *bad_dirs],
        "out_file": [
            str(d / "o.csv"),
            str(d / "fig.png"),
            str(d / "fig.svg"),
            str(d / "x.txt"),
            "-",
            *bad_dirs,
        ],  # fmt: skip
        "url": [
            "sim://",
            "sim://",
            "loop://",
            "socket://127.0.0.1:1",
            "can://virtual/fuzz",
            "/dev/no-such-port",
            "can://",
            "sim://" + missing,
            "sim://" + readme,
        ],  # fmt: skip
        "capture_out": [str(d / "cap.bin"), str(d / "cap.asc"), *bad_dirs],
    }


# dest -> kind of value (else by the action's type)
KIND = {
    "config": "experiment",
    "bench": "bench",
    "gains_from": "bench",
    "file": "data",
    "files": "data",
    "capture": "capture",
    "out": "out_dir",
    "csv": "out_file",
    "plot_save": "out_file",
    "url": "url",
    "to": "url",
    "link": "out_file",
    "duration": "duration",
    "can": "can",
    "set": "set",
    "weight": "weight",
    "scenario": "scenario",
    "regex": "regex",
    "host": "host",
}
POOLS = {
    "duration": SMALL_DURATIONS,
    "can": ["virtual/fuzz", "virtual", "nope/x", "/x"],
    "set": [
        "uart.bit_flip_rate=1e-4",
        "encoder.bits=12",
        "motor.r_ohm=1e9",
        "x",
        "a.b=[1]",
        "safety.watchdog_s=0.001",
        "motor.r_ohm = 1.3",
        "nope.key=1",
    ],  # fmt: skip
    "weight": ["chatter_duty=1000", "overshoot=nan", "nope=1", "x", "overshoot=-1"],
    "scenario": ["fig8", "step_demo", "nope", ""],
    "regex": ["tty", "(", "", ".*"],
    "host": ["127.0.0.1", "256.1.1.1", "", "localhost"],
}


def _value(
    rng: random.Random, action: argparse.Action, files: dict[str, list[str]], index: int = 0
) -> str:
    good = GOOD.get(action.dest)
    if good is not None and rng.random() < 0.6:
        return rng.choice(good[index] if isinstance(good[0], list) else good)
    kind = KIND.get(action.dest)
    if kind in files:
        return rng.choice(files[kind])
    if kind in POOLS:
        return rng.choice(POOLS[kind])
    if action.choices:
        return rng.choice([*map(str, action.choices), "nope"])
    if action.dest in ("gains",):
        return rng.choice(["velocity", "current", "position", "speed", *NUMBERS])
    if action.dest in ("speed",):
        return rng.choice(["inf", "inf", "100", "1", *NUMBERS])
    if action.type is not None or action.dest in ("title",):
        return rng.choice(NUMBERS if action.dest != "title" else TEXT)
    return rng.choice(TEXT + NUMBERS[:4])


def vector(rng: random.Random, name: str, parser: argparse.ArgumentParser, files) -> list[str]:
    """One argument vector for subcommand ``name``."""
    actions = [a for a in parser._actions if a.dest != "help"]
    argv = [name]
    for action in actions:
        if action.option_strings:
            # optional: present with some probability (more often when it keeps runs short)
            keep = action.dest in ("duration", "speed", "quiet") or rng.random() < 0.3
            if action.dest == "interactive" or not keep:
                continue  # --interactive reads the terminal: tested through the shell
            argv.append(rng.choice(action.option_strings))
            if action.nargs == 0:
                continue
            count = action.nargs if isinstance(action.nargs, int) else 1
            if rng.random() < 0.05:
                count = max(0, count - 1)  # a value short
            argv += [_value(rng, action, files, i) for i in range(count)]
        else:
            if rng.random() < 0.05:
                continue  # a required positional missing
            count = 2 if action.nargs == "+" and rng.random() < 0.3 else 1
            argv += [_value(rng, action, files) for _ in range(count)]
    if rng.random() < 0.04:
        argv.insert(rng.randrange(1, len(argv) + 1), rng.choice(["--nope", "-z", "extra"]))
    if name == "serve" and not any(a in argv for a in ("--pty", "--tcp", "--can")):
        argv += rng.choice([["--tcp", "0"], ["--pty"], ["--can", "virtual/fuzz"], []])
    if name == "serve" and "--tcp" in argv:
        argv[argv.index("--tcp") + 1 : argv.index("--tcp") + 2] = [
            rng.choice(["0", "0", "99999", "-1", "x"])
        ]
    return argv


@pytest.fixture
def recorders(monkeypatch):
    """The two bodies that run for minutes, replaced by recorders (see the module doc)."""
    import sim.commands.reproduce as reproduce_cmd
    import sim.commands.tune as tune_cmd

    calls: Counter[str] = Counter()

    def fake_execute(args):
        calls["reproduce"] += 1
        report = args.out / "REPORT.md"
        report.write_text("recorded\n")
        return SimpleNamespace(simulated_s=0.0, wall_s=0.0, paths=[report])

    def fake_tune(args):
        from sim.config import load_bench

        load_bench(args.config)  # the config check of the real body
        calls["tune"] += 1
        return 0

    monkeypatch.setattr(reproduce_cmd, "execute", fake_execute)
    monkeypatch.setattr(tune_cmd, "_tune", fake_tune)
    return calls


def _repository_files() -> dict[Path, int]:
    skip = {".git", "__pycache__", ".pytest_cache", ".ruff_cache", ".hypothesis"}
    return {
        p: p.stat().st_mtime_ns
        for p in ROOT.rglob("*")
        if p.is_file() and not skip.intersection(p.relative_to(ROOT).parts)
    }


def test_cli_fuzz(files, recorders, capfd, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # default output folders (tune_out, reproduce_out) land here
    monkeypatch.delenv("TURNTABLE_SIM_TRACEBACK", raising=False)
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    rng = random.Random(SEED)
    names = sorted(sub.choices)
    before = _repository_files()
    statuses: Counter[tuple[str, int]] = Counter()
    findings = []
    for k in range(N_VECTORS):
        name = names[k % len(names)]
        argv = vector(rng, name, sub.choices[name], files)
        # a vector that hangs is a finding too: after 5 minutes, dump where it waits and end
        # the run (a blocked suite helps nobody)
        faulthandler.dump_traceback_later(300, exit=True)
        status = cli.main(argv)
        faulthandler.cancel_dump_traceback_later()
        out, err = capfd.readouterr()
        statuses[(name, status)] += 1
        # (stdout may be data: replay to '-' writes the file it plays, whatever it says)
        if status not in (0, 1, 2) or "Traceback" in err or "internal error" in err:
            findings.append(f"{argv!r}: status {status}: {err.strip()[-300:]}")
        elif status == 2:
            last = err.strip().splitlines()[-1] if err.strip() else ""
            if not last.startswith("turntable-sim"):
                findings.append(f"{argv!r}: status 2 without a 'turntable-sim ...' line: {err!r}")
    summary = ", ".join(f"{n}:{s}={c}" for (n, s), c in sorted(statuses.items()))
    print(f"cli fuzz: {N_VECTORS} vectors; {summary}; recorded {dict(recorders)}")
    assert not findings, "\n".join(findings[:15])
    assert _repository_files() == before  # the fuzz wrote nothing into the repository
    # every subcommand was reached, and the fuzz ran real work, not only refusals
    assert {n for n, _ in statuses} == set(names)
    assert sum(c for (n, s), c in statuses.items() if s == 0) >= N_VECTORS // 10
    assert sum(c for (n, s), c in statuses.items() if s == 2) >= N_VECTORS // 3
