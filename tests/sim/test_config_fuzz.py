"""Config fuzz (issue #11 §5): generated bench and experiment files, each either refused with
one ``ConfigError`` line that names the file, or accepted AND run: a short simulation of every
accepted file must not raise, must log finite numbers, must deliver telemetry and answer the
commands it was sent (an accepted file that cannot do that is accepted nonsense).

The default budget is 2,000 files (seeded, deterministic). ``TURNTABLE_CONFIG_FUZZ=N`` runs N
files instead (the long run in docs: ``TURNTABLE_CONFIG_FUZZ=20000 python3 -m pytest
tests/sim/test_config_fuzz.py``); ``TURNTABLE_CONFIG_FUZZ_SEED`` picks another seed.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
import os
import random
import tomllib
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from serial_protocol.exceptions import ConfigError
from sim.config import (
    COMMAND_FIELDS,
    SANITY,
    TABLES,
    Experiment,
    ScriptedCommand,
    load_bench,
    load_experiment,
)
from sim.loop import run

BENCH = Path(__file__).resolve().parents[2] / "bench_configs" / "paper_bench.toml"
N_FILES = int(os.environ.get("TURNTABLE_CONFIG_FUZZ", "2000"))
SEED = int(os.environ.get("TURNTABLE_CONFIG_FUZZ_SEED", "2026"))
#: The short run each accepted file gets (simulated seconds; an experiment's own duration is
#: capped to it, its later commands dropped).
RUN_S = 0.3

# ------------------------------------------------------------------------ TOML writing


def toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # JSON escapes are TOML basic-string escapes
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, datetime.date):
        return value.isoformat()
    raise TypeError(value)


def toml_text(data: dict[str, Any]) -> str:
    """``data`` as TOML: plain keys first, then every table (dotted paths as headers), then
    the ``[[command]]`` array of tables."""
    lines = [
        f"{k} = {toml_value(v)}"
        for k, v in data.items()
        if not isinstance(v, dict) and k != "command"
    ]

    def tables(node: dict[str, Any], prefix: str) -> None:
        for key, value in node.items():
            if isinstance(value, dict) and not getattr(value, "inline", False):
                path = prefix + key
                plain = {
                    k: v
                    for k, v in value.items()
                    if not isinstance(v, dict) or getattr(v, "inline", False)
                }
                lines.append(f"\n[{path}]")
                lines.extend(
                    f"{k} = {toml_value(dict(v) if isinstance(v, dict) else v)}"
                    for k, v in plain.items()
                )
                tables({k: v for k, v in value.items() if k not in plain}, path + ".")

    tables({k: v for k, v in data.items() if isinstance(v, dict)}, "")
    for command in data.get("command", []):
        lines.append("\n[[command]]")
        lines.extend(f"{k} = {toml_value(v)}" for k, v in command.items())
    return "\n".join(lines) + "\n"


class Inline(dict):
    """A dict written as an inline table (``{a = 1}``) rather than as a ``[table]``."""

    inline = True


# ------------------------------------------------------------------------ generation

ODD_VALUES: list[Any] = [
    0, -1, 1, 0.0, -0.0, -1.0, 1e-300, 5e-324, 1e300, -1e300, 1e39, math.nan, math.inf,
    -math.inf, 2**31, 2**63 - 1, 2**70, "text", "", True, False, [1.0], [0.01, 0.02], [],
    [[1.0]], Inline(a=1), datetime.date(1979, 5, 27),
]  # fmt: skip


def _field_value(rng: random.Random, default: Any, span: Any = None) -> Any:
    """A value for a field whose default is ``default``: mostly near it, sometimes odd,
    sometimes at an edge of its sanity range ``span`` (extreme but accepted plants)."""
    r = rng.random()
    if span is not None and rng.random() < 0.3:
        return type(default)(rng.choice(span[:2]))
    if isinstance(default, str):
        return rng.choice(["float", "fixed", "fixed", "double", 1])
    if r < 0.25 or isinstance(default, bool):
        return rng.choice(ODD_VALUES + [True, False] * 4)
    if isinstance(default, int):
        return rng.choice(
            [
                default,
                default + rng.randint(-3, 3),
                default * rng.choice([2, 10]),
                default // 2,
                rng.randint(-100, 100),
            ]
        )
    scale = rng.choice([0.0, 0.1, 0.5, 0.9, 1.0, 1.1, 2.0, 10.0, 1e3, 1e-3, -1.0])
    return float(default) * scale


def _defaults() -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for path, cls in TABLES.items():
        out[path] = {f.name: f.default for f in dataclasses.fields(cls)}
    return out


DEFAULTS = _defaults()


def _set(data: dict[str, Any], path: str, key: str, value: Any) -> None:
    node = data
    for part in path.split("."):
        node = node.setdefault(part, {})
    node[key] = value


def mutate_tables(rng: random.Random, data: dict[str, Any], n: int) -> None:
    for _ in range(n):
        r = rng.random()
        path = rng.choice(sorted(DEFAULTS))
        if r < 0.93:
            key = rng.choice(sorted(DEFAULTS[path]))
            span = SANITY.get((path, key))
            _set(data, path, key, _field_value(rng, DEFAULTS[path][key], span))
        elif r < 0.96:
            _set(data, path, rng.choice(["typo_key", "r_ohms", "bits2"]), 1.0)
        else:
            _set(data, rng.choice(["motr", "controller.speed", "safety.extra"]), "x", 1.0)


WIRE_FLOATS: list[Any] = [
    1.0,
    10.0,
    90.0,
    148.0,
    500.0,
    990.0,
    3000.0,
    -3000.0,
    2e5,
    3e6,
    1e39,
    -1e39,
    math.nan,
    math.inf,
    0.0,
    -5.0,
    1e-9,
    "1",
    True,
]


def _command_value(rng: random.Random, kind: str) -> Any:
    if rng.random() < 0.04:
        return rng.choice(ODD_VALUES)
    if kind == "float":
        return rng.choice(WIRE_FLOATS) if rng.random() < 0.4 else rng.uniform(-2000.0, 2000.0)
    if kind == "int":
        return rng.choice([0, 1, 2, 5, 100, 65535, 65536, -1])
    if kind == "bool":
        return rng.random() < 0.7
    if kind == "profile":
        return rng.choice(["trapezoid", "scurve", "step", "TRAPEZOID", "jerk"])
    if kind == "loop":
        return rng.choice(["current", "velocity", "position", "speed"])
    return rng.choice(
        ["a55a", "", "zz", "a55a0402", bytes(rng.randrange(256) for _ in range(12)).hex()]
    )


def make_command(rng: random.Random, duration_s: float) -> dict[str, Any]:
    ctype = rng.choice(sorted(COMMAND_FIELDS) + ["move", "move", "stop", "get_status"])
    t_s: Any = (
        round(rng.uniform(0.0, duration_s), 3)
        if rng.random() < 0.95
        else rng.choice([-1.0, duration_s, "0", math.nan])
    )
    entry: dict[str, Any] = {"t_s": t_s, "type": ctype if rng.random() < 0.97 else "teleport"}
    spec = COMMAND_FIELDS.get(ctype, {})
    for key, (required, kind) in spec.items():
        if key in ("target_deg", "target_mdeg"):
            continue
        if (required and rng.random() < 0.97) or (not required and rng.random() < 0.5):
            entry[key] = _command_value(rng, kind)
    if ctype == "move":
        r = rng.random()
        if r < 0.6:
            entry["target_deg"] = _command_value(rng, "float")
        elif r < 0.95:
            value = _command_value(rng, "float")
            if isinstance(value, float):
                value *= 1000.0
            entry["target_mdeg"] = value
        else:
            entry["target_deg"] = entry["target_mdeg"] = 1.0
    if rng.random() < 0.03:
        entry["speed"] = 1.0
    return entry


def make_bench(rng: random.Random) -> dict[str, Any]:
    data = tomllib.loads(BENCH.read_text())
    mutate_tables(rng, data, rng.choice([1, 1, 1, 2, 3]))
    return data


def make_experiment(rng: random.Random) -> dict[str, Any]:
    duration: Any = rng.choice([0.05, 0.1, 0.2, RUN_S, 1.0, 30.0])
    if rng.random() < 0.05:
        duration = rng.choice([0, -1.0, math.inf, "1", 1e6])
    data: dict[str, Any] = {
        "bench": "paper_bench.toml" if rng.random() < 0.97 else rng.choice(["nope.toml", 3, "."]),
        "duration_s": duration,
    }
    if rng.random() < 0.2:
        data["title"] = rng.choice(["t", 3])
    if rng.random() < 0.4:
        mutate_tables(rng, data, rng.choice([1, 1, 2]))
    d = (
        float(duration)
        if isinstance(duration, int | float)
        and not isinstance(duration, bool)
        and 0 < duration < 1e5
        else 1.0
    )
    commands = [make_command(rng, min(d, RUN_S)) for _ in range(rng.choice([0, 1, 2, 3, 4]))]
    if commands:
        data["command"] = commands
    return data


def file_bytes(rng: random.Random, data: dict[str, Any]) -> bytes:
    text = toml_text(data).encode()
    r = rng.random()
    if r < 0.02:
        return text[: rng.randrange(len(text))]
    if r < 0.04:
        k = rng.randrange(len(text))
        return text[:k] + bytes([rng.randrange(0x80, 0x100)]) + text[k:]  # not UTF-8
    if r < 0.045:
        return bytes(rng.randrange(256) for _ in range(200))
    if r < 0.05:
        return b""
    return text


# ------------------------------------------------------------------------ the oracle


def _clean_line(bench: Any) -> bool:
    u = bench.uart
    return not any((u.bit_flip_rate, u.drop_rate, u.insert_rate, u.burst_rate))


def check_run(exp: Experiment) -> list[str]:
    """Run ``exp`` (capped to ``RUN_S``) and say what is wrong with the run ('' list if
    nothing): an exception, a non-finite log, no telemetry, an unanswered command."""
    duration_s = min(exp.duration_s, RUN_S)
    commands = tuple(c for c in exp.commands if c.t_s < duration_s)
    exp = dataclasses.replace(exp, duration_s=duration_s, commands=commands)
    try:
        result = run(exp, seed=0)
    except Exception as exc:  # noqa: BLE001 - any exception of an accepted file is the finding
        return [f"run raised {type(exc).__name__}: {exc}"]
    problems = []
    log = result.log
    for name in ("pos_deg", "vel_dps", "true_pos_deg", "current_a", "duty", "voltage_v"):
        if not np.all(np.isfinite(getattr(log, name))):
            problems.append(f"log.{name} not finite")
    bench = exp.bench
    byte_s = 10.0 / bench.firmware.telemetry.baud
    frame_s = 34 * byte_s
    if not _clean_line(bench):
        return problems
    tel = result.telemetry_arrays()["tick"]
    if bench.firmware.telemetry.decimation > 0 and duration_s > 0.02 + 8 * frame_s:
        if len(tel) == 0:
            problems.append("no telemetry reached the PC")
    # every command sent early enough is answered (raw bytes may swallow what follows them)
    if any(c.type == "raw" for c in commands):
        return problems
    # Every command but a heartbeat (the board answers none) is answered with its cmd_id;
    # the scripted PC opens a session with a Hello of its own before its first command
    # unless that command is a hello (sim.loop.run), which is answered too.
    answered = {m.cmd_id for m in result.replies if getattr(m, "cmd_id", None) is not None}
    slack_s = 0.02 + 4 * len(commands) * frame_s * max(1, bench.firmware.telemetry.decimation and 2)
    due = [c for c in commands if c.type != "heartbeat" and c.t_s <= duration_s - slack_s]
    expected = len(due) + (1 if commands and commands[0].type != "hello" and due else 0)
    if len(answered) < expected:
        problems.append(
            f"{expected - len(answered)} of {expected} commands unanswered "
            f"({', '.join(f'{c.type} at {c.t_s} s' for c in due)})"
        )
    return problems


def _bench_experiment(bench: Any) -> Experiment:
    """The short script every accepted bench file runs: hello, status, a move, status."""
    return Experiment(
        bench=bench,
        duration_s=RUN_S,
        commands=(
            ScriptedCommand(0.0, "hello"),
            ScriptedCommand(0.01, "get_status"),
            ScriptedCommand(
                0.02, "move", (("target_deg", 5.0), ("v_max_dps", 200.0), ("a_max_dps2", 1000.0))
            ),
            ScriptedCommand(0.1, "get_status"),
        ),
    )


def fuzz_one(rng: random.Random, folder: Path, k: int) -> tuple[str, list[str]]:
    """Generate, load and (if accepted) run one file; returns (outcome, problems)."""
    kind = "bench" if rng.random() < 0.5 else "experiment"
    data = make_bench(rng) if kind == "bench" else make_experiment(rng)
    path = folder / f"{kind}_{k}.toml"
    path.write_bytes(file_bytes(rng, data))
    try:
        loaded = load_bench(path) if kind == "bench" else load_experiment(path)
    except ConfigError as exc:
        text = str(exc)
        bad = []
        if "\n" in text:
            bad.append(f"error of more than one line: {text!r}")
        if not text.startswith(str(path)) and not text.startswith(str(BENCH)):
            bad.append(f"error does not start with the file: {text!r}")
        return "refused", bad
    except Exception as exc:  # noqa: BLE001 - anything but ConfigError is the finding
        return "crashed", [f"load raised {type(exc).__name__}: {exc}"]
    exp = _bench_experiment(loaded) if kind == "bench" else loaded
    return "accepted", check_run(exp)


def test_config_fuzz(tmp_path):
    rng = random.Random(SEED)
    outcomes: Counter[str] = Counter()
    findings = []
    for k in range(N_FILES):
        outcome, problems = fuzz_one(rng, tmp_path, k)
        outcomes[outcome] += 1
        findings.extend(f"file #{k} in {tmp_path} ({outcome}): {p}" for p in problems)
    print(f"config fuzz: {N_FILES} files, {dict(outcomes)}, {len(findings)} findings")
    assert not findings, "\n".join(findings[:20])
    # the generator reaches both sides: enough files accepted and run, enough refused
    assert outcomes["accepted"] >= N_FILES // 5
    assert outcomes["refused"] >= N_FILES // 5


def test_the_generator_writes_what_it_means(tmp_path):
    """The TOML writer round-trips through tomllib (so a refusal is about the value, not
    about a file the generator wrote wrong)."""
    rng = random.Random(1)
    for _ in range(200):
        data = make_experiment(rng) if rng.random() < 0.5 else make_bench(rng)
        text = toml_text(data)
        assert _same_with_nan(tomllib.loads(text), data), text


def _same_with_nan(a: Any, b: Any) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same_with_nan(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same_with_nan(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a):
        return math.isnan(b)
    return a == b and type(a) is type(b)


def _unchecked(cls: type, base: Any, **changes: Any) -> Any:
    """A copy of dataclass ``base`` with ``changes``, bypassing its checks (what a loader
    without them would have let through)."""
    obj = object.__new__(cls)
    for f in dataclasses.fields(cls):
        object.__setattr__(obj, f.name, changes.get(f.name, getattr(base, f.name)))
    return obj


def test_the_oracle_sees_accepted_nonsense():
    """The run check fails on the nonsense the issue found accepted (so the fuzz can fail):
    a UART FIFO smaller than a telemetry frame gives no telemetry; smaller than a Status
    frame also leaves the commands unanswered."""
    from sim.params import UartParams

    bench = load_bench(BENCH)
    assert check_run(_bench_experiment(bench)) == []
    for fifo_bytes, expected in ((30, "no telemetry reached the PC"), (20, "unanswered")):
        uart = _unchecked(UartParams, bench.uart, fifo_bytes=fifo_bytes)
        problems = check_run(_bench_experiment(dataclasses.replace(bench, uart=uart)))
        assert any(expected in p for p in problems), problems
