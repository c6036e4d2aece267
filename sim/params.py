"""Plant parameters: one frozen dataclass per part of the bench, one TOML table each.

Every dataclass checks its own fields in ``__post_init__`` and raises
``ValueError("key = value: reason")``; ``sim.config`` turns that into a ``ConfigError`` that
names the file and the table. Where each default comes from (seed 000, a datasheet, or
"assumed" with a reason) is listed in ``docs/model.md`` and in ``bench_configs/paper_bench.toml``.

A float field may also hold a numpy array of shape ``(N,)`` (one value per batch member), as
``sim.loop.Simulation(overrides=...)`` builds for parameter studies; the checks hold for every
element. ``PlantParams.member(k)`` picks member ``k`` back out as plain floats.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

__all__ = [
    "BeltParams",
    "BridgeParams",
    "CurrentSenseParams",
    "EncoderParams",
    "GearboxParams",
    "LoopParams",
    "MotorParams",
    "PlantParams",
    "PlatterParams",
    "SupplyParams",
    "TABLES",
    "ThermalParams",
    "UartParams",
    "largest_board_frame",
    "per_member",
]


def per_member(value: Any, n: int) -> np.ndarray:
    """A parameter (float, or ``(n,)`` array: one per batch member) as a contiguous ``(n,)``
    float array, the form the compiled batch loops take."""
    return np.ascontiguousarray(np.broadcast_to(np.asarray(value, dtype=float), (n,)))


def replace_unchecked(obj: Any, changes: dict[str, Any]) -> Any:
    """A copy of the frozen dataclass ``obj`` with ``changes``, without ``__init__`` and
    ``__post_init__``'s checks (``PlantParams.member``, ``sim.plant.Coefficients.members``:
    the values come from a batch's arrays, already checked or computed)."""
    new = object.__new__(type(obj))  # what copy.copy does for a dataclass without slots
    new.__dict__.update(vars(obj))
    new.__dict__.update(changes)
    return new


def _check(obj: Any, name: str, ok: bool, reason: str) -> None:
    if not ok:
        raise ValueError(f"{name} = {getattr(obj, name)!r}: {reason}")


def _finite(v: Any) -> bool:
    return bool(np.all(np.isfinite(np.asarray(v, dtype=float))))


def _positive(obj: Any, *names: str) -> None:
    for name in names:
        v = getattr(obj, name)
        _check(obj, name, _finite(v) and bool(np.all(np.asarray(v) > 0)), "must be finite and > 0")


def _non_negative(obj: Any, *names: str) -> None:
    for name in names:
        v = getattr(obj, name)
        _check(
            obj, name, _finite(v) and bool(np.all(np.asarray(v) >= 0)), "must be finite and >= 0"
        )


