"""Any recorded run as the PC saw it: ``load_trace(path)`` for ``turntable-sim plot``.

Recognised, by content (not by name, except python-can's log formats):

* a ``run`` log (``log.csv``, the columns of ``sim.loop.LOG_FIELDS``): the firmware's signals
  per tick, with the plant's true current as ``true_current``;
* a telemetry CSV (``monitor --csv``, ``decode``, the reproduction's ``telemetry/*.csv``:
  ``serial_protocol.telemetry_csv``);
* a serial capture, raw or timestamped (``sim.capture``), decoded frame by frame;
* a CAN log (``.asc``, ``.blf``, ``.trc``), reassembled as ``decode`` does.

Each gives a ``sim.reproduce.experiments.Trace`` (measured current = the IS-pin reading the
board reports; the bus voltage the board reports in its telemetry, or a ``log.csv``'s
``bus_v``; none from a file or a board without it). A file with no telemetry in it is an
error naming the file.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from serial_protocol.exceptions import CommandError
from sim.capture import is_can_log, read_chunks
from sim.reproduce.experiments import Trace

__all__ = ["detect_kind", "load_trace"]

_TELEMETRY_KEYS = ("tick", "sp_pos_deg", "sp_vel_dps", "pos_deg", "vel_dps", "duty")
_CSV_SNIFF_BYTES = 4096


def detect_kind(path: str | Path) -> str:
    """``"can"``, ``"log_csv"``, ``"telemetry_csv"`` or ``"capture"``."""
    if is_can_log(path):
        return "can"
    with open(path, "rb") as f:
        head = f.read(_CSV_SNIFF_BYTES)
    first = head.split(b"\n", 1)[0].strip().decode("ascii", errors="replace")
    names = set(first.split(","))
    if {"t_s", "sp_vel_dps", "vel_dps"} <= names:
        return "log_csv" if "true_pos_deg" in names else "telemetry_csv"
    return "capture"


def load_trace(path: str | Path, *, tick_hz: float = 500.0, can_base_id: int = 0x100) -> Trace:
    """Read ``path`` (see the module) into a ``Trace`` named after the file.

    Raises ``CommandError`` naming the file when it cannot be read or holds no telemetry.
    """
    path = Path(path)
    if not tick_hz > 0:
        raise CommandError(f"tick_hz = {tick_hz!r}: must be > 0")
    try:
        kind = detect_kind(path)
        if kind == "can":
            columns = _from_messages(_can_messages(path, can_base_id), tick_hz)
        elif kind == "capture":
            columns = _from_messages(_capture_messages(path), tick_hz)
        else:
            columns = _from_csv(path, kind)
    except OSError as exc:
        raise CommandError(f"cannot read {str(path)!r}: {exc.strerror or exc}") from None
    except (ValueError, KeyError) as exc:
        raise CommandError(f"{str(path)!r}: not a run this tool can read ({exc})") from None
    if columns is None or len(columns["t_s"]) == 0:
        raise CommandError(
            f"{str(path)!r}: no telemetry in it (expected a log.csv, a telemetry CSV, a raw or "
            "timestamped serial capture, or a CAN log)"
        )
    # "log.csv" alone says little in a legend: name it with its folder (run's --out)
    name = path.name if path.name != "log.csv" else f"{path.parent.name}/{path.name}"
    return _trace(name, columns, tick_hz)


def _trace(name: str, c: dict[str, np.ndarray], tick_hz: float) -> Trace:
    empty = ()
    return Trace(
        name=name,
        dt_s=1.0 / tick_hz,
        t_s=c["t_s"],
        sp_pos_deg=c["sp_pos_deg"],
        sp_vel_dps=c["sp_vel_dps"],
        pos_deg=c["pos_deg"],
        vel_dps=c["vel_dps"],
        current_a=c["current_meas_a"],
        duty=c["duty"],
        state=c["state"].astype(np.int64),
        fault=c["fault"].astype(np.int64),
        command_t_s=empty,
        command_target_deg=empty,
        command_a_max_dps2=empty,
        replies=empty,
        true_t_s=c.get("true_t_s", np.zeros(0)),
        true_current_a=c.get("true_current_a", np.zeros(0)),
        bus_voltage_v=c.get("bus_voltage_v", np.zeros(0)),
    )


def _from_csv(path: Path, kind: str) -> dict[str, np.ndarray]:
    from serial_protocol.messages import Fault, State

    with open(path, newline="", encoding="utf-8", errors="replace") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return {"t_s": np.zeros(0)}

    def col(*names: str) -> np.ndarray:
        for name in names:
            if name in rows[0]:
                return np.array([float(r[name]) for r in rows])
        raise KeyError(f"no column {' or '.join(names)}")

    def code(name: str, enum: type) -> np.ndarray:
        values = [r[name] for r in rows]
        return np.array([enum[v].value if v in enum.__members__ else int(v) for v in values])

    out = {
        "t_s": col("t_s"),
        "sp_pos_deg": col("sp_pos_deg"),
        "sp_vel_dps": col("sp_vel_dps"),
        "pos_deg": col("pos_deg"),
        "vel_dps": col("vel_dps"),
        # measured (IS pin); "current_a" is the column name before the rename
        "current_meas_a": col("current_meas_a", "current_a"),
        "duty": col("duty"),
        "state": code("state", State),
        "fault": code("fault", Fault),
    }
    # appended column: older telemetry CSVs have none
    for name in ("bus_voltage_v", "bus_v") if kind == "log_csv" else ("bus_voltage_v",):
        if name in rows[0]:
            out["bus_voltage_v"] = col(name)
            break
    if kind == "log_csv":
        out["true_t_s"] = out["t_s"]
        out["true_current_a"] = col("true_current_a", "current_a")
        if "current_meas_a" in rows[0]:
            out["current_meas_a"] = col("current_meas_a")
    return out


def _capture_messages(path: Path) -> list:
    from serial_protocol.frame import Decoder

    decoder = Decoder()
    messages: list = []
    with open(path, "rb") as f:
        for _, data in read_chunks(f):
            messages += decoder.feed(data)
    return messages + decoder.flush()


def _can_messages(path: Path, base_id: int) -> list:
    import can

    from serial_protocol.can_link import CanReassembler

    reassembler = CanReassembler(base_id)
    messages = []
    for frame in can.LogReader(str(path)):
        if not frame.is_extended_id and not frame.is_remote_frame:
            msg = reassembler.feed(frame.arbitration_id, bytes(frame.data))
            if msg is not None:
                messages.append(msg)
    return messages


def _from_messages(messages: list, tick_hz: float) -> dict[str, np.ndarray]:
    from serial_protocol.messages import Telemetry

    tel = [m for m in messages if isinstance(m, Telemetry)]
    if not tel:
        return {"t_s": np.zeros(0)}
    # The tick counter is u32 on the wire: unwrap it so that time keeps increasing.
    ticks = np.array([m.tick for m in tel], dtype=np.int64)
    steps = np.diff(ticks) & 0xFFFFFFFF
    ticks = ticks[0] + np.concatenate(([0], np.cumsum(steps)))
    out = {"t_s": ticks / tick_hz}
    for name in ("sp_pos_deg", "sp_vel_dps", "pos_deg", "vel_dps", "duty"):
        out[name] = np.array([getattr(m, name) for m in tel], dtype=float)
    out["current_meas_a"] = np.array([m.current_a for m in tel], dtype=float)
    out["state"] = np.array([int(m.state) for m in tel])
    out["fault"] = np.array([int(m.fault) for m in tel])
    out["bus_voltage_v"] = np.array([m.bus_voltage_v for m in tel], dtype=float)
    return out
