"""The firmware's configuration: one frozen dataclass per TOML table of the bench file.

``TABLES`` maps each TOML table path to its dataclass so that the generic loader in
``sim/config.py`` can build them; :class:`FirmwareParams` bundles them. Every dataclass checks
its own fields in ``__post_init__`` and raises ``ValueError("key = value: reason")``.

Gains (the fields of the ``controller.*`` tables) may be floats or numpy arrays of shape
``(N,)`` (one value per batch member, for the offline tuner); a list is turned into an array.

The default gains are derived from the *firmware's* nominal model of the plant
(:data:`NOMINAL`), as a firmware engineer would derive them from the motor's data sheet; the
derivation is in ``docs/model.md`` (section "Firmware") and in :func:`default_gains`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
import numpy.typing as npt

from firmware_model.units import GEAR_RATIO, MOTOR_RAD_S_PER_AXIS_DPS, TOTAL_RATIO

__all__ = [
    "NOMINAL",
    "CurrentLoopGains",
    "EstimatorParams",
    "FirmwareParams",
    "LimitsParams",
    "PositionLoopGains",
    "SafetyParams",
    "ServoParams",
    "TABLES",
    "TelemetryParams",
    "VelocityLoopGains",
    "default_gains",
]

Gain = float | npt.NDArray[np.float64]

#: The firmware's nominal plant model (motor data sheet and bench drawing; assumed values,
#: agreed with the plant model in ``sim/``). Used only to derive default gains and
#: feed-forward terms, and by the stability check of ``SetGains``.
NOMINAL: dict[str, float] = {
    "supply_v": 24.0,
    "resistance_ohm": 1.2,
    "inductance_h": 0.6e-3,
    "kt_nm_per_a": 0.0145,
    # Rotor + magnet + gearbox input, plus the platter (0.08 kg*m^2) reflected through 400:1
    # at 80 % gearbox efficiency: 1.2e-5 + 0.08 / 400**2 / 0.8 = 1.2625e-5.
    "inertia_kgm2": 1.2e-5 + 0.08 / TOTAL_RATIO**2 / 0.8,
    "tick_hz": 500.0,
}


#: Current-loop bandwidth times the sample period (see :func:`default_gains`).
CURRENT_BW_TS = 0.3


def default_gains() -> dict[str, float]:
    """The default gains, derived from :data:`NOMINAL` (see docs/model.md, "Firmware").

    * Current loop (in volts per ampere): bandwidth ``bw`` limited by the 500 Hz loop with
      one tick of compute delay to ``bw * Ts = 0.3`` (150 rad/s: gain margin 3.2 and phase
      margin 68 deg on the sampled static plant, 2.4 and 52 deg with the electrical pole);
      ``Kp = bw * L``, ``Ki = Kp * R / L = bw * R``. Resistive and back-EMF feed-forward do
      the bulk of the work; the PI corrects the model error.
    * Velocity loop (symmetric optimum, a = 2) around the sum of the small lags
      ``T_sigma`` = compute delay + current loop + ZOH + estimator ~ 7.3 ms:
      ``Kp = J / (2 Kt T_sigma)`` [A per motor rad/s], ``Ti = 4 T_sigma``.
    * Position loop: P at a quarter of the velocity crossover ``1 / (2 T_sigma)``.
    """
    ts_s = 1.0 / NOMINAL["tick_hz"]
    bw_current_rad_s = CURRENT_BW_TS / ts_s
    kp_v_per_a = bw_current_rad_s * NOMINAL["inductance_h"]
    ki_v_per_as = kp_v_per_a * NOMINAL["resistance_ohm"] / NOMINAL["inductance_h"]
    estimator_bw_rad_s = 300.0
    t_sigma_s = 1.5 * ts_s + 0.5 * ts_s + 1.0 / estimator_bw_rad_s + 1.0 * ts_s
    kp_a_per_motor_rad_s = NOMINAL["inertia_kgm2"] / (NOMINAL["kt_nm_per_a"] * 2.0 * t_sigma_s)
    kp_a_per_dps = kp_a_per_motor_rad_s * MOTOR_RAD_S_PER_AXIS_DPS
    ki_a_per_deg = kp_a_per_dps / (4.0 * t_sigma_s)
    kp_pos_per_s = 1.0 / (2.0 * t_sigma_s) / 4.0
    return {
        "current.kp_v_per_a": kp_v_per_a,
        "current.ki_v_per_as": ki_v_per_as,
        "current.back_emf_v_per_dps": NOMINAL["kt_nm_per_a"] * MOTOR_RAD_S_PER_AXIS_DPS,
        "velocity.kp_a_per_dps": kp_a_per_dps,
        "velocity.ki_a_per_deg": ki_a_per_deg,
        "velocity.acc_ff_a_per_dps2": NOMINAL["inertia_kgm2"]
        * MOTOR_RAD_S_PER_AXIS_DPS
        / NOMINAL["kt_nm_per_a"],
        "position.kp_per_s": kp_pos_per_s,
        "estimator.bandwidth_rad_s": estimator_bw_rad_s,
        "estimator.accel_per_amp_dps2": NOMINAL["kt_nm_per_a"]
        / NOMINAL["inertia_kgm2"]
        / MOTOR_RAD_S_PER_AXIS_DPS,
    }


_DEFAULTS = default_gains()


def _fail(key: str, value: Any, reason: str) -> None:
    raise ValueError(f"{key} = {value!r}: {reason}")


def _number(key: str, value: Any, *, lo: float = -math.inf, hi: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        _fail(key, value, "must be a number")
    if not math.isfinite(value):
        _fail(key, value, "must be finite")
    if not lo <= value <= hi:
        _fail(key, value, f"must be in [{lo}, {hi}]")
    return float(value)


def _positive(key: str, value: Any) -> float:
    v = _number(key, value)
    if not v > 0.0:
        _fail(key, value, "must be > 0")
    return v


def _integer(key: str, value: Any, *, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        _fail(key, value, "must be an integer")
    if not lo <= value <= hi:
        _fail(key, value, f"must be in [{lo}, {hi}]")
    return int(value)


def _gain(key: str, value: Any) -> Gain:
    """A non-negative finite gain: a float or an ``(N,)`` float array (batch)."""
    if isinstance(value, list | tuple | np.ndarray):
        arr = np.array(value, dtype=float)
        if arr.ndim != 1 or arr.size == 0:
            _fail(key, value, "a gain array must have shape (N,) with N >= 1")
        if not np.all(np.isfinite(arr)):
            _fail(key, value, "must be finite")
        if np.any(arr < 0.0):
            _fail(key, value, "must be >= 0")
        arr.setflags(write=False)
        return arr
    return _number(key, value, lo=0.0)


class _Checked:
    """Mixin: run each field's checker (named in the field metadata) after init."""

    def __post_init__(self) -> None:
        for f in fields(self):  # type: ignore[arg-type]
            check = f.metadata.get("check")
            if check is not None:
                object.__setattr__(self, f.name, check(f.name, getattr(self, f.name)))
        self._check_relations()

    def _check_relations(self) -> None:
        pass


