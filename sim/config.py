"""TOML bench and experiment files -> frozen dataclasses (the only place raw dicts live).

The loader is generic over ``sim.params.TABLES`` and ``firmware_model.params.TABLES`` (TOML
table path -> dataclass). Each dataclass validates its own fields and raises
``ValueError("key = value: reason")``; every problem here comes out as a ``ConfigError``
naming the file, the table, the key and the value.

A bench file holds the tables. An experiment file names its bench (``bench = "x.toml"``,
relative to the experiment file, else a built-in config), may override any bench table key
by key, and lists timed ``[[command]]`` entries (see README, "Config format").
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import bench_configs
from firmware_model import params as fw_params
from firmware_model import units
from serial_protocol import messages as msg
from serial_protocol.exceptions import ConfigError
from sim import params as sim_params
from sim import wire

__all__ = [
    "BenchConfig",
    "COMMAND_FIELDS",
    "Experiment",
    "ScriptedCommand",
    "build_tables",
    "load_bench",
    "load_experiment",
]

TABLES: dict[str, type] = {**sim_params.TABLES, **fw_params.TABLES}


@dataclass(frozen=True)
class BenchConfig:
    """A whole bench: the plant, the firmware, the UART and the loop settings."""

    plant: sim_params.PlantParams = field(default_factory=sim_params.PlantParams)
    firmware: fw_params.FirmwareParams = field(default_factory=fw_params.FirmwareParams)
    uart: sim_params.UartParams = field(default_factory=sim_params.UartParams)
    loop: sim_params.LoopParams = field(default_factory=sim_params.LoopParams)
    path: Path | None = None

    @property
    def dt_s(self) -> float:
        """Servo tick (2 ms at 500 Hz)."""
        return self.firmware.servo.dt_s


# Scripted command type -> {TOML key: (required?, kind)}; kinds are checked in _command.
COMMAND_FIELDS: dict[str, dict[str, tuple[bool, str]]] = {
    "hello": {},
    "move": {
        "target_mdeg": (False, "float"),
        "target_deg": (False, "float"),
        "v_max_dps": (True, "float"),
        "a_max_dps2": (True, "float"),
        "j_max_dps3": (False, "float"),
        "profile": (False, "profile"),
    },
    "stop": {"a_max_dps2": (False, "float")},
    "set_gains": {
        "loop": (True, "loop"),
        "kp": (True, "float"),
        "ki": (True, "float"),
        "kd": (False, "float"),
    },
    "get_gains": {"loop": (True, "loop")},
    "set_limits": {
        "v_max_dps": (True, "float"),
        "a_max_dps2": (True, "float"),
        "current_limit_a": (True, "float"),
        "following_error_deg": (True, "float"),
        "over_current_trip_a": (False, "float"),
        "bus_over_voltage_v": (False, "float"),
        "bus_under_voltage_v": (False, "float"),
        "thermal_derate_c": (False, "float"),
        "thermal_trip_c": (False, "float"),
        "brake_current_limit_a": (False, "float"),
    },
    "get_limits": {},
    "get_fault": {"bit": (True, "int")},
    "heartbeat": {},
    "get_status": {},
    "clear_fault": {},
    "set_enable": {"enable": (True, "bool")},
    "set_telemetry": {"decimation": (True, "int")},
    # Programs, streams and jog (docs/protocol.md 4.5-4.7).
    "queue_segment": {
        "target_deg": (True, "float"),
        "v_max_dps": (True, "float"),
        "dwell_s": (False, "float"),
    },
    "queue_control": {"action": (True, "queue_action"), "override_pct": (False, "float")},
    "jog": {"vel_dps": (True, "float"), "a_max_dps2": (True, "float"),
            "timeout_ms": (False, "int")},  # fmt: skip
    "stream_control": {
        "action": (True, "stream_action"),
        "interp": (False, "interp"),
        "period_s": (False, "float"),
        "prefill": (False, "int"),
    },
    # A program file's blocks, sent one after the other at t_s (at most the queue's size:
    # a run file has no flow control).
    "program": {"file": (True, "path")},
    # A point file streamed from t_s: START, the points five to a frame, each frame sent
    # STREAM_LEAD_POINTS points ahead of the axis, then END (sim.motionfile).
    "stream": {"file": (True, "path"), "period_s": (False, "float"), "prefill": (False, "int")},
    # Bytes sent as they are (hex string): for protocol fault-injection experiments.
    "raw": {"hex": (True, "hex")},
}
#: Points a run file's stream keeps the board ahead of the axis (the board holds 64).
STREAM_LEAD_POINTS = 48


@dataclass(frozen=True)
class ScriptedCommand:
    """One timed command of an experiment, validated; ``message(cmd_id)`` builds it."""

    t_s: float
    type: str
    fields: tuple[tuple[str, Any], ...] = ()

    def get(self, key: str, default: Any = None) -> Any:
        return dict(self.fields).get(key, default)

    def message(self, cmd_id: int, session: int = 0) -> msg.Message | bytes:
        """The wire message (or raw bytes for ``type = "raw"``) with ``cmd_id``, in
        ``session`` (for ``hello``: the session it opens)."""
        return self._message(cmd_id) if self.type == "raw" else dataclasses.replace(
            self._message(cmd_id), session=session  # type: ignore[type-var]
        )

    def _message(self, cmd_id: int) -> msg.Message | bytes:
        f = dict(self.fields)
        if self.type == "raw":
            return bytes.fromhex(f["hex"])
        if self.type == "hello":
            return msg.Hello(cmd_id)
        if self.type == "move":
            target = f["target_deg"] if "target_deg" in f else f["target_mdeg"] / 1000.0
            return msg.Move(
                cmd_id=cmd_id,
                target_deg=target,
                v_max_dps=f["v_max_dps"],
                a_max_dps2=f["a_max_dps2"],
                j_max_dps3=f.get("j_max_dps3", 0.0),
                profile=f.get("profile", msg.Profile.TRAPEZOID),
            )
        if self.type == "stop":
            return msg.Stop(cmd_id=cmd_id, a_max_dps2=f.get("a_max_dps2", 0.0))
        if self.type == "set_gains":
            return msg.SetGains(cmd_id, f["loop"], f["kp"], f["ki"], f.get("kd", 0.0))
        if self.type == "get_gains":
            return msg.GetGains(cmd_id, f["loop"])
        if self.type == "set_limits":
            return msg.SetLimits(
                cmd_id,
                f["v_max_dps"],
                f["a_max_dps2"],
                f["current_limit_a"],
                f["following_error_deg"],
                f.get("over_current_trip_a", 0.0),
                bus_over_voltage_v=f.get("bus_over_voltage_v", 0.0),
                bus_under_voltage_v=f.get("bus_under_voltage_v", 0.0),
                thermal_derate_c=f.get("thermal_derate_c", 0.0),
                thermal_trip_c=f.get("thermal_trip_c", 0.0),
                brake_current_limit_a=f.get("brake_current_limit_a", 0.0),
            )
        if self.type == "get_limits":
            return msg.GetLimits(cmd_id)
        if self.type == "get_fault":
            return msg.GetFault(cmd_id, f["bit"])
        if self.type == "heartbeat":
            return msg.Heartbeat(cmd_id)
        if self.type == "get_status":
            return msg.GetStatus(cmd_id)
        if self.type == "clear_fault":
            return msg.ClearFault(cmd_id)
        if self.type == "set_enable":
            return msg.SetEnable(cmd_id, f["enable"])
        if self.type == "queue_segment":
            return msg.QueueSegment(cmd_id, f["target_deg"], f["v_max_dps"], f.get("dwell_s", 0.0))
        if self.type == "queue_control":
            return msg.QueueControl(cmd_id, f["action"], f.get("override_pct", 100.0))
        if self.type == "jog":
            return msg.Jog(cmd_id, f["vel_dps"], f["a_max_dps2"], f.get("timeout_ms", 0))
        if self.type == "stream_control":
            return msg.StreamControl(cmd_id, f["action"], f.get("interp", msg.Interp.LINEAR),
                                     f.get("period_s", 0.0), f.get("prefill", 1))  # fmt: skip
        if self.type == "stream_points":  # made by a "stream" entry, not written in files
            return msg.StreamPoints.of(cmd_id, f["first_index"], f["pos_deg"], f["vel_dps"])
        return msg.SetTelemetry(cmd_id, f["decimation"])


@dataclass(frozen=True)
class Experiment:
    """A bench, a duration and the timed commands the simulated PC sends."""

    bench: BenchConfig
    duration_s: float
    commands: tuple[ScriptedCommand, ...] = ()
    path: Path | None = None
    title: str = ""


# ------------------------------------------------------------------------ loading


def _where(file: Path | str | None, table: str) -> str:
    return f"{file if file is not None else '<config>'}: [{table}]"


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a folder, not a TOML file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{path}: not valid TOML: not UTF-8 (byte {exc.object[exc.start]:#04x} at offset "
            f"{exc.start})"
        ) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None


def _lookup(data: Mapping[str, Any], dotted: str) -> Mapping[str, Any] | None:
    node: Any = data
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return None
        node = node[part]
    return node


def _field_types(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _type_problem(value: Any, hint: Any) -> str:
    """Why ``value`` cannot be a field declared ``hint`` ('' if it can, or if unsure)."""
    if isinstance(value, list):
        # A file describes one bench: one value per key. Per-member arrays for a batch are
        # given to ``Simulation(overrides=...)``, not written in a file.
        return "must be a single value, not a list (one bench per file)"
    is_number = isinstance(value, int | float) and not isinstance(value, bool)
    if hint is float and not is_number:
        return "must be a number"
    if hint is int and (isinstance(value, bool) or not isinstance(value, int)):
        return "must be an integer"
    if hint is bool and not isinstance(value, bool):
        return "must be true or false"
    if hint is str and not isinstance(value, str):
        return "must be a string"
    return ""


def _coerce(value: Any, hint: Any) -> Any:
    """TOML value -> field value: ints where a float is declared become floats (an int too
    large for a float is refused by the check that follows); anything else goes to the
    dataclass's own checks unchanged."""
    if hint is float and isinstance(value, int) and not isinstance(value, bool):
        try:
            return float(value)
        except OverflowError:
            return math.inf
    return value


