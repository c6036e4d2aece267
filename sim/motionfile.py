"""Program files and point files: what ``monitor --program`` / ``--stream``, the shell's
``program`` / ``stream`` and ``run`` experiment files send to the board.

A **program file** (TOML) lists the blocks of a motion program (docs/protocol.md 4.5)::

    title = "inspection scan"        # optional
    v_max_dps = 300.0                # default speed limit of the blocks (optional)

    [[segment]]
    target_deg = 40.0
    v_max_dps = 60.0                 # this block's speed limit (or the default above)
    dwell_s = 0.5                    # rest at the target (optional, default 0)

A **point file** is a stream (docs/protocol.md 4.6), either TOML::

    period_s = 0.15
    interp = "cubic"                 # "linear" (default without vel_dps) or "cubic"
    pos_deg = [0.9375, 3.75, ...]    # points 1, 2, ... (point 0 is where the axis rests)
    vel_dps = [12.5, 25.0, ...]      # optional; required by "cubic"

or CSV with a header ``pos_deg`` or ``pos_deg,vel_dps`` (one point a line; the period is
then given by the caller). Positions are absolute axis degrees.

A bad file is one :class:`ConfigError` naming the file, the key (or line) and the value;
values are checked against what their wire fields can carry, not against a board's limits
(the board refuses those, naming the field).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from serial_protocol.exceptions import ConfigError
from serial_protocol.messages import Interp

__all__ = ["Program", "PointStreamFile", "load_points", "load_program"]

# What the wire can carry (docs/protocol.md 4.1): an i32 in 1e-4 deg; an f32.
_POS_MAX_DEG = (2**31 - 1) / 10_000.0
_F32_MAX = 3.4028234663852886e38
#: Most blocks and points a file may hold (a sanity bound: a program is sent with flow
#: control, so this is not the board's queue size).
MAX_BLOCKS = 100_000
MAX_POINTS = 10_000_000


@dataclass(frozen=True)
class Program:
    """Blocks ``(target_deg, v_max_dps, dwell_s)`` in order."""

    blocks: tuple[tuple[float, float, float], ...]
    title: str = ""
    path: Path | None = None


@dataclass(frozen=True)
class PointStreamFile:
    """Points 1..n of a stream: ``pos_deg`` and, for PVT, ``vel_dps`` (same length)."""

    pos_deg: tuple[float, ...]
    vel_dps: tuple[float, ...] | None
    period_s: float | None
    interp: Interp
    path: Path | None = None


def _read(path: Path) -> dict[str, Any]:
    from sim.config import _read_toml

    return _read_toml(path)


def _number(where: str, key: str, value: Any, *, low: float, high: float, unit: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{where} {key} = {value!r}: must be a number ({unit})")
    if not math.isfinite(value) or not low <= value <= high:
        raise ConfigError(f"{where} {key} = {value!r}: must be in [{low:g}, {high:g}] {unit}")
    return float(value)


def load_program(path: str | Path) -> Program:
    """Read a program file (see the module docstring)."""
    file = Path(path)
    data = _read(file)
    top = f"{file}: [top]"
    for key in data:
        if key not in ("title", "v_max_dps", "segment"):
            raise ConfigError(f"{top} {key} = {data[key]!r}: unknown key (title, v_max_dps, "
                              "[[segment]])")  # fmt: skip
    title = data.get("title", "")
    if not isinstance(title, str):
        raise ConfigError(f"{top} title = {title!r}: must be a string")
    default_v = data.get("v_max_dps")
    if default_v is not None:
        default_v = _number(top, "v_max_dps", default_v, low=0.0, high=_F32_MAX, unit="deg/s")
    rows = data.get("segment")
    if not isinstance(rows, list) or not rows:
        raise ConfigError(f"{top} segment = {rows!r}: give the blocks as [[segment]] tables")
    if len(rows) > MAX_BLOCKS:
        raise ConfigError(f"{top} segment: {len(rows)} blocks, at most {MAX_BLOCKS}")
    blocks = []
    for k, row in enumerate(rows):
        where = f"{file}: [segment #{k + 1}]"
        if not isinstance(row, dict):
            raise ConfigError(f"{where}: must be a table")
        for key in row:
            if key not in ("target_deg", "v_max_dps", "dwell_s"):
                raise ConfigError(f"{where} {key} = {row[key]!r}: unknown key (target_deg, "
                                  "v_max_dps, dwell_s)")  # fmt: skip
        if "target_deg" not in row:
            raise ConfigError(f"{where} target_deg = <missing>: every block needs its target")
        target = _number(where, "target_deg", row["target_deg"], low=-_POS_MAX_DEG,
                         high=_POS_MAX_DEG, unit="deg")  # fmt: skip
        v = row.get("v_max_dps", default_v)
        if v is None:
            raise ConfigError(f"{where} v_max_dps = <missing>: give it here or at the top")
        v = _number(where, "v_max_dps", v, low=0.0, high=_F32_MAX, unit="deg/s")
        dwell = _number(where, "dwell_s", row.get("dwell_s", 0.0), low=0.0, high=_F32_MAX,
                        unit="s")  # fmt: skip
        blocks.append((target, v, dwell))
    return Program(tuple(blocks), title, file)


def load_points(path: str | Path, period_s: float | None = None) -> PointStreamFile:
    """Read a point file, TOML or CSV (by its extension); ``period_s`` is required for a
    CSV file and overrides a TOML file's."""
    file = Path(path)
    if file.suffix.lower() == ".csv":
        pos, vel = _csv_points(file)
        interp = Interp.CUBIC if vel is not None else Interp.LINEAR
        period = period_s
    else:
        data = _read(file)
        top = f"{file}: [top]"
        for key in data:
            if key not in ("period_s", "interp", "pos_deg", "vel_dps"):
                raise ConfigError(f"{top} {key} = {data[key]!r}: unknown key (period_s, "
                                  "interp, pos_deg, vel_dps)")  # fmt: skip
        pos = _array(top, "pos_deg", data.get("pos_deg"), _POS_MAX_DEG, "deg")
        vel = None
        if "vel_dps" in data:
            vel = _array(top, "vel_dps", data["vel_dps"], _F32_MAX, "deg/s")
            if len(vel) != len(pos):
                raise ConfigError(f"{top} vel_dps: {len(vel)} values for {len(pos)} positions")
        names = {i.name.lower(): i for i in Interp}
        word = data.get("interp", "cubic" if vel is not None else "linear")
        if word not in names:
            raise ConfigError(f"{top} interp = {word!r}: must be one of {sorted(names)}")
        interp = names[word]
        if interp is Interp.CUBIC and vel is None:
            raise ConfigError(f"{top} interp = 'cubic': needs vel_dps (positions and velocities)")
        period = period_s if period_s is not None else data.get("period_s")
    where = f"{file}: [top]"
    if period is None:
        raise ConfigError(f"{where} period_s = <missing>: give the period between points")
    period = _number(where, "period_s", period, low=0.0, high=_F32_MAX, unit="s")
    if period <= 0.0:
        raise ConfigError(f"{where} period_s = {period!r}: must be > 0 s")
    return PointStreamFile(pos, vel, period, interp, file)