def _f(default: Any, check: Any) -> Any:
    return field(default=default, metadata={"check": check})


def _rng(lo: float, hi: float) -> Any:
    return lambda k, v: _number(k, v, lo=lo, hi=hi)


def _irng(lo: int, hi: int) -> Any:
    return lambda k, v: _integer(k, v, lo=lo, hi=hi)


def _choice(*options: str) -> Any:
    def check(k: str, v: Any) -> str:
        if v not in options:
            _fail(k, v, f"must be one of {options}")
        return str(v)

    return check


def _boolean(k: str, v: Any) -> bool:
    if not isinstance(v, bool):
        _fail(k, v, "must be true or false")
    return bool(v)


@dataclass(frozen=True)
class ServoParams(_Checked):
    """``[servo]``: rates, arithmetic and power-on behaviour of the STM32 firmware.

    Attributes:
        tick_hz: servo (position and velocity loop) rate; seed 000: 500 Hz.
        current_loop_multiple: current-loop runs per servo tick (the paper: 1).
        compute_delay_ticks: current-loop periods between the ADC sample and the PWM update
            that uses it (1: the duty computed now is loaded at the next timer update).
        arithmetic: ``"float"`` (reference) or ``"fixed"`` (int32 Q-format, as on the
            FPU-less STM32F103; see ``firmware_model/fixedpoint.py``).
        start_enabled: power on with the bridge enabled, holding the position it wakes up
            at (handy for scripted runs; a real bench would wait for ``SetEnable``).
    """

    tick_hz: float = _f(500.0, _rng(50.0, 20_000.0))
    current_loop_multiple: int = _f(1, _irng(1, 40))
    compute_delay_ticks: int = _f(1, _irng(0, 4))
    arithmetic: str = _f("float", _choice("float", "fixed"))
    start_enabled: bool = _f(True, _boolean)

    @property
    def dt_s(self) -> float:
        return 1.0 / self.tick_hz