#: Physical sanity ranges of the plant's keys in a file (or ``serve --set``): wide ranges
#: around the bench's parts; outside them a number is a typo (a motor of 1000 ohm, a platter
#: of 1e9 kg m^2), and the model is not made for it. The dataclasses themselves only refuse
#: what cannot be computed (tests and studies may build extreme plants in code).
SANITY: dict[tuple[str, str], tuple[float, float, str]] = {
    ("supply", "voltage_v"): (5.5, 27.8, "the BTN7971B's operating supply range"),
    ("supply", "source_resistance_ohm"): (1e-4, 10.0, "a supply's output and leads"),
    ("supply", "bulk_capacitance_uf"): (1.0, 1e6, "a bus capacitor bank"),
    ("supply", "logic_load_a"): (0.0, 5.0, "the logic's draw"),
    ("supply", "brake_resistor_ohm"): (0.0, 1e4, "a brake resistor"),
    ("supply", "brake_on_v"): (5.5, 60.0, "a brake chopper's threshold"),
    ("supply", "sense_divider_ratio"): (1.0, 1000.0, "a divider into an ADC pin"),
    ("supply", "bus_quiet_v"): (0.0, 1.0, "a swing of the rail within a period, not a fault"),
    ("supply", "tvs_breakdown_v"): (0.0, 60.0, "a TVS across a 24 V rail"),
    ("supply", "tvs_resistance_ohm"): (0.01, 100.0, "a TVS's dynamic resistance"),
    ("bridge", "ov_lockout_v"): (20.0, 60.0, "a bridge's over-voltage lock-out"),
    ("bridge", "ov_release_v"): (20.0, 60.0, "a bridge's over-voltage lock-out"),
    ("bridge", "uv_lockout_v"): (1.0, 20.0, "a bridge's under-voltage lock-out"),
    ("bridge", "uv_release_v"): (1.0, 20.0, "a bridge's under-voltage lock-out"),
    ("bridge", "pulse_shift_with_current_us"): (-20.0, 20.0, "a bridge's switching delays"),
    ("bridge", "pulse_shift_against_current_us"): (-20.0, 20.0, "a bridge's switching delays"),
    ("bridge", "r_on_path_ohm"): (0.0, 10.0, "a bridge path, not a resistor bank"),
    ("bridge", "timer_clock_hz"): (1e6, 72e6, "the STM32F103's timer clock"),
    ("bridge", "pwm_hz"): (100.0, 100e3, "a PWM the BTN7971B can switch"),
    ("bridge", "current_limit_a"): (0.1, 200.0, "the chip's own current limitation"),
    ("bridge", "diode_drop_v"): (0.0, 5.0, "a power diode's forward drop"),
    ("current_sense", "k_ilis"): (100.0, 1e6, "a current-sense ratio"),
    ("current_sense", "r_is_ohm"): (1.0, 1e6, "a sense resistor"),
    ("current_sense", "adc_vref_v"): (0.5, 5.5, "an ADC reference"),
    ("current_sense", "noise_rms_lsb"): (0.0, 1000.0, "ADC noise"),
    ("current_sense", "is_offset_ua"): (0.0, 1000.0, "an IS pin's offset current"),
    ("current_sense", "is_settling_us"): (0.0, 50.0, "an IS pin's settling time"),
    ("current_sense", "is_filter_us"): (0.0, 1000.0, "an RC low-pass on the IS pin"),
    ("current_sense", "is_offset_mismatch_ua"): (-2000.0, 2000.0, "two IS pins' offsets apart"),
    ("motor", "r_ohm"): (1e-3, 1e3, "a DC motor's armature resistance"),
    ("motor", "l_h"): (1e-6, 1.0, "a DC motor's armature inductance"),
    ("motor", "kt_nm_a"): (1e-4, 10.0, "a DC motor's torque constant"),
    ("motor", "ke_v_s_rad"): (1e-4, 10.0, "a DC motor's back-EMF constant"),
    ("motor", "j_kgm2"): (1e-9, 1.0, "a DC motor's rotor inertia"),
    ("motor", "viscous_nm_s_rad"): (0.0, 1.0, "a DC motor's viscous friction"),
    ("motor", "coulomb_nm"): (0.0, 10.0, "a DC motor's dry friction"),
    ("motor", "coulomb_band_rad_s"): (1e-6, 1e3, "a friction smoothing band"),
    ("motor", "stiction_nm"): (0.0, 10.0, "a DC motor's breakaway friction"),
    ("motor", "stribeck_rad_s"): (0.0, 1e3, "a Stribeck speed"),
    ("gearbox", "backlash_deg"): (0.0, 90.0, "a gearbox's backlash"),
    ("gearbox", "drag_nm"): (0.0, 10.0, "a gearbox's no-load drag at the motor"),
    ("gearbox", "drag_viscous_nm_s_rad"): (0.0, 1.0, "a gearbox's viscous drag at the motor"),
    ("belt", "small_teeth"): (8, 1000, "a timing pulley"),
    ("belt", "large_teeth"): (8, 1000, "a timing pulley"),
    ("belt", "stiffness_nm_rad"): (1.0, 1e9, "a timing belt's stiffness"),
    ("belt", "damping_nm_s_rad"): (0.0, 1e6, "a timing belt's damping"),
    ("platter", "j_kgm2"): (1e-6, 1e4, "a platter's inertia"),
    ("platter", "coulomb_nm"): (0.0, 1e4, "a slewing bearing's friction"),
    ("platter", "viscous_nm_s_rad"): (0.0, 1e4, "a slewing bearing's viscous friction"),
    ("platter", "coulomb_band_rad_s"): (1e-9, 1e3, "a friction smoothing band"),
    ("platter", "stiction_nm"): (0.0, 1e4, "a slewing bearing's breakaway friction"),
    ("platter", "stribeck_rad_s"): (0.0, 1e3, "a Stribeck speed"),
    ("encoder", "noise_rms_lsb"): (0.0, 1000.0, "encoder noise"),
    ("thermal", "ambient_c"): (-40.0, 85.0, "a room or an enclosure"),
    ("thermal", "alpha_cu_per_k"): (0.0, 0.01, "a conductor's temperature coefficient"),
    ("thermal", "magnet_tc_per_k"): (-0.005, 0.0, "a magnet's remanence coefficient"),
    ("thermal", "r_winding_housing_k_w"): (0.01, 100.0, "a motor's thermal resistance"),
    ("thermal", "r_housing_ambient_k_w"): (0.01, 100.0, "a motor's thermal resistance"),
    ("thermal", "tau_winding_s"): (0.1, 3600.0, "a winding's thermal time constant"),
    ("thermal", "tau_housing_s"): (1.0, 1e5, "a motor's thermal time constant"),
}