@dataclass(frozen=True)
class SupplyParams:
    """The 24 V switching supply (seed 000: 220 V -> 24 V) and the bridge's bus.

    ``bus_model = false`` (the default) takes the supply as stiff: the bridge always sees
    ``voltage_v``. ``true`` models the bus (``sim.supply``): a supply that cannot sink
    current (its output diode), with its source resistance, feeding the bulk capacitor;
    braking returns energy into the capacitor and lifts the bus, up to the BTN7971B's
    over-voltage lock-out (``[bridge] ov_lockout_v``) unless a brake chopper takes it.
    ``sense_divider_ratio``: the board's divider from the bus to an STM32 ADC channel (the
    ADC of ``[current_sense]``), which the firmware reads every current-loop period.
    ``tvs_breakdown_v`` (0: none) / ``tvs_resistance_ohm``: a TVS diode across the rail,
    conducting ``(v - V_br) / R_d`` above its breakdown (instead of a chopper).
    ``bus_quiet_v``: a current-loop period whose rail swings by at most this much (and
    meets no switch: ``sim.supply``, "The adaptive step") is one exact plant step instead
    of ``bus_substeps``; 0 = always the sub-steps.
    """

    voltage_v: float = 24.0
    bus_model: bool = False
    source_resistance_ohm: float = 0.05
    bulk_capacitance_uf: float = 2200.0
    logic_load_a: float = 0.04
    brake_resistor_ohm: float = 0.0
    brake_on_v: float = 26.5
    bus_substeps: int = 16
    bus_quiet_v: float = 0.001
    tvs_breakdown_v: float = 0.0
    tvs_resistance_ohm: float = 0.7
    sense_divider_ratio: float = 11.0

    def __post_init__(self) -> None:
        _positive(self, "voltage_v", "source_resistance_ohm", "bulk_capacitance_uf")
        _check(
            self,
            "sense_divider_ratio",
            _finite(self.sense_divider_ratio)
            and bool(np.all(np.asarray(self.sense_divider_ratio) >= 1)),
            "must be finite and >= 1 (a divider)",
        )
        _non_negative(self, "logic_load_a", "brake_resistor_ohm", "bus_quiet_v", "tvs_breakdown_v")
        _positive(self, "tvs_resistance_ohm")
        tvs = np.asarray(self.tvs_breakdown_v)
        _check(
            self,
            "tvs_breakdown_v",
            bool(
                np.all(
                    (tvs == 0)
                    | (
                        (tvs > np.asarray(self.voltage_v))
                        & (np.asarray(self.brake_resistor_ohm) == 0)
                    )
                )
            ),
            "must be 0 (none) or above the supply voltage, and no brake chopper with it "
            "(the model takes one clamp: brake_resistor_ohm = 0)",
        )
        # The BTN7971B locks out above 27.8 V (datasheet V_OV(OFF) min).
        _check(
            self,
            "voltage_v",
            bool(np.all(np.asarray(self.voltage_v) < 27.8)),
            "above the BTN7971B over-voltage lock-out (27.8 V)",
        )
        _check(self, "bus_model", isinstance(self.bus_model, bool), "must be true or false")
        _check(
            self,
            "bus_substeps",
            isinstance(self.bus_substeps, int)
            and not isinstance(self.bus_substeps, bool)
            and self.bus_substeps in (1, 2, 4, 8, 16, 32, 64),
            "must be a power of two in [1, 64]",
        )
        _check(
            self,
            "brake_on_v",
            _finite(self.brake_on_v)
            and bool(
                np.all(
                    (np.asarray(self.brake_on_v) > np.asarray(self.voltage_v))
                    | (np.asarray(self.brake_resistor_ohm) == 0)
                )
            ),
            "must be above the supply voltage (the chopper would burn the supply's power)",
        )

    @property
    def capacitance_f(self) -> Any:
        """The bulk capacitance in farads."""
        return self.bulk_capacitance_uf * 1e-6


