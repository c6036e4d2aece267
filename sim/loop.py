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
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from operator import itemgetter
from typing import Any

import numba
import numpy as np

from firmware_model.firmware import SIGNAL_NAMES
from serial_protocol import frame
from serial_protocol.exceptions import ConfigError
from serial_protocol.messages import Hello, Telemetry
from serial_protocol.uart import EmulatedUart, FaultInjection
from sim.config import TABLES, BenchConfig, Experiment, check_bench
from sim.encoder import Encoder
from sim.params import PlantParams, UartParams, per_member
from sim.plant import I_A, TWIST, VEL, Plant

__all__ = ["LOG_FIELDS", "RunLog", "RunResult", "Simulation", "apply_overrides", "run"]

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
)
LOG_FIELDS = ("t_s",) + FW_FIELDS + PLANT_FIELDS
_INT_FIELDS = ("state", "fault")


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
    ``duty * V_supply`` (0 while disabled). ``current_a`` is the true armature current,
    ``current_meas_a`` the firmware's signed reading of the IS pin.
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
        record_inputs: keep the ``(duty, enable)`` of every plant step (``inputs()``), e.g.
            to replay a run through ``solve_ivp``.
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
        self._deg_per_rad_axis = math.degrees(1.0) / plant.gearbox.ratio
        self._n_total = plant.total_ratio
        self.plant = Plant(plant, n, self.h_s, bench.loop.event_levels)
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
        self._xlog = np.empty((0, n, 5))
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
        signal_row = getattr(firmware, "signal_row", None)
        if signal_row is None:
            pick, signals = itemgetter(*FW_FIELDS), firmware.signals

            def signal_row() -> tuple[Any, ...]:
                return pick(signals())

        self._signal_row = signal_row

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

    def step(self, n_ticks: int = 1) -> None:
        """Advance ``n_ticks`` servo ticks."""
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

        cols = {f: columns(a[:n]) for f, a in self._arrays.items()}
        x = self._xlog[:n]  # (n, N, 5)
        pos = x[:, :, 1]
        # New (n, N) arrays: their transposes need no copy.
        cols["true_pos_deg"] = (pos * self._deg_per_rad_axis).T
        cols["true_vel_dps"] = (x[:, :, VEL] * self._deg_per_rad_axis).T
        cols["platter_pos_deg"] = np.degrees(pos / self._n_total - x[:, :, TWIST]).T
        cols["motor_pos_rad"] = columns(pos)
        cols["current_a"] = columns(x[:, :, I_A])
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
        for f in (*FW_FIELDS, "voltage_v"):
            dtype = np.int64 if f in _INT_FIELDS else float
            new = np.empty((cap, n), dtype=dtype)  # row per tick: contiguous writes
            if f in self._arrays:
                new[: self._cap] = self._arrays[f][: self._cap]
            self._arrays[f] = new
        # The plant state at each sampling instant; log() derives its columns.
        new = np.empty((cap, n, 5))
        new[: self._cap] = self._xlog[: self._cap]
        self._xlog = new
        self._cap = cap

    def reserve(self, n_ticks: int) -> None:
        """Make room for ``n_ticks`` more log rows at once (batch; ``run`` calls it)."""
        if self._keep_log and self.tick + n_ticks > self._cap:
            self._grow(self.tick + n_ticks)

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
            self._xlog[k] = x
        counts = self.encoder.read(x)
        tx = fw.servo_tick(int(counts[0]) if scalar else counts, self._rx_for_board,
                           self.uart_tx.free)  # fmt: skip
        if tx:
            self.uart_tx.write(tx)
        t = k * self.dt_s
        n = self.n
        for _ in range(self.multiple):
            # sim.bridge.sensed_current_a and adc_counts, with the duty's sign kept from
            # the last period.
            draw = self._rng.standard_normal(n) if self._adc_noisy else _NO_DRAW
            adc = np.empty(n, dtype=np.int64)
            _adc_counts(x, self._sense_sign, self._a_per_lsb_n, self._adc_noise_n, draw,
                        self._adc_full, adc)  # fmt: skip
            if scalar:  # the one-axis API: floats in and out
                duty_in, enable_in = self._one_duty, self._one_enable
                duty_in[0], enable_in[0] = fw.current_tick(int(adc[0]))
                duty, enable = duty_in, enable_in
            else:
                duty, enable = fw.current_tick(adc)
                if not (isinstance(duty, np.ndarray) and duty.shape == (n,)):
                    duty = np.broadcast_to(np.asarray(duty, dtype=float), (n,))
                if not (isinstance(enable, np.ndarray) and enable.shape == (n,)):
                    enable = np.broadcast_to(np.asarray(enable, dtype=bool), (n,))
            # New arrays (the firmware may reuse its own), the duty on the timer's steps
            # (sim.bridge.quantise_duty).
            d, en = np.empty(n), np.empty(n, dtype=bool)
            _bridge(duty, enable, self._arr_n, self._vs_n, d, en, self._sense_sign, self._volt)
            self._duty, self._enable = d, en
            if self._record_inputs:
                self._inputs.append((d.copy(), en.copy()))
            x = self.plant.update(t, x, (d, en))
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


def uart_faults(uart: UartParams) -> FaultInjection | None:
    """The line faults of ``[uart]`` (both directions), or None for a clean line."""
    rates = (uart.bit_flip_rate, uart.drop_rate, uart.insert_rate, uart.burst_rate)
    if not any(rates):
        return None
    return FaultInjection(*rates, burst_bytes=uart.burst_bytes)


_NO_DRAW = np.empty(0)


@numba.njit(cache=True)
def _adc_counts(x, sense_sign, a_per_lsb, noise_lsb, draw, adc_full, out):
    """The ADC counts of the IS pin per member: ``sim.bridge.sensed_current_a`` (the
    current in the direction of ``sense_sign``, the high side only) through
    ``sim.bridge.adc_counts`` (rounded to nearest, plus noise, clamped to the ADC range).
    ``draw``: one standard normal per member, or nothing for a noiseless ADC."""
    noisy = draw.shape[0] > 0
    for j in range(x.shape[0]):
        v = sense_sign[j] * x[j, I_A]
        c = 0.0 if 0.0 >= v else v  # np.maximum(0.0, v); NaN passes
        c = c / a_per_lsb[j] + 0.5
        if noisy:
            c = c + noise_lsb[j] * draw[j]
        c = np.floor(c)
        if c > adc_full:
            c = adc_full
        if c < 0.0:
            c = 0.0
        out[j] = np.int64(c)


@numba.njit(cache=True)
def _bridge(duty, enable, arr, supply_v, d_out, en_out, sense_sign, volt):
    """The bridge per member: the duty clamped to [-1, 1] on the timer's ``1/arr`` steps
    (``sim.bridge.quantise_duty``, half to even), the enable, the IS pin's sign of the
    next period and the average output voltage (0 while disabled)."""
    for j in range(d_out.shape[0]):
        v = duty[j]
        if v < -1.0:
            v = -1.0
        if v > 1.0:
            v = 1.0
        v = np.rint(v * arr[j]) / arr[j]
        e = bool(enable[j])
        d_out[j] = v
        en_out[j] = e
        sign = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else (0.0 if v == 0.0 else v))
        sense_sign[j] = sign if e else 0.0
        volt[j] = v * supply_v[j] if e else 0.0
