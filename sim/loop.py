"""The simulation loop: owns the clock, the plant state and the two UART directions.

Per 500 Hz servo tick, in this order (docs/architecture.md, "The plant <-> firmware
boundary"):

1. the encoder reads the plant (``sim.encoder``),
2. ``fw.servo_tick(encoder_counts, rx_bytes, tx_free)`` runs the servo tick with the bytes
   the board's UART received during the previous tick and returns the bytes it queued for
   the PC, which go into the board's TX FIFO,
3. ``current_loop_multiple`` times: the ADC reads the IS pin of the present current, then
   ``fw.current_tick(adc_counts)`` gives ``(duty, enable)`` (the firmware applies its own
   compute delay), the bridge rounds the duty to the timer's 1/ARR steps, then the plant
   advances ``dt / multiple`` with that input held,
4. the log row is written,
5. both UART directions move the bytes of one tick: PC -> board bytes arrive for the next
   servo tick, board -> PC bytes are buffered for ``pc_read()``.

One path for every N: one axis (``batch=None``) is a batch of one, with scalars only where
the firmware's API takes them. The plant states are ``(N, 5)`` arrays, the log rows of
preallocated ``(capacity, N)`` arrays. The scripted PC of ``run`` writes its frames with
``pc_write`` at their times, exactly as a PC program would.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import threading
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from operator import itemgetter
from typing import Any

import numpy as np

from firmware_model import tick as ftick
from firmware_model.firmware import SIGNAL_NAMES
from serial_protocol import frame
from serial_protocol.exceptions import ConfigError
from serial_protocol.messages import Hello, Telemetry
from serial_protocol.uart import EmulatedUart, FaultInjection, bytes_per_s
from sim import tick as st
from sim.bridge import (
    apply_bridge,
    inject_sense_fault,
    pwm_sense_table,
    read_adc,
    switching,
    switching_table,
)
from sim.config import TABLES, BenchConfig, Experiment, check_bench
from sim.encoder import BLOCK, Encoder
from sim.params import PlantParams, UartParams, per_member
from sim.plant import I_A, POS, TWIST, VEL, Plant
from sim.supply import Bus, read_bus_adc, step_period
from sim.thermal import Heat, heat_advance, heat_groups

__all__ = [
    "LOG_FIELDS", "RunLog", "RunResult", "Simulation", "apply_overrides", "run", "warm_up",
]  # fmt: skip

# Every logged signal, in CSV column order after t_s (README, "CSV columns"): the firmware's
# signals, then the plant's.
FW_FIELDS = SIGNAL_NAMES
PLANT_FIELDS = (
    "true_pos_deg",
    "true_vel_dps",
    "platter_pos_deg",
    "motor_pos_rad",
    "current_a",
    "voltage_v",
    "bus_v",
    "winding_c",
)
LOG_FIELDS = ("t_s",) + FW_FIELDS + PLANT_FIELDS
_INT_FIELDS = ("state", "fault")
_SHARED_FIELDS = ("sp_pos_deg", "sp_vel_dps", "sp_acc_dps2")
# The plant's log columns, in the order of the compiled tick's (5, capacity, N) array.
PLANT_LOG = ("true_pos_deg", "true_vel_dps", "platter_pos_deg", "motor_pos_rad", "current_a")
_RAD2DEG = 180.0 / math.pi  # np.degrees' factor (numpy: x * (180 / pi))


def _broadcast(values: np.ndarray, n: int, copy: bool, over_time: bool = False) -> np.ndarray:
    """A column kept once for the batch (``values``: ``(n_ticks,)``, the same for every one of
    ``n`` members) or once for the run (``over_time``: ``(N,)``, constant over ``n``
    ticks) as the log's ``(N, n_ticks)``: a read-only view, or a copy."""
    shape = (values.shape[0], n) if over_time else (n, values.shape[0])
    view = np.broadcast_to(values[:, None] if over_time else values, shape)
    return view.copy() if copy else view


@dataclass(frozen=True)
class RunLog:
    """The whole run, one value per servo tick (``(n_ticks,)``, or ``(N, n_ticks)`` in
    batch; ``t_s`` is always ``(n_ticks,)``).

    Row k is servo tick k: ``t_s = k * dt_s`` is its sampling instant; the plant signals
    (``true_*``, ``platter_pos_deg``, ``motor_pos_rad``, ``current_a``) are the state at that
    instant (what the encoder and ADC sample); the firmware signals are what the firmware
    computed in tick k from those samples; ``voltage_v`` is what the bridge applied during
    the tick (the last current-loop period of it). Axis angles (gearmotor output) in degrees unless
    named ``platter_`` or ``motor_``. ``voltage_v`` is the bridge's average output
    ``duty * V_bus`` (0 while disabled or locked out), ``bus_v`` the bus voltage at the
    sampling instant (the supply's voltage without ``[supply] bus_model``). ``current_a`` is
    the true armature current,
    ``current_meas_a`` the firmware's signed reading of the IS pin.

    The setpoint columns (the batch's one setpoint) and, without the bus or heat model,
    ``bus_v`` and ``winding_c`` (constant) of ``run``'s log are read-only broadcasts of one
    value a tick or a member (``Simulation.log()`` gives copies).
    """

    t_s: np.ndarray
    sp_pos_deg: np.ndarray
    sp_vel_dps: np.ndarray
    sp_acc_dps2: np.ndarray
    pos_deg: np.ndarray
    vel_dps: np.ndarray
    vel_raw_dps: np.ndarray
    current_meas_a: np.ndarray
    current_ref_a: np.ndarray
    duty: np.ndarray
    state: np.ndarray
    fault: np.ndarray
    true_pos_deg: np.ndarray
    true_vel_dps: np.ndarray
    platter_pos_deg: np.ndarray
    motor_pos_rad: np.ndarray
    current_a: np.ndarray
    voltage_v: np.ndarray
    bus_v: np.ndarray
    winding_c: np.ndarray

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def member(self, k: int) -> RunLog:
        """Batch member ``k`` as a single-axis log."""
        return RunLog(**{f: (v if f == "t_s" or v.ndim == 1 else v[k]) for f, v in self.items()})

    def items(self) -> list[tuple[str, np.ndarray]]:
        return [(f, getattr(self, f)) for f in LOG_FIELDS]