@dataclass(frozen=True)
class BridgeParams:
    """Two BTN7971B half-bridges forming an H-bridge, PWM from STM32F103 TIM1.

    The averaged bridge applies ``duty * voltage`` (duty quantised to ``1/arr`` steps,
    ``arr = timer_clock_hz / pwm_hz`` for edge-aligned PWM). ``current_limit_a`` is the
    chip's own switched-mode current limitation (datasheet I_CL, not the firmware's 5 A).
    ``ov_lockout_v`` / ``ov_release_v`` and ``uv_lockout_v`` / ``uv_release_v``: the chip's
    over- and under-voltage lock-out with its hysteresis (outputs off above/below the first,
    back on past the second); only the bus model (``[supply] bus_model``) can reach them.
    ``pulse_shift_with_current_us`` / ``pulse_shift_against_current_us``: how much longer
    (negative: shorter) the output pulse is than the PWM input pulse, with the current
    flowing in the duty's direction (the high side's switching delays set the edges) or
    against it (the low side's); a pulse shortened to nothing is not switched at all
    (``sim.bridge.switching``). 0 and 0: the ideal bridge.
    """

    r_on_path_ohm: float = 0.016
    timer_clock_hz: float = 72e6
    pwm_hz: float = 20e3
    current_limit_a: float = 70.0
    diode_drop_v: float = 0.8
    ov_lockout_v: float = 28.0
    ov_release_v: float = 27.8
    uv_lockout_v: float = 4.5
    uv_release_v: float = 5.5
    pulse_shift_with_current_us: float = 0.0
    pulse_shift_against_current_us: float = 0.0

    def __post_init__(self) -> None:
        _non_negative(self, "r_on_path_ohm", "diode_drop_v")
        # pwm_hz first: the pulse shifts are checked against its period
        _positive(self, "timer_clock_hz", "pwm_hz", "current_limit_a")
        for name in ("pulse_shift_with_current_us", "pulse_shift_against_current_us"):
            v = getattr(self, name)
            with np.errstate(over="ignore"):  # a huge finite shift times pwm_hz is inf: refused
                shorter = bool(np.all(np.abs(np.asarray(v, dtype=float)) * self.pwm_hz < 1e6))
            _check(
                self, name, _finite(v) and shorter, "must be finite and shorter than the PWM period"
            )
        _positive(self, "ov_lockout_v", "ov_release_v", "uv_lockout_v", "uv_release_v")
        _check(
            self,
            "ov_release_v",
            bool(np.all(np.asarray(self.ov_release_v) <= self.ov_lockout_v)),
            "must not be above ov_lockout_v (the lock-out's hysteresis)",
        )
        _check(
            self,
            "uv_release_v",
            bool(np.all(np.asarray(self.uv_release_v) >= self.uv_lockout_v))
            and bool(np.all(np.asarray(self.uv_release_v) < self.ov_release_v)),
            "must lie between uv_lockout_v and ov_release_v",
        )
        _check(
            self,
            "pwm_hz",
            bool(np.all(np.asarray(self.timer_clock_hz) / self.pwm_hz >= 2)),
            "leaves fewer than 2 timer steps per PWM period",
        )
        _check(
            self,
            "pwm_hz",
            bool(np.all(np.asarray(self.timer_clock_hz) / self.pwm_hz <= 65536)),
            "needs more than 65536 timer steps per PWM period (TIM1 is a 16-bit timer)",
        )

    @property
    def arr(self) -> Any:
        """Timer steps per PWM period (3600 at 72 MHz / 20 kHz)."""
        arr = np.round(np.asarray(self.timer_clock_hz, dtype=float) / self.pwm_hz)
        return float(arr) if arr.ndim == 0 else arr