@dataclass(frozen=True)
class CurrentLoopGains(_Checked):
    """``[controller.current]``: current PI (volts out), feed-forward, PWM and current sense.

    The loop output is a voltage: ``R * i_ref + back_emf * vel + Kp e + Ki int(e)``; the duty
    is that voltage over ``supply_v``, clamped to ``duty_limit`` and quantised to
    ``pwm_arr`` timer steps. The sensed current is ``adc / 2^adc_bits * adc_vref_v /
    sense_resistor_ohm * sense_ratio`` (BTN7971 IS pin, high side only), signed by the duty.
    A reading at or below ``sense_floor_counts`` while the reference opposes the duty (or
    no duty is applied) is taken as "the high side carries nothing": the loop then uses its
    reference as the current (see docs/model.md, "The current loop").
    ``sense_offset_counts``: the IS pin's offset as calibrated (the reading with the high
    side on and no current), subtracted from every reading before anything else.
    ``sense_calibration``: measure that offset at every enable instead
    (``firmware_model.sense_calibration``): both high sides on (no voltage across the
    motor, no current at rest) for ``sense_calibration_samples`` current-loop periods, the
    two IS pins read in turn, each pin's mean its own offset (subtracted from the readings
    taken from that pin: the duty's sign picks it); refused (the enable NACKed) if the axis
    turns faster than ``sense_calibration_max_speed_dps``, the two pins' means differ by
    more than ``sense_calibration_pin_counts`` (more than two offsets within the datasheet
    can: a loop current, the motor turns) or a pin's offset is above
    ``sense_offset_max_counts`` (implausible: beyond the chip's datasheet maximum).

    The bus voltage comes in on a second ADC channel through a divider of
    ``bus_divider_ratio``. ``bus_compensation``: the duty is the voltage over the *measured*
    bus instead of ``supply_v``. ``regen_bus_current_limit_a`` (0: off): the velocity loop
    caps its braking current so that the current returned to the bus, about
    ``|i K_e w| / V_bus``, stays below it (ODrive's ``dc_max_negative_current``). From a
    bus reading of ``bus_hold_v`` up (the BTN7971B's over-voltage lock-out may have turned
    the outputs off: its IS pins then read nothing), the current PI holds its integrator.
    """

    kp_v_per_a: Gain = _f(_DEFAULTS["current.kp_v_per_a"], _gain)
    ki_v_per_as: Gain = _f(_DEFAULTS["current.ki_v_per_as"], _gain)
    resistance_ohm: Gain = _f(NOMINAL["resistance_ohm"], _gain)
    back_emf_v_per_dps: Gain = _f(_DEFAULTS["current.back_emf_v_per_dps"], _gain)
    supply_v: float = _f(NOMINAL["supply_v"], _rng(1.0, 60.0))
    duty_limit: float = _f(1.0, _rng(0.05, 1.0))
    pwm_arr: int = _f(3600, _irng(10, 65535))
    sense_ratio: float = _f(8500.0, _rng(100.0, 1e6))
    sense_resistor_ohm: float = _f(1000.0, _rng(1.0, 1e6))
    adc_vref_v: float = _f(3.3, _rng(0.5, 5.5))
    adc_bits: int = _f(12, _irng(8, 16))
    sense_floor_counts: int = _f(2, _irng(0, 100))
    sense_offset_counts: int = _f(0, _irng(0, 4095))
    sense_calibration: bool = _f(False, _boolean)
    sense_calibration_samples: int = _f(16, _irng(2, 1000))
    sense_calibration_max_speed_dps: float = _f(1.0, _rng(0.0, 1e4))
    sense_calibration_pin_counts: int = _f(248, _irng(0, 4095))
    sense_offset_max_counts: int = _f(248, _irng(0, 4095))
    bus_divider_ratio: float = _f(11.0, _rng(1.0, 1000.0))
    bus_compensation: bool = _f(False, _boolean)
    regen_bus_current_limit_a: float = _f(0.0, _rng(0.0, 100.0))
    bus_hold_v: float = _f(27.8, _rng(1.0, 100.0))

    def _check_relations(self) -> None:
        if self.sense_calibration_samples % 2:
            _fail(
                "sense_calibration_samples", self.sense_calibration_samples,
                "must be even (half of the readings from each IS pin)",
            )  # fmt: skip

    @property
    def v_per_bus_adc(self) -> float:
        """Volts of bus per count of its ADC channel (through the divider; 8.86 mV)."""
        return self.adc_vref_v / float(1 << self.adc_bits) * self.bus_divider_ratio

    @property
    def a_per_adc(self) -> float:
        """Amperes per ADC count of the IS-pin reading (6.85 mA with the defaults)."""
        full_scale = float(1 << self.adc_bits)
        return self.adc_vref_v / full_scale / self.sense_resistor_ohm * self.sense_ratio