class RunResult:
    """What ``run`` returns: the log, the bytes the PC received, what it decodes from them
    (decoded on first use) and the link counters.

    The PC's decode comes two ways, from the same bytes with the same decoder: as message
    objects (``messages``, ``telemetry``) or with the telemetry as columns
    (``telemetry_arrays``, ``replies``), which skips building one ``Telemetry`` per tick.

    Attributes:
        log: the ``RunLog``.
        pc_bytes: every byte that reached the PC, in order.
        experiment: the experiment that was run.
        firmware_counters: the firmware's ``counters`` at the end.
    """

    def __init__(
        self,
        log: RunLog,
        pc_bytes: bytes,
        uart_link: dict[str, int],
        experiment: Experiment | None = None,
        firmware_counters: dict[str, int] | None = None,
    ) -> None:
        self.log = log
        self.pc_bytes = pc_bytes
        self.experiment = experiment
        self.firmware_counters = dict(firmware_counters or {})
        self._uart_link = dict(uart_link)
        self._messages: tuple[Any, ...] | None = None
        self._columns: tuple[dict[str, np.ndarray], tuple[Any, ...]] | None = None
        self._decoder_stats: dict[str, int] = {}

    def _keep_stats(self, decoder: frame.Decoder) -> None:
        stats = dataclasses.asdict(decoder.stats())
        self._decoder_stats = {"pc_decoder_" + k: v for k, v in stats.items()}

    @property
    def messages(self) -> tuple[Any, ...]:
        """Every message the PC decoded (``Telemetry``, replies, ``Malformed``), in order."""
        if self._messages is None:
            decoder = frame.Decoder()
            self._messages = tuple(decoder.feed(self.pc_bytes))
            self._keep_stats(decoder)
        return self._messages

    def _decoded_columns(self) -> tuple[dict[str, np.ndarray], tuple[Any, ...]]:
        if self._columns is None:
            decoder = frame.Decoder()
            columns, others = decoder.feed_columns(self.pc_bytes)
            self._columns = (columns, tuple(others))
            self._keep_stats(decoder)
        return self._columns

    @property
    def link(self) -> dict[str, int]:
        """UART counters of both directions and the PC decoder's counters."""
        self._decoded_columns()
        return {**self._uart_link, **self._decoder_stats}

    @property
    def telemetry(self) -> tuple[Telemetry, ...]:
        return tuple(m for m in self.messages if isinstance(m, Telemetry))

    @property
    def replies(self) -> tuple[Any, ...]:
        """Every decoded message but the telemetry (replies, fault reports, ``Malformed``)."""
        return self._decoded_columns()[1]

    def telemetry_arrays(self) -> dict[str, np.ndarray]:
        """Decoded telemetry as arrays, one per ``Telemetry`` field (``tick``, ``state`` and
        ``fault`` int64, the rest float64), in the order received."""
        return {k: v.copy() for k, v in self._decoded_columns()[0].items()}


# ------------------------------------------------------------------------ overrides


def _locate(bench: BenchConfig, table: str) -> tuple[str, str | None]:
    """Where table ``table`` lives in a BenchConfig: (container attribute, field)."""
    if table in ("uart", "loop"):
        return table, None
    plant_fields = {f.name for f in dataclasses.fields(PlantParams)}
    if table in plant_fields:
        return "plant", table
    cls = TABLES.get(table)
    for f in dataclasses.fields(bench.firmware):
        if cls is not None and type(getattr(bench.firmware, f.name)) is cls:
            return "firmware", f.name
    raise ConfigError(f"overrides: [{table}]: unknown table (known: {', '.join(sorted(TABLES))})")


def apply_overrides(bench: BenchConfig, overrides: Mapping[str, Any]) -> BenchConfig:
    """A copy of ``bench`` with ``{"table.key": value}`` replaced (value: scalar, or an
    ``(N,)`` array for one value per batch member). Validated like the TOML file."""
    for dotted, value in overrides.items():
        table, _, key = dotted.rpartition(".")
        container, part_name = _locate(bench, table)
        holder = getattr(bench, container)
        part = holder if part_name is None else getattr(holder, part_name)
        if key not in {f.name for f in dataclasses.fields(part)}:
            raise ConfigError(f"overrides: [{table}] {key} = {value!r}: unknown key")
        if isinstance(value, list | tuple):
            value = np.asarray(value, dtype=float)
        try:
            new_part = dataclasses.replace(part, **{key: value})
            if part_name is None:
                bench = dataclasses.replace(bench, **{container: new_part})
            else:
                new_holder = dataclasses.replace(holder, **{part_name: new_part})
                bench = dataclasses.replace(bench, **{container: new_holder})
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"overrides: [{table}] {key} = {value!r}: {exc}") from None
    if overrides:
        check_bench(bench, "overrides", nominal=False)
    return bench


# ------------------------------------------------------------------------ simulation