@dataclass(frozen=True)
class CurrentSenseParams:
    """BTN7971B IS pin -> sense resistor -> STM32 12-bit ADC (high-side current only).

    Within the PWM period (``sim.bridge.read_adc``): ``sample_point`` is where in the high
    side's on-time the ADC samples (0.5, the middle, reads the period's mean current; 0 the
    ripple's valley, 1 its peak); ``is_offset_ua`` the IS pin's current with the high side
    on and no load (BTS7960B datasheet 4.4.9, I_ISH: up to 200 uA); ``is_settling_us`` the
    pin's settling after the high side turns on (a sample earlier reads nothing);
    ``is_filter_us`` the time constant of an RC low-pass on the pin (``R_IS C``, 0 = none):
    the pin's voltage follows the IS current, on during the on-time, with it
    (``sim.bridge.rc_factor``). The defaults (0.5, 0, 0, 0) are the averaged sense of the
    model so far, bit for bit.

    The board has two IS pins, one per half-bridge (two chips): ``is_offset_ua`` is their
    offsets' mean and ``is_offset_mismatch_ua`` the difference, the pin of the half-bridge
    that drives positive current minus the other's (pin + at ``is_offset_ua + mismatch / 2``,
    pin - at ``is_offset_ua - mismatch / 2``; neither below 0). 0: both pins alike.
    """

    k_ilis: float = 8500.0
    r_is_ohm: float = 1000.0
    adc_vref_v: float = 3.3
    adc_bits: int = 12
    noise_rms_lsb: float = 0.0
    sample_point: float = 0.5
    is_offset_ua: float = 0.0
    is_settling_us: float = 0.0
    is_filter_us: float = 0.0
    is_offset_mismatch_ua: float = 0.0

    def __post_init__(self) -> None:
        _positive(self, "k_ilis", "r_is_ohm", "adc_vref_v")
        _non_negative(self, "noise_rms_lsb", "is_offset_ua", "is_settling_us", "is_filter_us")
        _check(
            self,
            "is_offset_mismatch_ua",
            _finite(self.is_offset_mismatch_ua)
            and bool(
                np.all(np.abs(self.is_offset_mismatch_ua) <= 2.0 * np.asarray(self.is_offset_ua))
            ),
            "must be within +-2 x is_offset_ua (neither pin's offset below 0)",
        )
        _check(
            self,
            "sample_point",
            _finite(self.sample_point)
            and bool(
                np.all((np.asarray(self.sample_point) >= 0) & (np.asarray(self.sample_point) <= 1))
            ),
            "must be in [0, 1] (a fraction of the high side's on-time)",
        )
        _check(
            self,
            "adc_bits",
            isinstance(self.adc_bits, int) and 6 <= self.adc_bits <= 16,
            "must be an integer in [6, 16]",
        )

    @property
    def a_per_lsb(self) -> Any:
        """Load current per ADC count (A)."""
        return self.adc_vref_v / (1 << self.adc_bits) * self.k_ilis / self.r_is_ohm


def _check_stiction(obj: Any) -> None:
    """Stiction 0 (off) or at least Coulomb, with a Stribeck speed above the band."""
    _non_negative(obj, "stiction_nm", "stribeck_rad_s")
    ts, tc = np.asarray(obj.stiction_nm), np.asarray(obj.coulomb_nm)
    on = ts > 0
    _check(obj, "stiction_nm", bool(np.all(~on | (ts >= tc))), "must be 0 (off) or >= coulomb_nm")
    ws, wb = np.asarray(obj.stribeck_rad_s), np.asarray(obj.coulomb_band_rad_s)
    _check(
        obj, "stribeck_rad_s", bool(np.all(~on | (ws > wb))),
        "must be > coulomb_band_rad_s when stiction_nm > 0",
    )  # fmt: skip


def _breakaway(obj: Any) -> Any:
    ts = obj.stiction_nm
    if isinstance(ts, np.ndarray) or isinstance(obj.coulomb_nm, np.ndarray):
        return np.where(np.asarray(ts) > 0, ts, obj.coulomb_nm)
    return ts if ts > 0 else obj.coulomb_nm


def _stribeck_edge(obj: Any) -> Any:
    ts = obj.stiction_nm
    if isinstance(ts, np.ndarray) or isinstance(obj.stribeck_rad_s, np.ndarray):
        return np.where(np.asarray(ts) > 0, obj.stribeck_rad_s, obj.coulomb_band_rad_s)
    return obj.stribeck_rad_s if ts > 0 else obj.coulomb_band_rad_s