def _array(where: str, key: str, value: Any, bound: float, unit: str) -> tuple[float, ...]:
    if not isinstance(value, list) or not value:
        raise ConfigError(f"{where} {key} = {value!r}: must be a non-empty array of numbers")
    if len(value) > MAX_POINTS:
        raise ConfigError(f"{where} {key}: {len(value)} points, at most {MAX_POINTS}")
    out = []
    for k, x in enumerate(value):
        out.append(_number(where, f"{key}[{k}]", x, low=-bound, high=bound, unit=unit))
    return tuple(out)


def _csv_points(file: Path) -> tuple[tuple[float, ...], tuple[float, ...] | None]:
    try:
        with open(file, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except FileNotFoundError:
        raise ConfigError(f"{file}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{file}: cannot read: {exc}") from None
    if not rows or [c.strip() for c in rows[0]] not in (["pos_deg"], ["pos_deg", "vel_dps"]):
        head = rows[0] if rows else "<empty>"
        raise ConfigError(f"{file}: line 1 = {head!r}: the header must be pos_deg or "
                          "pos_deg,vel_dps")  # fmt: skip
    cols = len(rows[0])
    pos: list[float] = []
    vel: list[float] = []
    for line, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        if len(row) != cols:
            raise ConfigError(f"{file}: line {line} = {row!r}: {cols} values expected")
        try:
            values = [float(c) for c in row]
        except ValueError:
            raise ConfigError(f"{file}: line {line} = {row!r}: not a number") from None
        p = _number(f"{file}: line {line}", "pos_deg", values[0], low=-_POS_MAX_DEG,
                    high=_POS_MAX_DEG, unit="deg")  # fmt: skip
        pos.append(p)
        if cols == 2:
            vel.append(_number(f"{file}: line {line}", "vel_dps", values[1], low=-_F32_MAX,
                               high=_F32_MAX, unit="deg/s"))  # fmt: skip
    if not pos:
        raise ConfigError(f"{file}: no points after the header")
    if len(pos) > MAX_POINTS:
        raise ConfigError(f"{file}: {len(pos)} points, at most {MAX_POINTS}")
    return tuple(pos), (tuple(vel) if cols == 2 else None)