class Simulation:
    """Firmware + plant + UART, stepped tick by tick; the only owner of clock and state.

    Args:
        bench: the bench (``sim.config.load_bench``).
        batch: None for one axis, or N axes in lock-step (parameters or gains may differ
            per member through ``overrides`` arrays of shape ``(N,)``).
        seed: seeds the encoder and ADC noise and the UART fault injection.
        overrides: ``{"table.key": value}`` applied to ``bench`` first.
        firmware: a firmware object to use instead of ``firmware_model.firmware.Firmware``
            (anything with ``servo_tick``, ``current_tick`` and ``signals``; a
            ``signal_row()`` giving the signals as a tuple in ``FW_FIELDS`` order is used
            where it exists).
        record_inputs: keep the ``(duty, enable)`` of every plant step (``inputs()``) and
            the plant state at every sampling instant (``states()``), e.g. to replay a run
            through ``solve_ivp``.
        keep_log: keep the per-tick log (``log()``). A long-running server (``serve``)
            passes False: the log grows by about 1 kB per tick (1.8 GB per hour at N = 1).
    """

    def __init__(
        self,
        bench: BenchConfig,
        *,
        batch: int | None = None,
        seed: int = 0,
        overrides: Mapping[str, Any] | None = None,
        firmware: Any = None,
        record_inputs: bool = False,
        keep_log: bool = True,
    ) -> None:
        if overrides:
            bench = apply_overrides(bench, overrides)
        if batch is not None and (not isinstance(batch, int) or batch < 1):
            raise ValueError(f"batch = {batch!r}: must be None or an integer >= 1")
        n_param = bench.plant.batch_size()
        if n_param is not None and batch is None:
            raise ValueError(f"plant parameter arrays of {n_param} members need batch = N")
        self.bench = bench
        self.batch = batch
        self.seed = seed
        servo = bench.firmware.servo
        self.dt_s = servo.dt_s
        self.multiple = servo.current_loop_multiple
        self.h_s = self.dt_s / self.multiple
        if firmware is None:
            from firmware_model.firmware import Firmware

            firmware = Firmware(bench.firmware, batch=batch)
        self.fw = firmware
        self._rng = np.random.default_rng(seed)
        plant = bench.plant
        n = self.n = batch or 1
        self._scalar = batch is None
        self.encoder = Encoder(plant.encoder, self._rng)
        self._adc_full = (1 << plant.current_sense.adc_bits) - 1
        self._adc_noisy = bool(np.any(plant.current_sense.noise_rms_lsb))
        # With one noise source, the generator feeds nothing else: its blocks may hold
        # only the draws a run uses (the same stream; a short batch run would otherwise
        # draw 4096 rows of N it never reads). With two, they alternate in whole blocks.
        self._sole_noise = self.encoder.noisy != self._adc_noisy
        self._noise_rows = BLOCK
        # ADC noise: standard normals drawn in blocks of 4096 periods x N, as the encoder's.
        self._adc_block = np.empty((0, n))
        self._adc_row = 0
        # With the bus model the plant steps a whole current-loop period or sub-steps of it
        # (sim.supply): the sub-step is a level of the period's tables.
        self.bus = Bus(plant, n, self.h_s)
        # The motor's temperatures ([thermal] model, sim.thermal), advanced every period.
        self.heat = Heat(plant, n, self.h_s)
        self.plant = Plant(
            plant, n, self.h_s, max(bench.loop.event_levels, self.bus.substep_level)
        )
        self._x = np.zeros((n, 5))
        self._duty = np.zeros(n)
        self._enable = np.zeros(n, dtype=bool)
        uart = bench.uart
        baud = bench.firmware.telemetry.baud
        faults = uart_faults(uart)
        self.uart_tx = EmulatedUart(baud, uart.fifo_bytes, faults, seed=seed * 2 + 1)
        self.uart_rx = EmulatedUart(baud, uart.fifo_bytes, faults, seed=seed * 2 + 2)
        self._pc_out = bytearray()  # PC-side buffer (an OS serial driver's queue)
        self._pc_in = bytearray()
        self._rx_for_board = b""
        self.tick = 0
        self._record_inputs = record_inputs
        self._keep_log = keep_log
        self._inputs: list[tuple[Any, Any]] = []
        self._cap = 0
        self._arrays: dict[str, np.ndarray] = {}
        self._states: list[np.ndarray] = []
        # The log's plant columns (PLANT_LOG), (5, capacity, N), and their constants.
        self._plog = np.empty((len(PLANT_LOG), 0, n))
        ratio = per_member(plant.gearbox.ratio, n)
        total = ratio * per_member(plant.belt.ratio, n)
        self._plant_consts = np.array([math.degrees(1.0) / ratio, total, np.full(n, _RAD2DEG)])
        # The IS pin reads the current in the direction of the applied duty, from the
        # high side only (sim.bridge.sensed_current_a): sign(duty), 0 while disabled.
        self._sense_sign = np.zeros(n)
        self._one_duty, self._one_enable = np.zeros(1), np.zeros(1, dtype=bool)
        # The bridge voltage of the last current-loop period (the log's voltage_v).
        self._volt = np.zeros(n)
        # Parameters as (N,) arrays for the kernels (each may be scalar or (N,)).
        parameters = (
            plant.current_sense.a_per_lsb, plant.current_sense.noise_rms_lsb, plant.bridge.arr,
            plant.supply.voltage_v,
        )  # fmt: skip
        self._a_per_lsb_n, self._adc_noise_n, self._arr_n, self._vs_n = (
            per_member(v, n) for v in parameters
        )
        # The IS pin within the PWM period (sample point, ripple, offset, settling): empty
        # for the averaged sense (sim.bridge.read_adc).
        self._sense_table = pwm_sense_table(plant.current_sense, plant.bridge, plant.motor.l_h, n)
        # The bridge's switching times (sim.bridge.switching): empty for the ideal bridge.
        self._shifts = switching_table(plant.bridge, n)
        signal_row = getattr(firmware, "signal_row", None)
        if signal_row is None:
            pick, signals = itemgetter(*FW_FIELDS), firmware.signals

            def signal_row() -> tuple[Any, ...]:
                return pick(signals())

        self._signal_row = signal_row
        # The project's firmware runs in the compiled tick (sim/tick.py); another firmware
        # object, or a run that records every plant input, steps tick by tick here.
        from firmware_model.firmware import Firmware

        self._compiled = type(firmware) is Firmware and not record_inputs
        # The project's firmware reads the bus voltage too (a foreign one: the IS pin only).
        self._reads_bus = isinstance(firmware, Firmware)
        # The log's columns kept once a tick (the project's firmware has one setpoint for
        # the batch) and not at all (constant: the supply's voltage without the bus model,
        # the reference temperature without the heat model): ``_log`` broadcasts them.
        self._shared = _SHARED_FIELDS if self._reads_bus else ()
        self._constant = tuple(
            f for f, on in (("bus_v", self.bus.on), ("winding_c", self.heat.on)) if not on
        )
        self._x_spare = np.zeros((n, 5))
        # run_ticks' scratch and its log tuple, kept between calls (a call of one tick,
        # sim.step(1), should not pay a dozen small allocations): ctx, flags, credit, the
        # telemetry values, en_now, counts, adc; every call starts at the tick's top, where
        # run_ticks writes each before reading it.
        self._scratch = (
            np.zeros(st.N_CX, dtype=np.int64), np.zeros(st.N_F, dtype=np.int64), np.zeros(1),
            np.empty(6), np.zeros(n, dtype=bool), np.zeros(n, dtype=np.int64),
            np.zeros(n, dtype=np.int64),
        )  # fmt: skip
        self._logs: tuple[Any, ...] = ()
        self._logs_of: np.ndarray | None = None

    # ---------------------------------------------------------------- public API
    @property
    def t_s(self) -> float:
        """Simulated time now, ``tick * dt_s`` (the start of the next tick) (s)."""
        return self.tick * self.dt_s

    @property
    def plant_state(self) -> np.ndarray:
        """A copy of the plant state, ``(5,)`` or ``(N, 5)`` (see ``sim.plant``)."""
        return np.array(self._x[0] if self._scalar else self._x, dtype=float)

    def pc_write(self, data: bytes) -> None:
        """Bytes from the PC to the board; they enter the board's RX line as it has room."""
        self._pc_out += data

    @property
    def pc_pending_bytes(self) -> int:
        """Bytes the PC wrote that have not yet entered the board's RX line."""
        return len(self._pc_out)

    def pc_discard(self) -> int:
        """Forget the PC's bytes not yet on the line (the PC program went away); return
        how many there were."""
        n = len(self._pc_out)
        self._pc_out.clear()
        return n

    def pc_read(self) -> bytes:
        """Bytes the PC received from the board since the last call."""
        out = bytes(self._pc_in)
        self._pc_in.clear()
        return out

    def inputs(self) -> tuple[np.ndarray, np.ndarray]:
        """``(duty, enable)`` of every plant step so far (needs ``record_inputs=True``)."""
        if not self._record_inputs:
            raise ValueError("record_inputs = False: construct the Simulation with True")
        duty = np.array([d for d, _ in self._inputs], dtype=float).reshape(-1, self.n)
        enable = np.array([e for _, e in self._inputs], dtype=bool).reshape(-1, self.n)
        if self._scalar:
            return duty[:, 0], enable[:, 0]
        return duty, enable

    def states(self) -> np.ndarray:
        """The plant state at every sampling instant so far, ``(n_ticks, N, 5)`` (needs
        ``record_inputs=True``; with ``inputs()``, what a replay starts from)."""
        if not self._record_inputs:
            raise ValueError("record_inputs = False: construct the Simulation with True")
        return np.array(self._states).reshape(-1, self.n, 5)

    def inject_sense(self, kind: str, members: Any = None) -> None:
        """A fault on the IS reading from the next tick (``sim.bridge.inject_sense_fault``:
        ``"short"``, ``"stuck"`` or ``"clear"``), for ``members`` (all if None)."""
        self._sense_table = inject_sense_fault(self._sense_table, self.n, kind, members)

    def step(self, n_ticks: int = 1) -> None:
        """Advance ``n_ticks`` servo ticks."""
        if self._compiled:
            self._run_compiled(n_ticks)
            return
        for _ in range(n_ticks):
            self._step()

    def log(self) -> RunLog:
        """The log so far as numpy arrays (copies)."""
        if not self._keep_log:
            raise ValueError("keep_log = False: this Simulation keeps no log")
        return self._log(copy=True)

    def _log(self, *, copy: bool) -> RunLog:
        """The log so far; ``copy=False`` hands out views of the log buffers instead
        of copies, for a caller that discards the simulation (``run``). The loop only ever
        writes rows after ``tick``, so the views never change."""
        n = self.tick

        def columns(rows: np.ndarray) -> np.ndarray:
            # (n, N) rows -> (N, n) columns: the transposed view, copied in its own memory
            # order (Fortran), is a plain memcpy; a C-ordered copy would transpose.
            return np.array(rows.T, order="K") if copy else rows.T

        big = self.n
        cols = {}
        for f, a in self._arrays.items():
            if a.shape[1] == big:
                cols[f] = columns(a[:n])
            else:  # the shared setpoint, one value a tick: every member's row is the same
                cols[f] = _broadcast(a[:n, 0], big, copy)
        plant = self._plog[:, :n]  # (5, n, N): the plant's columns, in PLANT_LOG order
        for q, f in enumerate(PLANT_LOG):
            cols[f] = columns(plant[q])
        # Constant over the run without the bus model or the heat model: one value a member.
        if "bus_v" not in cols:
            cols["bus_v"] = _broadcast(self._vs_n, n, copy, over_time=True)
        if "winding_c" not in cols:
            cols["winding_c"] = _broadcast(self.heat.winding_c(), n, copy, over_time=True)
        cols["t_s"] = np.arange(n) * self.dt_s
        log = RunLog(**cols)
        return log.member(0) if self._scalar else log

    def link_stats(self) -> dict[str, int]:
        """UART counters of both directions, prefixed ``tx_`` (board -> PC) and ``rx_``."""
        out = {}
        for prefix, uart in (("board_to_pc_", self.uart_tx), ("pc_to_board_", self.uart_rx)):
            for f in dataclasses.fields(uart.stats):
                out[prefix + f.name] = getattr(uart.stats, f.name)
        out["pc_pending_bytes"] = len(self._pc_out)
        return out

    # ---------------------------------------------------------------- the tick
    def _move_bytes(self) -> None:
        rx = self.uart_rx
        if self._pc_out:
            n = rx.write(bytes(self._pc_out[: rx.free]))
            del self._pc_out[:n]
        # An empty RX line is idle (its advance would return nothing and change nothing):
        # skip the call, the PC sends rarely.
        self._rx_for_board = rx.advance(self.dt_s) if rx.pending else b""
        self._pc_in += self.uart_tx.advance(self.dt_s)

    def _grow(self, min_cap: int = 0) -> None:
        cap = max(1024, 2 * self._cap, min_cap)
        n = self.n
        # Per member and tick: the firmware's signals but the setpoint, the bridge voltage,
        # the bus voltage and winding temperature where they change (their models on), and
        # the plant's columns (written as the log shows them: no pass over the log after
        # the run). The setpoint, shared by the batch, is one value a tick; a constant bus
        # voltage or winding temperature is not stored (``_log`` broadcasts them).
        fields = [f for f in FW_FIELDS if f not in self._shared]
        fields += ["voltage_v"] + [f for f in ("bus_v", "winding_c") if f not in self._constant]
        # One allocation for the whole log (every column 8 bytes a value): numpy backs an
        # allocation of 4 MB or more with huge pages, so a batch log (~30 kB a tick at
        # N = 256) costs a few page faults instead of one per 4 kB written.
        block = cap * n * 8
        shared = cap * 8
        buf = _log_buffer(block * (len(fields) + len(PLANT_LOG)) + shared * len(self._shared))
        # The plant's columns first, as one (5, cap, N) array for the compiled tick.
        new = buf[: len(PLANT_LOG) * block].view(np.float64).reshape(len(PLANT_LOG), cap, n)
        new[:, : self._cap] = self._plog[:, : self._cap]
        self._plog = new
        at = len(PLANT_LOG) * block
        for f in (*fields, *self._shared):
            dtype = np.int64 if f in _INT_FIELDS else np.float64
            width = 1 if f in self._shared else n
            size = cap * width * 8
            # row per tick: contiguous writes
            new = buf[at : at + size].view(dtype).reshape(cap, width)
            at += size
            if f in self._arrays:
                new[: self._cap] = self._arrays[f][: self._cap]
            self._arrays[f] = new
        self._cap = cap

    def _log_plant(self, k: int, x: np.ndarray) -> None:
        """Log row ``k`` of the plant's columns from states ``x`` (``(N, 5)``): the
        compiled tick's arithmetic (``sim.tick._log_plant``), in numpy."""
        plog, (deg_axis, n_total, rad2deg) = self._plog, self._plant_consts
        pos = x[:, POS]
        plog[0, k] = pos * deg_axis
        plog[1, k] = x[:, VEL] * deg_axis
        plog[2, k] = (pos / n_total - x[:, TWIST]) * rad2deg
        plog[3, k] = pos
        plog[4, k] = x[:, I_A]

    def reserve(self, n_ticks: int) -> None:
        """Make room for ``n_ticks`` more log rows at once (batch; ``run`` calls it)."""
        if self._keep_log and self.tick + n_ticks > self._cap:
            self._grow(self.tick + n_ticks)

    def _adc_draw(self) -> np.ndarray:
        """The next row of ADC noise draws."""
        if self._adc_row == self._adc_block.shape[0]:
            self._adc_block = self._rng.standard_normal((self._noise_rows, self.n))
            self._adc_row = 0
        row = self._adc_block[self._adc_row]
        self._adc_row += 1
        return row

    def _rows(self, ticks: int) -> int:
        """Rows of noise draws to draw for ``ticks`` more ticks (``_sole_noise``)."""
        if not self._sole_noise:
            return BLOCK
        per_tick = self.multiple if self._adc_noisy else 1
        # At least 64: a caller stepping a few ticks at a time (serve) draws rarely.
        return min(BLOCK, max(64, ticks * per_tick))

    def _head(self, rows: int) -> int:
        """Rows of a block of encoder noise to draw at once, the rest on a thread while the
        compiled tick runs the first (``Encoder.refill``: in chunks, the tick goes on as each
        is drawn): a 32nd of a large block of the sole noise source (then nothing else draws
        from the generator meanwhile); 0 (all at once) for a block too small to gain from it
        (N = 1: ~1,000 draws)."""
        if self._sole_noise and rows * self.n >= 1 << 15:
            return max(1, rows // 32)
        return 0

    def _run_compiled(self, n_ticks: int) -> None:
        """``n_ticks`` ticks in the compiled tick (``sim.tick.run_ticks``), handling its
        events here (see ``sim/tick.py``)."""
        fw = self.fw
        if n_ticks < 0:
            return
        k_end = self.tick + n_ticks
        n = self.n
        keep = self._keep_log
        if keep and (k_end > self._cap or not self._arrays):
            self._grow(k_end)
        law, plant, enc = fw.law, self.plant, self.encoder
        if law.fixed not in _LOADED:
            _compile_plant_aside(self)
        ctx, flags, credit, values, en_now, counts, adc = self._scratch
        ctx[:] = 0
        ctx[st.CX_K] = self.tick
        ctx[st.CX_STAGE] = st.TOP
        ctx[st.CX_ENC_ROW] = enc.row
        ctx[st.CX_ADC_ROW] = self._adc_row
        x = self._x
        ctx[st.CX_KNOWN] = x is plant._last_x
        spare = self._x_spare if self._x_spare is not x else np.zeros((n, 5))
        uart_tx = self.uart_tx
        ctx[st.CX_PENDING] = uart_tx.pending
        credit[0] = uart_tx.credit
        flags[:] = 0
        flags[st.F_FRAMER] = ftick.framer_ok()
        flags[st.F_KEEP] = keep
        flags[st.F_FIFO] = uart_tx.fifo_bytes
        flags[st.F_FRAME_BYTES] = frame.TELEMETRY_FRAME_BYTES
        flags[st.F_ENC_NOISY] = enc.noisy
        flags[st.F_ADC_NOISY] = self._adc_noisy
        flags[st.F_ENC_FAULT] = enc.faulty
        # The boot (the first reading) stops the run before the observer: Firmware._boot.
        flags[st.F_BOOT] = not fw._booted
        # At most a telemetry frame a tick and a heartbeat every heartbeat period.
        hb_ticks = fw._heartbeat_ticks
        heartbeats = n_ticks // hb_ticks + 1 if hb_ticks else 0
        txbuf = np.empty(
            (n_ticks + 1) * frame.TELEMETRY_FRAME_BYTES + heartbeats * ftick.HB_FRAME_BYTES,
            dtype=np.uint8,
        )
        # The last applied duty (the IS pin reads within its PWM period, sim.bridge.read_adc).
        duty, enable = self._duty.astype(float), self._enable.astype(bool)
        if self._logs_of is not self._plog:  # a new log allocation (or the first call)
            # A column the log does not keep is (0, N): the compiled tick writes none.
            empty = np.empty((0, n))
            if keep:
                arrays = self._arrays
                self._logs = (
                    self._plog, tuple(arrays[f] for f in FW_FIELDS), arrays["voltage_v"],
                    arrays.get("bus_v", empty), arrays.get("winding_c", empty),
                    self._plant_consts,
                )  # fmt: skip
            else:
                ints = np.empty((0, n), dtype=np.int64)
                self._logs = (
                    np.empty((len(PLANT_LOG), 0, n)), (empty,) * 9 + (ints, ints), empty, empty,
                    empty, self._plant_consts,
                )  # fmt: skip
            self._logs_of = self._plog
        logs = self._logs
        bridge_params = (self._arr_n, self._vs_n, self._shifts)
        adc_params = (self._a_per_lsb_n, self._adc_noise_n, self._sense_table)
        bps = float(bytes_per_s(uart_tx.baud))
        x0, x1 = (x, spare)
        while True:
            fw._pack()
            fw._pack_link()
            flags[st.F_REPLIES] = len(fw._replies) > 0
            flags[st.F_RX_PRESENT] = len(self._rx_for_board) > 0
            flags[st.F_RX_ACTIVE] = bool(self._pc_out) or self.uart_rx.pending > 0
            # The silence rule: a partial frame is given up RX_SILENCE_S after its last byte.
            flags[st.F_SILENCE_AT] = (
                fw._last_byte_tick + fw._silence_ticks if fw.decoder._buf else -1
            )
            sim = (
                x0, x1, self.dt_s, self.multiple, enc.kernel_params(n), enc.block, adc_params,
                self._adc_block, self._adc_full, bridge_params, self._sense_sign, self._volt,
                duty, enable, counts, adc, bps, values,
            )  # fmt: skip
            plant_args = (
                plant._last_mech, plant._group, plant._slots, plant._phis, plant._rates,
                plant._consts, plant.event_levels, plant.split_budget, self.bus.kernel_args(),
                self.heat.kernel_args(), plant._scratch,
            )  # fmt: skip
            fw_args = (
                fw._fs, fw._fi, fw._enabled, fw._fault, fw._oc_ticks, fw._prof, en_now,
                fw._flags, fw._sf,
            )  # fmt: skip
            args = (
                k_end, ctx, credit, flags, (law.P, law.C, law.S, law.G, law.K), fw_args, sim,
                plant_args, logs, txbuf, _TABLES, enc.fault_args(n),
            )  # fmt: skip
            if law.fixed in _LOADED:
                code = st.run_ticks(*args)
            else:
                with compile_notice():
                    code = st.run_ticks(*args)
                _LOADED.add(law.fixed)
                _end_aside()
            # Catch up: the firmware's attributes, the TX line, the clock and the state.
            fw._unpack()
            txlen, shifted = int(ctx[st.CX_TXLEN]), int(ctx[st.CX_SHIFTED])
            if txlen or shifted:
                self._pc_in += uart_tx.transfer(bytes(txbuf[:txlen]), shifted, float(credit[0]))
                ctx[st.CX_TXLEN] = ctx[st.CX_SHIFTED] = 0
            ctx[st.CX_PENDING] = uart_tx.pending
            self.tick = int(ctx[st.CX_K])
            enc.row = int(ctx[st.CX_ENC_ROW])
            self._adc_row = int(ctx[st.CX_ADC_ROW])
            plant.n_events += int(ctx[st.CX_EVENTS])
            ctx[st.CX_EVENTS] = 0
            if ctx[st.CX_FLIP]:
                x0, x1 = x1, x0
                ctx[st.CX_FLIP] = 0
            self._x = x0
            if code == st.STOP_END:
                break
            if code == st.STOP_RX:  # as Firmware.servo_tick does
                rx = self._rx_for_board
                self._rx_for_board = b""
                if rx:
                    fw._receive(rx)
                else:
                    fw._silence()
            elif code == st.STOP_BOOT:  # as Firmware.servo_tick does on its first reading
                fw._boot(counts.copy())
                flags[st.F_BOOT] = 0
            elif code == st.STOP_TRIP:
                fw._check()
            elif code == st.STOP_TRANSMIT:
                data = fw._transmit(uart_tx.free)
                if data:
                    uart_tx.write(data)
                ctx[st.CX_PENDING] = uart_tx.pending
            elif code == st.STOP_OC:
                fw._current_trips()
                en_now[:] = fw._enabled
            elif code == st.STOP_MODE:
                plant._load(int(ctx[st.CX_NEED_GROUP]), int(ctx[st.CX_NEED_MODE]))
            elif code == st.STOP_NOISE:
                rows = self._rows(k_end - int(ctx[st.CX_K]))
                if ctx[st.CX_STAGE] == st.TOP:
                    head = self._head(rows)
                    if enc.drawing:  # the rest of the block: drawn on refill's thread
                        enc.more()
                    elif head:
                        enc.refill(n, rows, head)
                        ctx[st.CX_ENC_ROW] = 0
                    else:
                        enc.refill(n, rows)
                        ctx[st.CX_ENC_ROW] = 0
                else:
                    self._adc_block = self._rng.standard_normal((rows, n))
                    self._adc_row = 0
                    ctx[st.CX_ADC_ROW] = 0
            elif code == st.STOP_HEAT:
                self.heat.make_group(plant)
            elif code == st.STOP_UART:
                # The PC -> board direction of _move_bytes (the TX line moved in run_ticks).
                rx = self.uart_rx
                if self._pc_out:
                    del self._pc_out[: rx.write(bytes(self._pc_out[: rx.free]))]
                self._rx_for_board = rx.advance(self.dt_s) if rx.pending else b""
        enc.finish()  # every draw of this call made: the generator is free
        self._x = x0
        self._x_spare = x1
        plant._last_x = x0 if ctx[st.CX_KNOWN] else plant._last_x
        self._duty, self._enable = duty.copy(), enable.copy()

    @property
    def bus_v(self) -> np.ndarray:
        """The bus voltage (the bulk capacitor's) now, ``(N,)`` (V): the supply voltage
        without the bus model."""
        return self.bus.v.copy() if self.bus.on else self._vs_n.copy()

    def _plant_period(self, x: np.ndarray, d: np.ndarray, en: np.ndarray) -> np.ndarray:
        """One current-loop period of the plant with ``(d, en)`` held (``sim.supply.
        step_period``, the compiled tick's plant stage); returns the new states."""
        plant, heat = self.plant, self.heat
        if heat.on:  # the parameter set of each winding's temperature (sim.thermal)
            while heat_groups(x, heat.kernel_args(), plant._group, plant._last_mech, plant._consts):
                heat.make_group(plant)
        if not self.bus.on:
            xn = plant.update(0.0, x, (d, en))
        else:
            xn = np.empty_like(x)
            known = x is plant._last_x
            start = 0
            while True:
                start, events, group, need = step_period(
                    x, xn, d, en, plant._last_mech, known, start, plant._group, plant._slots,
                    plant._phis, plant._rates, plant._consts, plant.event_levels,
                    plant.split_budget, self.bus.kernel_args(), self._volt, self._sense_sign,
                    plant._scratch,
                )  # fmt: skip
                plant.n_events += events
                if need < 0:
                    break
                plant._load(group, need)
            plant._last_x = xn
        if heat.on:
            heat_advance(x, xn, heat.kernel_args())
        return xn

    def _step(self) -> None:
        """One servo tick (the module docstring's order)."""
        fw = self.fw
        x = self._x
        k = self.tick
        keep = self._keep_log
        scalar = self._scalar
        if keep:
            if k >= self._cap:
                self._grow()
            # The plant state at the sampling instant, where the firmware sees it.
            self._log_plant(k, x)
            if "bus_v" in self._arrays:
                self._arrays["bus_v"][k] = self.bus_v
            if "winding_c" in self._arrays:
                self._arrays["winding_c"][k] = self.heat.winding_c()
        if self._record_inputs:
            self._states.append(x.copy())
        counts = self.encoder.read(x, self._noise_rows)
        spi = self.encoder.spi_frames()  # None: valid frames (no fault injected)
        if spi is None:  # (a firmware object of a test may not take the frames)
            tx = fw.servo_tick(int(counts[0]) if scalar else counts, self._rx_for_board,
                               self.uart_tx.free)  # fmt: skip
        else:
            tx = fw.servo_tick(int(counts[0]) if scalar else counts, self._rx_for_board,
                               self.uart_tx.free, encoder_spi=spi)  # fmt: skip
        if tx:
            self.uart_tx.write(tx)
        t = k * self.dt_s
        n = self.n
        for _ in range(self.multiple):
            # sim.bridge.sensed_current_a and adc_counts, with the duty's sign kept from
            # the last period.
            draw = self._adc_draw() if self._adc_noisy else _NO_DRAW
            adc = np.empty(n, dtype=np.int64)
            read_adc(x, self._sense_sign, self._a_per_lsb_n, self._adc_noise_n, draw,
                     self._adc_full, adc, (self._duty, self._volt, self._sense_table))  # fmt: skip
            bus_adc = np.empty(n, dtype=np.int64)
            read_bus_adc(self.bus.kernel_args(), self._vs_n, self._adc_full, bus_adc)
            extra = () if not self._reads_bus else (int(bus_adc[0]) if scalar else bus_adc,)
            if scalar:  # the one-axis API: floats in and out
                duty_in, enable_in = self._one_duty, self._one_enable
                duty_in[0], enable_in[0] = fw.current_tick(int(adc[0]), *extra)
                duty, enable = duty_in, enable_in
            else:
                duty, enable = fw.current_tick(adc, *extra)
                if not (isinstance(duty, np.ndarray) and duty.shape == (n,)):
                    duty = np.broadcast_to(np.asarray(duty, dtype=float), (n,))
                if not (isinstance(enable, np.ndarray) and enable.shape == (n,)):
                    enable = np.broadcast_to(np.asarray(enable, dtype=bool), (n,))
            # New arrays (the firmware may reuse its own), the duty on the timer's steps
            # (sim.bridge.quantise_duty).
            d, en = np.empty(n), np.empty(n, dtype=bool)
            # Both high sides on while the project's firmware calibrates its IS offset.
            high = fw.bridge_high_sides if self._reads_bus else _NO_HIGH_SIDES
            apply_bridge(
                duty, enable, high, self._arr_n, self._vs_n, d, en, self._sense_sign, self._volt
            )
            switching(x, self._vs_n, self._shifts, d, self._sense_sign, self._volt)
            self._duty, self._enable = d, en
            if self._record_inputs:
                self._inputs.append((d.copy(), en.copy()))
            x = self._plant_period(x, d, en)
            t += self.h_s
        self._x = x
        if keep:
            arrays = self._arrays
            for f, v in zip(FW_FIELDS, self._signal_row(), strict=True):
                arrays[f][k] = v
            arrays["voltage_v"][k] = self._volt
        self.tick += 1
        self._move_bytes()


def run(
    exp: Experiment,
    *,
    seed: int = 0,
    batch: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    overrides: Mapping[str, Any] | None = None,
    firmware: Any = None,
) -> RunResult:
    """Run an experiment: the scripted PC sends each command as a wire frame through the
    emulated UART at its time, the board answers, the PC decodes what it receives.

    ``progress(tick, n_ticks)`` is called about 200 times over the run and at its end.
    """
    sim = Simulation(exp.bench, batch=batch, seed=seed, overrides=overrides, firmware=firmware)
    n_ticks = int(round(exp.duration_s / sim.dt_s))
    # Each command goes out at the first tick boundary at or after its time.
    schedule = [(math.ceil(c.t_s / sim.dt_s - 1e-9), c) for c in exp.commands]
    seq = 0
    cmd_id = 0
    session = 0  # the scripted PC opens session 1 before its first command
    nxt = 0
    every = max(1, n_ticks // 200)
    sim.reserve(n_ticks)
    tick = 0
    while tick < n_ticks:
        while nxt < len(schedule) and schedule[nxt][0] <= tick:
            cmd = schedule[nxt][1]
            if cmd.type != "raw" and (session == 0 or cmd.type == "hello"):
                session = session % 0xFFFF + 1
                if cmd.type != "hello":
                    cmd_id = (cmd_id + 1) & 0xFFFF
                    sim.pc_write(frame.encode(Hello(cmd_id, session=session), seq))
                    seq = (seq + 1) & 0xFF
            cmd_id = (cmd_id + 1) & 0xFFFF
            m = cmd.message(cmd_id, session)
            if isinstance(m, bytes):
                sim.pc_write(m)
            else:
                sim.pc_write(frame.encode(m, seq))
                seq = (seq + 1) & 0xFF
            nxt += 1
        # Step in one call up to the next command or progress report.
        stop = n_ticks
        if nxt < len(schedule):
            stop = min(stop, max(schedule[nxt][0], tick + 1))
        if progress is not None:
            stop = min(stop, (tick // every + 1) * every)
        sim.step(stop - tick)
        tick = stop
        if progress is not None and (tick % every == 0 or tick == n_ticks):
            progress(tick, n_ticks)
    counters = dict(getattr(sim.fw, "counters", {}))
    # The simulation ends here: a batch log's buffers become the result's, without copies.
    log = sim._log(copy=False)
    return RunResult(log, sim.pc_read(), sim.link_stats(), exp, counters)


# Log buffers (``Simulation._grow``) kept for the next run once no log views them: a fresh
# allocation of a batch log is page faults and the kernel zeroing every page (N = 256, 2 s:
# 28 MB, ~7,000 4 kB pages, or huge pages; glibc gives a freed block of that size back to the
# system or keeps it, depending on its thresholds), a tuner's or a study's runs of one size
# reuse one buffer instead. At most _POOL_KEEP buffers, each at most _POOL_MAX_BYTES.
_POOL: list[np.ndarray] = []
_POOL_LOCK = threading.Lock()
_POOL_KEEP = 2
_POOL_MAX_BYTES = 1 << 27


def _alone_count() -> int:
    """``sys.getrefcount`` of a pooled buffer that only the pool holds (measured, not
    assumed: an interpreter may count its own references differently), or -1 (never free:
    no reuse) if a view does not show in the count."""
    probe = [np.empty(8, dtype=np.uint8)]
    alone = sys.getrefcount(probe[0])
    view = probe[0][:4]
    return alone if view.base is probe[0] and sys.getrefcount(probe[0]) > alone else -1


_POOL_ALONE = _alone_count()


def _log_buffer(size: int) -> np.ndarray:
    """``size`` bytes (uint8) for a log: a view of a kept buffer that nothing views any more
    (its reference count is the pool's alone: every log column is a view whose base is the
    buffer), or a new buffer, kept for later if not too large."""
    with _POOL_LOCK:  # another thread's Simulation must not take the same buffer
        for k in range(len(_POOL)):
            if _POOL[k].shape[0] >= size and sys.getrefcount(_POOL[k]) == _POOL_ALONE:
                return _POOL[k][:size]
        buf = np.empty(size, dtype=np.uint8)
        if size <= _POOL_MAX_BYTES:
            if len(_POOL) >= _POOL_KEEP:
                # Forget a free one first (a busy one is still some log's memory).
                free = [k for k in range(len(_POOL)) if sys.getrefcount(_POOL[k]) == _POOL_ALONE]
                del _POOL[free[0] if free else 0]
            _POOL.append(buf)
        return buf


# The arithmetics whose compiled tick this process has loaded.
_LOADED: set[bool] = set()
_ASIDE: list[Any] = []  # the second compiling process of _compile_plant_aside (one try)
_ASIDE_CODE = (
    "import pickle, sys; sys.path.insert(0, {root!r}); "
    "from sim.supply import step_period; "
    "from firmware_model.laws.float64 import reset_control; "
    "plant, reset = pickle.loads(sys.stdin.buffer.read()); "
    "step_period.compile(plant); reset_control.compile(reset)"
)


# How long the tick's compile waits for the second process's plant step when its typing
# reaches the call first (``_compile_plant_aside``), before compiling the step itself (~1.5 s
# with its callees in the cache already).
_ASIDE_WAIT_S = 2.0


def _compile_plant_aside(sim: Simulation) -> None:
    """With an empty numba cache the first ``run_ticks`` of a process compiles for ~15-20 s;
    the plant's step (``sim.supply.step_period``, ~6-8 s of it) depends on nothing else of
    the tick, so a second process compiles it meanwhile (2 cores) and ``run_ticks`` loads it
    from the cache when its typing reaches the call, ~8 s in (numba's dispatcher looks in the
    cache before it compiles: if the second process is still at it then, the dispatcher waits
    for its entry, at most ``_ASIDE_WAIT_S``); then the law's ``reset_control`` (0.6 s), first
    called by the boot after the tick is compiled. If the second process cannot start, or
    lags, the tick compiles the step itself: the same machine code either way. Does nothing
    once the step is in the cache (its index is read, the step not loaded)."""
    if _ASIDE:
        return
    _ASIDE.append(None)
    import os
    import pickle
    import subprocess
    from pathlib import Path

    import numba
    from numba.core import types

    plant = sim.plant
    x = sim._x
    # Exactly the types run_ticks passes (sim/tick.py, the PLANT stage).
    argtypes = (
        *(numba.typeof(v) for v in (x, x, sim._duty.astype(float), sim._enable.astype(bool),
                                    plant._last_mech)),
        types.boolean, types.int64,
        *(numba.typeof(v) for v in (plant._group, plant._slots, plant._phis, plant._rates,
                                    plant._consts, plant.event_levels, plant.split_budget,
                                    sim.bus.kernel_args(), sim._volt, sim._sense_sign,
                                    plant._scratch)),
    )  # fmt: skip
    cache = step_period._cache
    try:
        key = cache._index_key(argtypes, step_period.targetctx.codegen())
        if key in cache._cache_file._load_index():
            return  # in the cache: nothing to compile
        proc = subprocess.Popen(
            [sys.executable, "-c", _ASIDE_CODE.format(root=str(Path(__file__).parents[1]))],
            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            env=dict(os.environ),
        )  # fmt: skip
        law = sim.fw.law
        # Then the law's reset (its first call is the boot's, after the tick is compiled).
        reset = (types.Array(types.boolean, 1, "C"),
                 *(numba.typeof(a) for a in (law.P, law.C, law.S, law.K)))  # fmt: skip
        proc.stdin.write(pickle.dumps((argtypes, reset)))
        proc.stdin.close()
    except (OSError, AttributeError, pickle.PicklingError):
        return  # no second process (or another numba): run_ticks compiles the step
    _ASIDE[0] = proc
    cache.before_load = _awaiting(proc, key)


def _awaiting(proc: Any, key: Any) -> Callable[[Any, Any, Any], None]:
    """``before_load`` of the plant step's cache while the second process compiles it: a
    load of that entry (``key``) waits until the process has written it, has ended, or
    ``_ASIDE_WAIT_S`` has passed; other loads go on at once."""
    import time

    def before_load(cache: Any, sig: Any, target_context: Any) -> None:
        if cache._index_key(sig, target_context.codegen()) != key:
            return
        deadline = time.monotonic() + _ASIDE_WAIT_S
        while proc.poll() is None and time.monotonic() < deadline:
            try:
                if key in cache._cache_file._load_index():
                    return
            except Exception:  # an index being replaced, or unreadable: read it again
                pass  # (numba renames a finished index into place; the wait is bounded)
            time.sleep(0.01)

    return before_load


def _end_aside() -> None:
    """``run_ticks`` is loaded: stop the second compiling process if it still runs (the tick
    has its step then; numba writes a cache entry by renaming a finished file, so a stopped
    writer leaves no half entry)."""
    step_period._cache.before_load = None
    if _ASIDE and _ASIDE[0] is not None:
        proc, _ASIDE[0] = _ASIDE[0], None
        if proc.poll() is None:
            proc.kill()
        proc.wait()


@contextmanager
def compile_notice(stream: Any = None) -> Iterator[None]:
    """Say on stderr what is happening if the block takes more than a second: numba
    compiling the kernels (once after an install; then they load from ``__pycache__``)."""
    stream = stream if stream is not None else sys.stderr

    def say() -> None:
        stream.write(
            "loading the simulation's compiled kernels (the first time after an install or "
            "a change they are compiled: 10-60 s, then cached)...\n"
        )
        stream.flush()

    timer = threading.Timer(1.0, say)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()


def warm_up(bench: BenchConfig, *, batch: int | None = None) -> None:
    """Load the compiled tick with the types a run of ``bench`` uses (numba's start-up:
    from its cache in a few tenths of a second, or compiled the first time after an
    install, with a message), so that a caller can time it apart from the run."""
    sim = Simulation(bench, batch=batch)
    with compile_notice():
        sim.step(1)  # the boot tick, in the compiled tick (STOP_BOOT)
        ftick.framer_ok()
        if sim._compiled:
            sim._run_compiled(0)  # the compiled tick, stopping at once


def uart_faults(uart: UartParams) -> FaultInjection | None:
    """The line faults of ``[uart]`` (both directions), or None for a clean line."""
    rates = (uart.bit_flip_rate, uart.drop_rate, uart.insert_rate, uart.burst_rate)
    if not any(rates):
        return None
    return FaultInjection(*rates, burst_bytes=uart.burst_bytes)


_NO_DRAW = np.empty(0)
_NO_HIGH_SIDES = np.empty(0, dtype=np.int64)  # a foreign firmware: never both high sides
# The compiled framers' tables (run_ticks' ``tables``).
_TABLES = (ftick.TABLES, ftick.HEARTBEAT_TABLES)