@dataclass(frozen=True)
class MotorParams:
    """Brushed DC motor (a 24 V 775-class motor, assumed; see docs/model.md)."""

    r_ohm: float = 1.2
    l_h: float = 0.6e-3
    kt_nm_a: float = 0.0145
    ke_v_s_rad: float = 0.0145
    j_kgm2: float = 1.2e-5
    viscous_nm_s_rad: float = 2e-6
    coulomb_nm: float = 0.004
    coulomb_band_rad_s: float = 0.1
    # Stiction: breakaway torque above Coulomb, falling to Coulomb at the Stribeck speed
    # (docs/model.md, "Friction"). 0 (the default) turns it off.
    stiction_nm: float = 0.0
    stribeck_rad_s: float = 0.0

    def __post_init__(self) -> None:
        _positive(self, "r_ohm", "l_h", "kt_nm_a", "ke_v_s_rad", "j_kgm2", "coulomb_band_rad_s")
        _non_negative(self, "viscous_nm_s_rad", "coulomb_nm")
        _check_stiction(self)

    @property
    def breakaway_nm(self) -> Any:
        """Friction torque at the edge of the band (N*m): the stiction, or Coulomb if off."""
        return _breakaway(self)

    @property
    def stribeck_edge_rad_s(self) -> Any:
        """Speed where the friction is back to Coulomb (rad/s); the band's edge if off."""
        return _stribeck_edge(self)


@dataclass(frozen=True)
class GearboxParams:
    """Planetary gearbox between motor and axis (the axis is its output shaft)."""

    ratio: float = 80.0
    efficiency: float = 0.8
    backlash_deg: float = 0.5
    # No-load drag of the gearbox (seals, grease churning, the planet stages turning with
    # no load), referred to the motor shaft: Coulomb (with the motor's friction band) and
    # viscous. Zero (the defaults) turns it off. With ``efficiency`` (a loss proportional to
    # the transmitted torque) it makes the efficiency load-dependent: low at light load.
    drag_nm: float = 0.0
    drag_viscous_nm_s_rad: float = 0.0

    def __post_init__(self) -> None:
        _positive(self, "ratio")
        _non_negative(self, "backlash_deg", "drag_nm", "drag_viscous_nm_s_rad")
        e = np.asarray(self.efficiency)
        _check(
            self, "efficiency", _finite(e) and bool(np.all((e > 0) & (e <= 1))), "must be in (0, 1]"
        )


@dataclass(frozen=True)
class BeltParams:
    """17 -> 85 tooth timing belt; stiffness and damping referred to the platter."""

    small_teeth: int = 17
    large_teeth: int = 85
    stiffness_nm_rad: float = 2500.0
    damping_nm_s_rad: float = 2.0

    def __post_init__(self) -> None:
        for name in ("small_teeth", "large_teeth"):
            v = getattr(self, name)
            _check(self, name, isinstance(v, int) and v >= 8, "must be an integer >= 8")
        _positive(self, "stiffness_nm_rad")
        _non_negative(self, "damping_nm_s_rad")

    @property
    def ratio(self) -> float:
        """Axis turns per platter turn (5.0)."""
        return self.large_teeth / self.small_teeth


@dataclass(frozen=True)
class PlatterParams:
    """Platter with the 85T pulley on its slewing bearing (values at the platter)."""

    j_kgm2: float = 0.08
    coulomb_nm: float = 0.3
    viscous_nm_s_rad: float = 0.05
    coulomb_band_rad_s: float = 1e-3
    # The slewing bearing's stiction, as the motor's (0 turns it off).
    stiction_nm: float = 0.0
    stribeck_rad_s: float = 0.0

    def __post_init__(self) -> None:
        _positive(self, "j_kgm2", "coulomb_band_rad_s")
        _non_negative(self, "coulomb_nm", "viscous_nm_s_rad")
        _check_stiction(self)

    @property
    def breakaway_nm(self) -> Any:
        """Friction torque at the edge of the band (N*m): the stiction, or Coulomb if off."""
        return _breakaway(self)

    @property
    def stribeck_edge_rad_s(self) -> Any:
        """Speed where the friction is back to Coulomb (rad/s); the band's edge if off."""
        return _stribeck_edge(self)