def sanity_problem(table: str, key: str, value: Any) -> str:
    """Why ``value`` is outside the physical range of ``[table] key`` ('' if it is not, or
    if the key has no such range)."""
    span = SANITY.get((table, key))
    if span is None or isinstance(value, bool) or not isinstance(value, int | float):
        return ""
    lo, hi, why = span
    if lo <= value <= hi:
        return ""
    return f"must be in [{lo:g}, {hi:g}] ({why})"


def _build(cls: type, values: Mapping[str, Any], file: Any, table: str) -> Any:
    hints = _field_types(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    for key, value in values.items():
        if key not in known:
            raise ConfigError(
                f"{_where(file, table)} {key} = {value!r}: unknown key "
                f"(known: {', '.join(sorted(known))})"
            )
    kwargs = {}
    for key, value in values.items():
        reason = _type_problem(value, hints.get(key))
        if reason:
            raise ConfigError(f"{_where(file, table)} {key} = {value!r}: {reason}")
        kwargs[key] = _coerce(value, hints.get(key))
    try:
        built = cls(**kwargs)
    except (ValueError, TypeError) as exc:
        text = str(exc)
        key = text.split(" = ", 1)[0] if " = " in text else "?"
        raw = values.get(key, "?")
        # "key = value: reason" from the dataclass: say the key and value once
        text = text.removeprefix(f"{key} = {kwargs.get(key)!r}: ")
        raise ConfigError(f"{_where(file, table)} {key} = {raw!r}: {text}") from None
    for key, value in values.items():
        reason = sanity_problem(table, key, value)
        if reason:
            raise ConfigError(f"{_where(file, table)} {key} = {value!r}: {reason}")
    return built


def _collect_table_paths(data: Mapping[str, Any], prefix: str = "") -> list[str]:
    """Every table path in ``data`` whose values are not all sub-tables."""
    paths = []
    for key, value in data.items():
        if isinstance(value, Mapping):
            path = prefix + key
            if any(not isinstance(v, Mapping) for v in value.values()) or not value:
                paths.append(path)
            paths.extend(_collect_table_paths(value, path + "."))
    return paths


def build_tables(data: Mapping[str, Any], file: Any = None) -> dict[str, Any]:
    """``{table path: dataclass}`` for every known table (defaults where absent)."""
    for path in _collect_table_paths(data):
        if path not in TABLES:
            raise ConfigError(
                f"{_where(file, path)}: unknown table (known: {', '.join(sorted(TABLES))})"
            )
    tables = {}
    for path, cls in TABLES.items():
        values = _lookup(data, path) or {}
        plain = {k: v for k, v in values.items() if not isinstance(v, Mapping)}
        tables[path] = _build(cls, plain, file, path)
    return tables


def bench_from_tables(
    tables: Mapping[str, Any], file: Any = None, *, errors_in: Any = None
) -> BenchConfig:
    """The ``BenchConfig`` of built tables (``build_tables``); ``file`` is its path, errors
    name ``errors_in`` (default ``file``: an experiment's overrides name the experiment)."""
    where = file if errors_in is None else errors_in
    plant_fields = {f.name for f in dataclasses.fields(sim_params.PlantParams)}
    plant = sim_params.PlantParams(**{k: v for k, v in tables.items() if k in plant_fields})
    try:
        firmware = fw_params.FirmwareParams.from_tables(dict(tables))
    except ValueError as exc:
        text = str(exc)
        key = text.split(" = ", 1)[0]
        table = next(
            (p for p, cls in fw_params.TABLES.items() if key in _field_types(cls)), "firmware"
        )
        raise ConfigError(f"{_where(where, table)} {text}") from None
    bench = BenchConfig(
        plant=plant,
        firmware=firmware,
        uart=tables["uart"],
        loop=tables["loop"],
        path=Path(file) if file is not None else None,
    )
    check_bench(bench, where)
    return bench


#: Plant values the firmware model is written for (``firmware_model/units.py``): its counts
#: to degrees scaling, the Q16.16 position format (one count = 18 raw units exactly) and the
#: unwrapping all assume them, so a bench with other values would be simulated wrongly.
FIRMWARE_FIXED: tuple[tuple[str, str, float, str], ...] = (
    ("encoder", "bits", units.ENCODER_BITS, "the AS5048's 14 bits"),
    ("gearbox", "ratio", units.GEAR_RATIO, "the 80:1 gearmotor"),
)


def check_bench(bench: BenchConfig, file: Any = None, *, nominal: bool = True) -> None:
    """Cross-table checks of a whole bench: the plant values the firmware hard-codes must be
    those, and (``nominal``) the firmware's nominal numbers must describe the plant it runs
    on. Raises ``ConfigError`` naming the key that is wrong. ``Simulation`` overrides are
    checked with ``nominal=False``: a plant spread around the firmware's nominal values is
    what a robustness study is made of."""
    plant = bench.plant
    for table, key, fixed, what in FIRMWARE_FIXED:
        value = getattr(getattr(plant, table), key)
        if not np.all(np.asarray(value) == fixed):
            raise ConfigError(
                f"{_where(file, table)} {key} = {_plain(value)!r}: the firmware model is "
                f"written for {what} ({key} = {fixed:g}; firmware_model/units.py), so no "
                "other value is accepted"
            )
    if not nominal:
        return
    cur = bench.firmware.current
    pairs = [
        ("controller.current", "pwm_arr", cur.pwm_arr, plant.bridge.arr, "bridge"),
        ("controller.current", "supply_v", cur.supply_v, plant.supply.voltage_v, "supply"),
        (
            "controller.current",
            "adc_bits",
            cur.adc_bits,
            plant.current_sense.adc_bits,
            "current_sense",
        ),
    ]
    for table, key, fw_value, plant_value, plant_table in pairs:
        if not np.all(np.asarray(fw_value) == np.asarray(plant_value)):
            raise ConfigError(
                f"{_where(file, table)} {key} = {_plain(fw_value)!r}: the bench's "
                f"[{plant_table}] gives {_plain(plant_value)!r} (firmware and plant must agree)"
            )


def _plain(value: Any) -> Any:
    """A parameter as written in a file (arrays as lists) for messages."""
    return value.tolist() if isinstance(value, np.ndarray) else value


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def load_bench(path: str | Path, overrides: Mapping[str, Any] | None = None) -> BenchConfig:
    """Load a bench TOML file; ``overrides`` is a nested dict merged over it first."""
    file = Path(path)
    data = _read_toml(file)
    if overrides:
        data = _merge(data, overrides)
    return bench_from_tables(build_tables(data, file), file)


def _resolve_bench(name: Any, file: Path) -> Path:
    if not isinstance(name, str) or not name:
        raise ConfigError(f"{file}: [top] bench = {name!r}: must name a bench TOML file")
    beside = (file.parent / name).resolve()
    if beside.is_file():
        return beside
    try:
        return bench_configs.path(name)
    except FileNotFoundError:
        raise ConfigError(f"{file}: [top] bench = {name!r}: no such file") from None


def _kind(value: Any, kind: str) -> Any:
    """Check one command field; return the value to use or raise ValueError(reason)."""
    if kind == "float":
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError("must be a number")
        if not math.isfinite(value):
            raise ValueError("must be finite (send NaN with type = 'raw' to test NACKs)")
        return float(value)
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError("must be an integer")
        return value
    if kind == "bool":
        if not isinstance(value, bool):
            raise ValueError("must be true or false")
        return value
    if kind == "profile":
        names = {p.name.lower(): p for p in msg.Profile}
        if not isinstance(value, str) or value not in names:
            raise ValueError(f"must be one of {sorted(names)}")
        return names[value]
    if kind in ("queue_action", "stream_action", "interp"):
        enum = {"queue_action": msg.QueueAction, "stream_action": msg.StreamAction,
                "interp": msg.Interp}[kind]  # fmt: skip
        names = {p.name.lower(): p for p in enum}
        if not isinstance(value, str) or value not in names:
            raise ValueError(f"must be one of {sorted(names)}")
        return names[value]
    if kind == "path":
        if not isinstance(value, str) or not value:
            raise ValueError("must be a file name (relative to this file)")
        return value
    if kind == "loop":
        names = {p.name.lower(): p for p in msg.Loop}
        if not isinstance(value, str) or value not in names:
            raise ValueError(f"must be one of {sorted(names)}")
        return names[value]
    # hex
    if not isinstance(value, str):
        raise ValueError("must be a hex string")
    try:
        bytes.fromhex(value)
    except ValueError:
        raise ValueError("must be a hex string such as 'a55a00'") from None
    return value


def stream_commands(
    t_s: float,
    pos_deg: Sequence[float],
    vel_dps: Sequence[float] | None,
    period_s: float,
    interp: msg.Interp,
    prefill: int,
) -> list[ScriptedCommand]:
    """The scripted PC's stream of points 1..n from ``t_s``: START, the points six to a
    frame, each frame sent when the axis has used the points that make room for it
    (:data:`STREAM_LEAD_POINTS` ahead), then END with the last frame."""
    n = len(pos_deg)
    pos = tuple(float(p) for p in pos_deg)
    vel = tuple(float(v) for v in vel_dps) if vel_dps is not None else (0.0,) * n
    out = [ScriptedCommand(t_s, "stream_control", (
        ("action", msg.StreamAction.START), ("interp", msg.Interp(interp)),
        ("period_s", float(period_s)), ("prefill", int(prefill))))]  # fmt: skip
    per = msg.STREAM_POINTS_PER_FRAME
    t_frame = t_s
    for first in range(0, n, per):
        last = min(n, first + per)
        t_frame = t_s + max(0, last - STREAM_LEAD_POINTS) * period_s
        out.append(ScriptedCommand(t_frame, "stream_points", (
            ("first_index", first + 1), ("pos_deg", pos[first:last]),
            ("vel_dps", vel[first:last]))))  # fmt: skip
    out.append(ScriptedCommand(t_frame, "stream_control", (("action", msg.StreamAction.END),)))
    return out


def _expand(cmd: ScriptedCommand, where: str, file: Path, duration_s: float
            ) -> list[ScriptedCommand]:  # fmt: skip
    """A ``program`` or ``stream`` entry as the commands the scripted PC sends."""
    from sim.motionfile import load_points, load_program

    f = dict(cmd.fields)
    path = (file.parent / f["file"]) if not Path(f["file"]).is_absolute() else Path(f["file"])
    t_s = cmd.t_s
    try:
        if cmd.type == "program":
            return _program_commands(t_s, load_program(path), where, f["file"])
        pts = load_points(path, f.get("period_s"))
    except ConfigError as exc:  # the file's own error, said from the experiment's line
        raise ConfigError(f"{where} file = {f['file']!r}: {exc}") from None
    return _stream_entry(t_s, pts, f, where, duration_s)


def _program_commands(t_s: float, prog: Any, where: str, name: str) -> list[ScriptedCommand]:
    """A program file's blocks, all sent at ``t_s`` (the UART paces them)."""
    from firmware_model.programs import QUEUE_CAPACITY

    if len(prog.blocks) > QUEUE_CAPACITY:
        raise ConfigError(
            f"{where} file = {name!r}: {len(prog.blocks)} blocks; a run file sends "
            f"a program at once, so at most the board's {QUEUE_CAPACITY} (monitor "
            "--program sends any length with flow control)"
        )
    return [
        ScriptedCommand(t_s, "queue_segment",
                        (("target_deg", t), ("v_max_dps", v), ("dwell_s", d)))
        for t, v, d in prog.blocks
    ]  # fmt: skip


def _stream_entry(t_s: float, pts: Any, f: dict[str, Any], where: str, duration_s: float
                  ) -> list[ScriptedCommand]:  # fmt: skip
    """A point file's START, frames and END (:func:`stream_commands`), checked."""
    from firmware_model.stream import STREAM_CAPACITY

    period = float(pts.period_s or 0.0)
    n = len(pts.pos_deg)
    prefill = f.get("prefill", min(n, STREAM_LEAD_POINTS))
    if not 1 <= prefill <= min(n, STREAM_CAPACITY):
        raise ConfigError(f"{where} prefill = {prefill!r}: must be in [1, {min(n, 64)}]")
    out = stream_commands(t_s, pts.pos_deg, pts.vel_dps, period, pts.interp, prefill)
    t_frame = out[-1].t_s
    if t_frame >= duration_s:
        raise ConfigError(f"{where} file = {f['file']!r}: its last points are sent at "
                          f"{t_frame:g} s, after duration_s = {duration_s:g}")  # fmt: skip
    return out


def _command(entry: Any, index: int, file: Path, duration_s: float) -> ScriptedCommand:
    table = f"command #{index + 1}"
    where = _where(file, table)
    if not isinstance(entry, Mapping):
        raise ConfigError(f"{where}: must be a table")
    ctype = entry.get("type")
    if ctype not in COMMAND_FIELDS:
        raise ConfigError(
            f"{where} type = {ctype!r}: must be one of {', '.join(sorted(COMMAND_FIELDS))}"
        )
    t_s = entry.get("t_s")
    if isinstance(t_s, bool) or not isinstance(t_s, int | float) or not math.isfinite(t_s):
        raise ConfigError(f"{where} t_s = {t_s!r}: must be a finite number of seconds")
    if not 0.0 <= t_s < duration_s:
        raise ConfigError(f"{where} t_s = {t_s!r}: must be in [0, duration_s = {duration_s})")
    spec = COMMAND_FIELDS[ctype]
    values = []
    for key, value in entry.items():
        if key in ("type", "t_s"):
            continue
        if key not in spec:
            raise ConfigError(
                f"{where} {key} = {value!r}: not a field of a {ctype!r} command "
                f"(fields: {', '.join(sorted(spec)) or 'none'})"
            )
        try:
            values.append((key, _kind(value, spec[key][1])))
        except ValueError as exc:
            raise ConfigError(f"{where} {key} = {value!r}: {exc}") from None
    for key, (required, _) in spec.items():
        if required and key not in entry:
            raise ConfigError(f"{where} {key} = <missing>: required by a {ctype!r} command")
    if ctype == "move" and ("target_mdeg" in entry) == ("target_deg" in entry):
        raise ConfigError(
            f"{where} target_mdeg = {entry.get('target_mdeg')!r}: give exactly "
            "one of target_mdeg and target_deg"
        )
    command = ScriptedCommand(float(t_s), ctype, tuple(values))
    if ctype not in ("raw", "program", "stream"):
        # A value the wire cannot carry is the file's error, not the board's to NACK.
        problem = wire.wire_problem(command.message(1))
        if problem:
            field_name = problem.split(" = ", 1)[0]
            key = field_name
            if field_name == "target_deg" and "target_mdeg" in entry:
                key = "target_mdeg"
            raise ConfigError(f"{where} {key} = {entry.get(key)!r}: {problem}")
    return command


_EXPERIMENT_KEYS = {"bench", "duration_s", "command", "title"}


def load_experiment(path: str | Path) -> Experiment:
    """Load an experiment file: its bench (with overrides), duration and commands."""
    file = Path(path)
    data = _read_toml(file)
    bench_file = _resolve_bench(data.get("bench"), file)
    duration = data.get("duration_s")
    if (
        isinstance(duration, bool)
        or not isinstance(duration, int | float)
        or not math.isfinite(duration)
        or not 0 < duration <= 86_400
    ):
        raise ConfigError(f"{file}: [top] duration_s = {duration!r}: must be in (0, 86400] s")
    title = data.get("title", "")
    if not isinstance(title, str):
        raise ConfigError(f"{file}: [top] title = {title!r}: must be a string")
    for key, value in data.items():
        if key not in _EXPERIMENT_KEYS and not isinstance(value, Mapping):
            raise ConfigError(f"{file}: [top] {key} = {value!r}: unknown key")
    overrides = {k: v for k, v in data.items() if isinstance(v, Mapping)}
    base = _read_toml(bench_file)
    # Errors in the bench itself name the bench file; errors the overrides bring in name
    # the experiment file.
    bench = bench_from_tables(build_tables(base, bench_file), bench_file)
    if overrides:
        bench = bench_from_tables(
            build_tables(_merge(base, overrides), file), bench_file, errors_in=file
        )
    entries = data.get("command", [])
    if not isinstance(entries, list):
        raise ConfigError(f"{file}: [top] command = {entries!r}: use [[command]] tables")
    commands_list: list[ScriptedCommand] = []
    for k, e in enumerate(entries):
        c = _command(e, k, file, float(duration))
        if c.type in ("program", "stream"):
            commands_list += _expand(c, _where(file, f"command #{k + 1}"), file, float(duration))
        else:
            commands_list.append(c)
    # stable: a program's blocks and a stream's frames keep their order
    commands = tuple(sorted(commands_list, key=lambda c: c.t_s))
    return Experiment(
        bench=bench, duration_s=float(duration), commands=commands, path=file, title=title
    )