@dataclass(frozen=True)
class VelocityLoopGains(_Checked):
    """``[controller.velocity]``: velocity PI (amperes out, axis deg/s in) + inertia
    feed-forward ``acc_ff_a_per_dps2 * sp_acc_dps2``."""

    kp_a_per_dps: Gain = _f(_DEFAULTS["velocity.kp_a_per_dps"], _gain)
    ki_a_per_deg: Gain = _f(_DEFAULTS["velocity.ki_a_per_deg"], _gain)
    acc_ff_a_per_dps2: Gain = _f(_DEFAULTS["velocity.acc_ff_a_per_dps2"], _gain)


@dataclass(frozen=True)
class PositionLoopGains(_Checked):
    """``[controller.position]``: position P (axis deg/s per deg) + velocity feed-forward
    (``vel_ff`` = 1 passes the planner's velocity through)."""

    kp_per_s: Gain = _f(_DEFAULTS["position.kp_per_s"], _gain)
    vel_ff: Gain = _f(1.0, _gain)


@dataclass(frozen=True)
class EstimatorParams(_Checked):
    """``[estimator]``: velocity observer on the unwrapped encoder count (the digital
    tracking loop of a resolver-to-digital converter, one order up): position, velocity and
    an acceleration disturbance (friction, load), all three poles at
    ``exp(-bandwidth_rad_s * dt_s)``.

    ``accel_per_amp_dps2`` (nominal Kt / J in axis deg/s^2 per A; 0 = off) feeds the
    current of the period that just ended (the reference of the duty applied in it plus the
    model error seen at the last ADC sample) into the prediction as a known acceleration, so
    that the estimate does not lag behind a current step; the disturbance state absorbs what
    the model gets wrong.
    """

    bandwidth_rad_s: float = _f(_DEFAULTS["estimator.bandwidth_rad_s"], _rng(1.0, 5000.0))
    accel_per_amp_dps2: float = _f(_DEFAULTS["estimator.accel_per_amp_dps2"], _rng(0.0, 1e7))

    def observer_gains(self, dt_s: float) -> tuple[float, float, float]:
        """Gains ``(k_pos, k_vel, k_acc)`` of the third-order observer (position, velocity,
        acceleration disturbance, in tick units) with a triple pole at
        ``exp(-bandwidth_rad_s * dt_s)`` (Ackermann's formula on the error dynamics
        ``(I - K H) F``)."""
        r = math.exp(-self.bandwidth_rad_s * dt_s)
        f = np.array([[1.0, 1.0, 0.5], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
        h = np.array([[1.0, 0.0, 0.0]])
        obs = np.vstack([h, h @ f, h @ f @ f])
        c = np.poly([r, r, r])
        phi = sum(c[i] * np.linalg.matrix_power(f, 3 - i) for i in range(4))
        gain_l = phi @ np.linalg.solve(obs, np.array([0.0, 0.0, 1.0]))
        k = np.linalg.solve(f, gain_l)
        return float(k[0]), float(k[1]), float(k[2])


@dataclass(frozen=True)
class LimitsParams(_Checked):
    """``[limits]``: what a ``Move`` may ask for and the following-error trip (all axis).

    ``v_max_dps`` and ``a_max_dps2`` are the largest values a ``Move`` may carry (and the
    velocity clamp of the position loop); ``Stop`` with ``a_max_dps2 = 0`` uses
    ``a_max_dps2``. ``in_position_deg`` ends a ``STEP`` move (no planner to say so).
    """

    v_max_dps: float = _f(1000.0, _rng(1.0, 1e5))
    a_max_dps2: float = _f(2000.0, _rng(1.0, 1e7))
    current_limit_a: float = _f(5.0, _rng(0.01, 50.0))
    following_error_deg: float = _f(30.0, _rng(1e-3, 1e6))
    travel_min_deg: float = _f(-1e5, _rng(-1e6, 1e6))
    travel_max_deg: float = _f(1e5, _rng(-1e6, 1e6))
    in_position_deg: float = _f(0.5, _rng(1e-4, 1e3))

    def _check_relations(self) -> None:
        if not self.travel_min_deg < self.travel_max_deg:
            _fail("travel_max_deg", self.travel_max_deg, "must be > travel_min_deg")


@dataclass(frozen=True)
class SafetyParams(_Checked):
    """``[safety]``: trip thresholds. Each trip latches a ``Fault``, brakes (``brake_s``)
    and disables the bridge and sends a ``FaultReport``; only ``ClearFault`` clears it.

    Attributes:
        over_current_a: |sensed current| above this for ``over_current_ticks`` samples.
        over_speed_dps: |estimated axis velocity| above this.
        encoder_jump_counts: |reading - predicted reading| above this in one tick
            (a physically impossible jump: at 5 A the motor moves ~60 counts off prediction).
        encoder_stuck_ticks: the raw reading unchanged this many ticks while the position
            loop asks for more than ``encoder_stuck_min_vel_dps``.
        watchdog_s: no valid frame from the PC for this long while enabled (0 = off).
        position_limit_margin_deg: the estimated axis position beyond ``[limits]
            travel_min_deg .. travel_max_deg`` by more than this (every trajectory is planned
            within the travel; this trip catches what planning cannot, e.g. an axis dragged
            or coasting past the end).
        sensor_mismatch_deg: how far the axis moved by the motor's back-EMF beyond what the
            encoder and the model's tolerance (``sensor_mismatch_tolerance_dps`` + ``_ratio``
            times the speed) explain, over a leaky window of ``sensor_mismatch_window_s``,
            above this: a frozen or implausible encoder, or a runaway
            (``firmware_model.safety.sensor_mismatch_step``).
        sensor_mismatch_sense_spread, sensor_mismatch_offset_counts, sensor_mismatch_r_spread:
            what the check does not know, so that a healthy board within its datasheet
            spreads never trips it (the back-EMF speed becomes an interval): the chip's
            k_ILIS relative to ``[controller.current] sense_ratio`` within ``1 ±`` the
            spread (0.65: the BTN7971's 3k-14k around 8.5k, no gain calibration), the IS
            reading's offset left after ``sense_offset_counts`` within ± this many counts
            (62: 50 uA through the 1 kOhm sense resistor; with ``[controller.current]
            sense_calibration`` ``sensor_mismatch_calibrated_offset_counts`` instead, 2: what
            the calibration leaves), the winding's resistance within ``resistance_ohm * (1
            ±`` the spread) (0.3: a part's spread), raised by the thermal protection's
            estimated rise since power-up when that is on, and by a warm restart's
            (``sensor_mismatch_restart_rise_k``; docs/model.md "Safety", the decision).
        sensor_mismatch_restart_rise_k: with the thermal protection on, how much warmer
            than its assumed ambient the motor may have been at power-up (a warm restart
            the estimate cannot see), in K of winding and housing; the check's upper R
            end takes the estimate plus that excess as it decays through the protection's
            own network (``firmware_model.tick.servo_stage``). 0: none. 80 by default: the
            trip's 120 degC less the assumed 40 degC ambient, the hottest restart of a board
            that stops at its trip.
        encoder_diag_ticks: the AS5048 reports an error (SPI parity, EF, CORDIC overflow,
            magnetic field out of range, offset compensation not finished) this many ticks
            in a row.
        brake_s: the fault reaction of every trip but over-current: dynamic braking (both
            low-side switches on, duty 0: the motor's back-EMF drives a braking current
            through its own resistance; no sensor needed) for this long, then the bridge
            off. 0 = the bridge off at once (the motor coasts). Over-current always turns
            the bridge off at once.
        brake_current_limit_a: a cap on that brake's current (A; 0 = none, the full short,
            bounded only by the BTN7971B's own current limitation). The short's current is
            the back-EMF over R; the firmware cannot measure it (its sense is the high
            sides' IS pins), so it holds the short off, the bridge off and the motor
            coasting, until its model predicts the short's current at or below the cap,
            ``|k_emf v| <= R cap``, then shorts for ``brake_s``. Coasting returns nothing to
            the bus while the back-EMF stays below it (docs/model.md, "The brake's current
            after a bus trip").
        thermal_protection: the firmware's estimate of the winding temperature
            (``firmware_model.thermal.thermal_protection``: the two-node network of
            ``firmware_model.thermal`` fed with ``i_meas^2 R(T)`` into the winding and
            ``thermal_no_load_current_a`` times the back-EMF into the housing, from
            ``thermal_ambient_c`` at power-up). From ``thermal_derate_c`` the current limit
            falls linearly to ``thermal_derate_min_ratio`` of itself at ``thermal_trip_c``,
            where the ``THERMAL`` trip latches. The network's constants are the firmware's
            copy of the motor's (``thermal_r_*``, ``thermal_tau_*``, ``thermal_alpha_cu_per_k``).
        thermal_ff_resistance: the current loop's feed-forward resistance (and its
            regenerative clamp's) follows the rise the same estimate has seen since
            power-up, ``R_nom (1 + alpha (T_est - thermal_ambient_c))`` (``R_nom``:
            ``[controller.current] resistance_ohm``, taken as the power-up value); needs
            ``thermal_protection`` (off, or without it: ``R_nom``).
        thermal_ff_back_emf: the current loop's back-EMF feed-forward constant (and its
            regenerative clamp's and the regenerative bus-current limit's) follows the
            same estimate, ``k_emf (1 + thermal_magnet_tc_per_k (T_est -
            thermal_ambient_c))`` (``k_emf``: ``[controller.current] back_emf_v_per_dps``,
            the power-up value): the magnets weaken as the motor warms, and a cold
            ``k_emf`` drives a reversing current past the limit (docs/model.md, "Thermal
            protection"); needs ``thermal_protection``.
        thermal_magnet_tc_per_k: the firmware's copy of the magnets' remanence coefficient
            (1/K; hard ferrite -0.002, sintered NdFeB about -0.001).
    """

    over_current_a: float = _f(7.5, _rng(0.01, 60.0))
    over_current_ticks: int = _f(2, _irng(1, 1000))
    over_speed_dps: float = _f(1100.0, _rng(1.0, 1e5))
    encoder_jump_counts: int = _f(1024, _irng(16, 8191))
    encoder_stuck_ticks: int = _f(100, _irng(2, 100_000))
    encoder_stuck_min_vel_dps: float = _f(20.0, _rng(0.01, 1e5))
    watchdog_s: float = _f(0.0, _rng(0.0, 3600.0))
    position_limit_margin_deg: float = _f(5.0, _rng(0.0, 1e5))
    sensor_mismatch_deg: float = _f(0.75, _rng(0.01, 1e5))
    sensor_mismatch_window_s: float = _f(0.05, _rng(0.004, 10.0))
    sensor_mismatch_tolerance_dps: float = _f(50.0, _rng(0.0, 1e5))
    sensor_mismatch_tolerance_ratio: float = _f(0.25, _rng(0.0, 10.0))
    encoder_diag_ticks: int = _f(3, _irng(1, 1000))
    brake_s: float = _f(0.4, _rng(0.0, 10.0))
    brake_current_limit_a: float = _f(0.0, _rng(0.0, 100.0))
    thermal_protection: bool = _f(True, _boolean)
    thermal_derate_c: float = _f(100.0, _rng(-40.0, 250.0))
    thermal_trip_c: float = _f(120.0, _rng(-40.0, 250.0))
    thermal_derate_min_ratio: float = _f(0.5, _rng(0.0, 1.0))
    thermal_ambient_c: float = _f(40.0, _rng(-40.0, 125.0))
    thermal_alpha_cu_per_k: float = _f(0.00393, _rng(0.0, 0.01))
    thermal_r_winding_housing_k_w: float = _f(2.5, _rng(0.01, 100.0))
    thermal_r_housing_ambient_k_w: float = _f(6.0, _rng(0.01, 100.0))
    thermal_tau_winding_s: float = _f(30.0, _rng(0.1, 3600.0))
    thermal_tau_housing_s: float = _f(900.0, _rng(1.0, 1e5))
    thermal_no_load_current_a: float = _f(0.4, _rng(0.0, 10.0))
    thermal_ff_resistance: bool = _f(True, _boolean)
    thermal_ff_back_emf: bool = _f(True, _boolean)
    thermal_magnet_tc_per_k: float = _f(-0.002, _rng(-0.01, 0.0))
    sensor_mismatch_measured_bus: bool = _f(False, _boolean)
    sensor_mismatch_sense_spread: float = _f(0.65, _rng(0.0, 0.99))
    sensor_mismatch_offset_counts: int = _f(62, _irng(0, 4095))
    sensor_mismatch_calibrated_offset_counts: int = _f(2, _irng(0, 4095))
    sensor_mismatch_r_spread: float = _f(0.3, _rng(0.0, 0.99))
    sensor_mismatch_restart_rise_k: float = _f(80.0, _rng(0.0, 300.0))
    bus_voltage_check: bool = _f(False, _boolean)
    bus_over_voltage_v: float = _f(27.0, _rng(1.0, 100.0))
    bus_under_voltage_v: float = _f(18.0, _rng(0.0, 100.0))
    bus_voltage_samples: int = _f(1, _irng(1, 1000))

    def _check_relations(self) -> None:
        if not self.thermal_derate_c < self.thermal_trip_c:
            _fail(
                "thermal_derate_c", self.thermal_derate_c,
                f"must be below thermal_trip_c ({self.thermal_trip_c:g})",
            )  # fmt: skip
        if not self.bus_under_voltage_v < self.bus_over_voltage_v:
            _fail(
                "bus_under_voltage_v",
                self.bus_under_voltage_v,
                f"must be below bus_over_voltage_v ({self.bus_over_voltage_v})",
            )


@dataclass(frozen=True)
class TelemetryParams(_Checked):
    """``[telemetry]``: the board's UART and its telemetry rate.

    ``decimation`` is the requested rate (1 = every tick, 0 = off); the firmware raises it
    automatically when a telemetry frame per tick does not fit ``baud`` (8N1, 10 bits per
    byte) with ``reply_reserve`` of the link kept free for replies. ``heartbeat_s`` is the
    period of the board's ``BoardHeartbeat`` (0 = none, otherwise at least one servo tick; it is
    rounded to whole ticks).
    """

    decimation: int = _f(1, _irng(0, 65535))
    baud: int = _f(460_800, _irng(1200, 12_000_000))
    reply_reserve: float = _f(0.2, _rng(0.0, 0.9))
    reply_queue_frames: int = _f(32, _irng(1, 255))
    heartbeat_s: float = _f(0.2, _rng(0.0, 60.0))


@dataclass(frozen=True)
class FirmwareParams:
    """Every firmware table; built by ``sim/config.py`` or with defaults for tests."""

    servo: ServoParams = field(default_factory=ServoParams)
    current: CurrentLoopGains = field(default_factory=CurrentLoopGains)
    velocity: VelocityLoopGains = field(default_factory=VelocityLoopGains)
    position: PositionLoopGains = field(default_factory=PositionLoopGains)
    estimator: EstimatorParams = field(default_factory=EstimatorParams)
    limits: LimitsParams = field(default_factory=LimitsParams)
    safety: SafetyParams = field(default_factory=SafetyParams)
    telemetry: TelemetryParams = field(default_factory=TelemetryParams)

    def __post_init__(self) -> None:
        if not self.limits.current_limit_a < self.safety.over_current_a:
            _fail(
                "current_limit_a",
                self.limits.current_limit_a,
                f"must be below safety.over_current_a = {self.safety.over_current_a}",
            )
        if not self.limits.v_max_dps < self.safety.over_speed_dps:
            _fail(
                "v_max_dps",
                self.limits.v_max_dps,
                f"must be below safety.over_speed_dps = {self.safety.over_speed_dps}",
            )
        # The bus trips (as SetLimits checks them): over above the supply, at most the
        # level from which the BTN7971B may have locked out (the trip would come after
        # it); under below the supply (else either trips as soon as the bridge is enabled).
        s, cur = self.safety, self.current
        if s.bus_voltage_check:
            if not cur.supply_v <= s.bus_over_voltage_v <= cur.bus_hold_v:
                _fail(
                    "bus_over_voltage_v",
                    s.bus_over_voltage_v,
                    f"must lie in [controller.current] supply_v .. bus_hold_v "
                    f"({cur.supply_v:g} .. {cur.bus_hold_v:g} V) with bus_voltage_check",
                )
            if not s.bus_under_voltage_v <= cur.supply_v:
                _fail(
                    "bus_under_voltage_v",
                    s.bus_under_voltage_v,
                    f"must not be above [controller.current] supply_v ({cur.supply_v:g} V) "
                    "with bus_voltage_check",
                )
        # The watchdog counts whole ticks: at or below one tick it would never see a frame
        # arrive in time (and rounds to 0 ticks, which is "off").
        watchdog_s = self.safety.watchdog_s
        if watchdog_s != 0.0 and not watchdog_s > self.servo.dt_s:
            _fail(
                "watchdog_s",
                watchdog_s,
                f"must be 0 (off) or longer than one servo tick ({self.servo.dt_s:g} s at "
                f"servo.tick_hz = {self.servo.tick_hz:g})",
            )
        # The board heartbeat is counted in whole ticks too: below one tick it would round
        # to 0 ticks, which is "none" — a heartbeat asked for and silently never sent.
        heartbeat_s = self.telemetry.heartbeat_s
        if heartbeat_s != 0.0 and not heartbeat_s >= self.servo.dt_s:
            _fail(
                "heartbeat_s",
                heartbeat_s,
                f"must be 0 (none) or at least one servo tick ({self.servo.dt_s:g} s at "
                f"servo.tick_hz = {self.servo.tick_hz:g})",
            )
        # An encoder can only be unwrapped if the motor turns < half a revolution per tick
        # off the prediction; the over-speed trip must sit below one revolution per tick.
        rev_per_tick_dps = 360.0 / GEAR_RATIO * self.servo.tick_hz
        if not self.safety.over_speed_dps < rev_per_tick_dps:
            _fail(
                "over_speed_dps",
                self.safety.over_speed_dps,
                f"must be below one motor revolution per tick ({rev_per_tick_dps} dps)",
            )

    @classmethod
    def from_tables(cls, tables: dict[str, Any]) -> FirmwareParams:
        """Build from ``{table path: dataclass instance}`` (missing tables get defaults)."""
        kwargs = {}
        for path, name in _FIELD_OF_TABLE.items():
            if path in tables:
                kwargs[name] = tables[path]
        return cls(**kwargs)

    def batch_size(self) -> int | None:
        """N if any gain is an ``(N,)`` array (all arrays must agree), else None."""
        sizes = set()
        for part in (self.current, self.velocity, self.position):
            for f in fields(part):
                value = getattr(part, f.name)
                if isinstance(value, np.ndarray):
                    sizes.add(value.shape[0])
        if len(sizes) > 1:
            _fail("gains", sorted(sizes), "gain arrays must all have the same length N")
        return sizes.pop() if sizes else None


#: TOML table path -> dataclass (the generic loader's map).
TABLES: dict[str, type] = {
    "servo": ServoParams,
    "controller.current": CurrentLoopGains,
    "controller.velocity": VelocityLoopGains,
    "controller.position": PositionLoopGains,
    "estimator": EstimatorParams,
    "limits": LimitsParams,
    "safety": SafetyParams,
    "telemetry": TelemetryParams,
}

_FIELD_OF_TABLE: dict[str, str] = {
    "servo": "servo",
    "controller.current": "current",
    "controller.velocity": "velocity",
    "controller.position": "position",
    "estimator": "estimator",
    "limits": "limits",
    "safety": "safety",
    "telemetry": "telemetry",
}