@dataclass(frozen=True)
class EncoderParams:
    """AS5048 14-bit magnetic encoder on the motor tail."""

    bits: int = 14
    latency_s: float = 100e-6
    noise_rms_lsb: float = 0.0
    offset_counts: float = 0.0
    # Integral non-linearity as harmonics of the motor angle (motor degrees, phase degrees):
    # once per turn (magnet eccentricity) and twice per turn (field ellipticity). Zero
    # amplitudes (the defaults) turn it off.
    inl_h1_deg: float = 0.0
    inl_h1_phase_deg: float = 0.0
    inl_h2_deg: float = 0.0
    inl_h2_phase_deg: float = 0.0

    def __post_init__(self) -> None:
        _check(
            self,
            "bits",
            isinstance(self.bits, int) and 8 <= self.bits <= 20,
            "must be an integer in [8, 20]",
        )
        _non_negative(self, "latency_s", "noise_rms_lsb", "offset_counts")
        _non_negative(self, "inl_h1_deg", "inl_h2_deg")
        for name in ("inl_h1_deg", "inl_h2_deg"):
            _check(
                self, name, bool(np.all(np.asarray(getattr(self, name)) <= 5.0)),
                "must be <= 5 deg (the AS5048's error is well under a degree)",
            )  # fmt: skip
        for name in ("inl_h1_phase_deg", "inl_h2_phase_deg"):
            _check(self, name, _finite(getattr(self, name)), "must be finite")
        _check(
            self, "latency_s", bool(np.all(np.asarray(self.latency_s) < 0.01)), "must be < 0.01 s"
        )
        _check(
            self,
            "offset_counts",
            bool(np.all(np.asarray(self.offset_counts) < self.counts_per_rev)),
            f"must be below one revolution ({self.counts_per_rev} counts)",
        )

    @property
    def counts_per_rev(self) -> int:
        return 1 << self.bits


def largest_board_frame() -> tuple[int, str]:
    """Bytes and name of the longest frame the board sends (from the codec)."""
    from serial_protocol import frame, messages

    sizes = [
        (frame.frame_bytes(cls), cls.__name__)
        for cls in vars(messages).values()
        if isinstance(cls, type) and getattr(cls, "MSG_TYPE", 0) >= 0x80
    ]
    return max(sizes)


@dataclass(frozen=True)
class UartParams:
    """The board's UART: FIFO size and seeded line faults, per byte, in both directions
    (``serial_protocol.uart.FaultInjection``). The baud rate is the firmware's
    ``[telemetry] baud``."""

    fifo_bytes: int = 256
    bit_flip_rate: float = 0.0
    drop_rate: float = 0.0
    insert_rate: float = 0.0
    burst_rate: float = 0.0
    burst_bytes: int = 4

    def __post_init__(self) -> None:
        largest, name = largest_board_frame()
        _check(
            self,
            "fifo_bytes",
            isinstance(self.fifo_bytes, int) and largest <= self.fifo_bytes <= 1 << 24,
            f"must be an integer in [{largest}, {1 << 24}]: the TX FIFO must hold the largest "
            f"frame the board sends ({largest} bytes, {name})",
        )
        rates = ("bit_flip_rate", "drop_rate", "insert_rate", "burst_rate")
        for name in rates:
            v = getattr(self, name)
            _check(self, name, _finite(v) and 0.0 <= v <= 1.0, "must be a probability in [0, 1]")
        _check(
            self,
            "burst_rate",
            sum(getattr(self, n) for n in rates) <= 1.0,
            "the four rates must add up to at most 1",
        )
        _check(
            self,
            "burst_bytes",
            isinstance(self.burst_bytes, int) and 1 <= self.burst_bytes <= 1 << 20,
            "must be an integer in [1, 1048576]",
        )


@dataclass(frozen=True)
class LoopParams:
    """How the simulation loop steps the plant.

    ``event_levels``: how many times a step in which the plant's piecewise-linear mode changes
    (friction band, backlash contact, power-flow direction, current limitation) is halved to
    locate the switch; 20 halvings of 2 ms locate it within 2 ns.
    """

    event_levels: int = 20

    def __post_init__(self) -> None:
        _check(
            self,
            "event_levels",
            isinstance(self.event_levels, int) and 0 <= self.event_levels <= 40,
            "must be an integer in [0, 40]",
        )


# The temperature range of the heat model (degC): the plant's step matrices exist for
# winding temperatures in it (sim.thermal clips to it), the parameters are checked against it.
T_MIN_C, T_MAX_C = -60.0, 250.0


@dataclass(frozen=True)
class ThermalParams:
    """The motor's heat: a two-node lumped network (winding -> housing -> ambient), the
    winding's resistance R(T) and the magnets' torque constant Kt(T) (``sim.thermal``).

    ``model = false`` (the default) keeps the motor at ``reference_c``: ``[motor] r_ohm``,
    ``kt_nm_a`` and ``ke_v_s_rad`` as given (the model before, bit for bit). ``true``:
    the winding is heated by ``i^2 R(T)``, the housing by ``friction_heat_fraction`` of the
    motor's own friction loss; ``R(T) = R_ref (1 + alpha_cu (T - T_ref))`` for the motor
    (the bridge's R_ON stays at its 25 degC value), ``Kt(T) = Kt_ref (1 + magnet_tc (T -
    T_ref))`` and the same for K_e. The capacities follow from the time constants as in
    a motor catalogue: ``C_w = tau_w / R_wh``, ``C_h = tau_h / R_ha``.
    ``matrix_step_k``: the plant's exact step matrices are built for the winding
    temperature rounded to this step (docs/model.md, "Heat"). The run starts with the
    winding and the housing ``initial_winding_rise_k`` / ``initial_housing_rise_k`` above
    ``ambient_c`` (0, 0: a motor at ambient).
    """

    model: bool = False
    ambient_c: float = 25.0
    initial_winding_rise_k: float = 0.0
    initial_housing_rise_k: float = 0.0
    reference_c: float = 20.0
    alpha_cu_per_k: float = 0.00393
    magnet_tc_per_k: float = -0.002
    r_winding_housing_k_w: float = 2.5
    r_housing_ambient_k_w: float = 6.0
    tau_winding_s: float = 30.0
    tau_housing_s: float = 900.0
    friction_heat_fraction: float = 1.0
    matrix_step_k: float = 0.1

    def __post_init__(self) -> None:
        _check(self, "model", isinstance(self.model, bool), "must be true or false")
        for name in (
            "ambient_c", "reference_c", "alpha_cu_per_k", "magnet_tc_per_k",
            "initial_winding_rise_k", "initial_housing_rise_k",
        ):  # fmt: skip
            _check(self, name, _finite(getattr(self, name)), "must be finite")
        _positive(
            self, "r_winding_housing_k_w", "r_housing_ambient_k_w", "tau_winding_s",
            "tau_housing_s", "matrix_step_k",
        )  # fmt: skip
        f = np.asarray(self.friction_heat_fraction)
        _check(
            self, "friction_heat_fraction", _finite(f) and bool(np.all((f >= 0) & (f <= 1))),
            "must be in [0, 1]",
        )  # fmt: skip
        # The temperatures the model covers (its tables of step matrices, R(T) > 0).
        for name, v in (
            ("ambient_c", self.ambient_c),
            ("initial_winding_rise_k", self.ambient_c + self.initial_winding_rise_k),
            ("initial_housing_rise_k", self.ambient_c + self.initial_housing_rise_k),
        ):
            _check(
                self, name, bool(np.all((np.asarray(v) >= T_MIN_C) & (np.asarray(v) <= T_MAX_C))),
                f"the temperature must be in [{T_MIN_C:g}, {T_MAX_C:g}] degC (the model's range)",
            )  # fmt: skip
        for name in ("alpha_cu_per_k", "magnet_tc_per_k"):
            k = np.asarray(getattr(self, name))
            ref = self.reference_c
            worst = np.minimum(1 + k * (T_MIN_C - ref), 1 + k * (T_MAX_C - ref))
            _check(
                self, name, bool(np.all(worst > 0)),
                f"makes the motor's constant <= 0 within [{T_MIN_C:g}, {T_MAX_C:g}] degC",
            )  # fmt: skip
        _check(
            self, "matrix_step_k", bool(np.all(np.asarray(self.matrix_step_k) <= 10.0)),
            "must be at most 10 K",
        )  # fmt: skip


@dataclass(frozen=True)
class PlantParams:
    """Everything the physical model needs, one field per TOML table."""

    supply: SupplyParams = field(default_factory=SupplyParams)
    bridge: BridgeParams = field(default_factory=BridgeParams)
    current_sense: CurrentSenseParams = field(default_factory=CurrentSenseParams)
    motor: MotorParams = field(default_factory=MotorParams)
    gearbox: GearboxParams = field(default_factory=GearboxParams)
    belt: BeltParams = field(default_factory=BeltParams)
    platter: PlatterParams = field(default_factory=PlatterParams)
    encoder: EncoderParams = field(default_factory=EncoderParams)
    thermal: ThermalParams = field(default_factory=ThermalParams)

    @property
    def motor_coulomb_nm(self) -> Any:
        """Coulomb friction at the motor shaft (N*m): the motor's brushes and bearings plus
        the gearbox's no-load drag."""
        return self.motor.coulomb_nm + self.gearbox.drag_nm

    @property
    def motor_breakaway_nm(self) -> Any:
        """Breakaway friction at the motor shaft (N*m): the motor's plus the gearbox drag."""
        return self.motor.breakaway_nm + self.gearbox.drag_nm

    @property
    def motor_viscous_nm_s_rad(self) -> Any:
        """Viscous friction at the motor shaft (N*m*s/rad): motor plus gearbox drag."""
        return self.motor.viscous_nm_s_rad + self.gearbox.drag_viscous_nm_s_rad

    @property
    def total_ratio(self) -> float:
        """Motor turns per platter turn (400)."""
        return self.gearbox.ratio * self.belt.ratio

    def batch_size(self) -> int | None:
        """N if any field holds an ``(N,)`` array, else None."""
        n = None
        for part in (getattr(self, f.name) for f in fields(self)):
            for f in fields(part):
                v = getattr(part, f.name)
                if isinstance(v, np.ndarray) and v.ndim == 1:
                    if n is not None and v.shape[0] != n:
                        raise ValueError(f"{f.name} = array of {v.shape[0]}: batch is {n}")
                    n = v.shape[0]
        return n

    def member(self, k: int) -> PlantParams:
        """The parameters of batch member ``k`` with every array replaced by a float.

        Not validated again: each check of a table holds for every member of its arrays
        (they compare element by element), so a member of valid parameters is valid
        (through ``dataclasses.replace`` and the checks a member cost 0.2 ms: N = 256 of
        them were ~40 % of a 2 s Monte-Carlo run when ``Plant`` built its sets this way)."""
        parts = {}
        for f in fields(self):
            part = getattr(self, f.name)
            changes = {
                g.name: float(getattr(part, g.name)[k])
                for g in fields(part)
                if isinstance(getattr(part, g.name), np.ndarray)
            }
            if changes:
                parts[f.name] = replace_unchecked(part, changes)
        return replace_unchecked(self, parts)


# TOML table path -> dataclass. ``sim.config`` is generic over this and firmware_model's TABLES.
TABLES: dict[str, type] = {
    "supply": SupplyParams,
    "bridge": BridgeParams,
    "current_sense": CurrentSenseParams,
    "motor": MotorParams,
    "gearbox": GearboxParams,
    "belt": BeltParams,
    "platter": PlatterParams,
    "encoder": EncoderParams,
    "thermal": ThermalParams,
    "uart": UartParams,
    "loop": LoopParams,
}
