"""Relay auto-tune of the velocity loop on the simulated bench (Astrom-Hagglund), as
Marlin's ``M303`` and Klipper's ``PID_CALIBRATE`` do on a heater.

The firmware's own estimator and current loop run (``firmware_model.servo.Law``, one axis); the
velocity PI is replaced by a relay: ``i_ref = bias + h`` while the estimated speed is below
``vel_dps`` and ``bias - h`` above it. The bias is re-centred every cycle to the mean current
of the last cycle (Klipper's balancing of heating and cooling), which cancels the friction.
The speed then oscillates with amplitude ``a`` and period ``Tu``; the ultimate gain is
``Ku = 4 h / (pi a)`` and the velocity PI follows Ziegler-Nichols (``Kp = 0.45 Ku``,
``Ti = Tu / 1.2``); the position P is put at a sixteenth of the ultimate frequency
(``2 pi / Tu / 16``: the velocity crossover of a Ziegler-Nichols PI sits near a quarter of
it, the position loop a quarter below that); the current loop is kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from firmware_model.servo import Law
from sim.config import BenchConfig
from sim.loop import Simulation
from sim.tuning.gains import GainSet

__all__ = ["RelayResult", "relay_tune"]


class _RelayBoard:
    """A stand-in board for ``sim.loop.Simulation(firmware=...)``: the real estimator and
    current loop, a relay on the velocity error. Single axis, no UART traffic."""

    def __init__(self, bench: BenchConfig, vel_dps: float, amp_a: float) -> None:
        self.law = Law(bench.firmware)
        self._raw = np.zeros(1, dtype=np.int64)
        self._on = np.ones(1, dtype=bool)
        self.vel_dps = vel_dps
        self.amp_a = amp_a
        self.bias_a = 0.0
        self._booted = False
        self._high = True
        self._cycle: list[float] = []
        self.switch_ticks: list[int] = []
        self.tick = 0

    def servo_tick(self, encoder_counts: Any, rx_bytes: bytes, tx_free: int) -> bytes:
        self._raw[0] = encoder_counts
        if not self._booted:
            self.law.reset(self._raw)
            self._booted = True
        self.law.estimate(self._raw)
        high = self.law.vel_dps[0] < self.vel_dps
        if high and not self._high:
            # A full cycle ended: re-centre the relay on its mean current.
            self.switch_ticks.append(self.tick)
            if self._cycle:
                self.bias_a = float(np.mean(self._cycle))
            self._cycle = []
        self._high = high
        i_ref = self.bias_a + (self.amp_a if high else -self.amp_a)
        self.law.current_ref_a = i_ref
        self._cycle.append(i_ref)
        self.tick += 1
        return b""

    def current_tick(self, adc_counts: Any) -> tuple[float, bool]:
        self._raw[0] = adc_counts
        return float(self.law.current(self._raw, self._on)[0]), True

    def signals(self) -> dict[str, Any]:
        law = self.law
        return {
            "sp_pos_deg": 0.0,
            "sp_vel_dps": self.vel_dps,
            "sp_acc_dps2": 0.0,
            "pos_deg": float(law.pos_deg[0]),
            "vel_dps": float(law.vel_dps[0]),
            "vel_raw_dps": float(law.vel_raw_dps[0]),
            "current_meas_a": float(law.current_meas_a[0]),
            "current_ref_a": float(law.current_ref_a[0]),
            "duty": float(law.duty[0]),
            "state": 2,
            "fault": 0,
        }


@dataclass(frozen=True)
class RelayResult:
    """The relay experiment and the gains derived from it."""

    ku_a_per_dps: float
    tu_s: float
    amplitude_dps: float
    cycles: int
    gains: GainSet


def relay_tune(
    bench: BenchConfig,
    start: GainSet,
    *,
    vel_dps: float = 200.0,
    amp_a: float = 1.0,
    duration_s: float = 1.5,
    seed: int = 0,
) -> RelayResult:
    """Run the relay experiment on the bench (the plant of ``bench``) and derive gains."""
    board = _RelayBoard(bench, vel_dps, amp_a)
    sim = Simulation(bench, seed=seed, firmware=board, overrides={"loop.event_levels": 8})
    sim.step(int(round(duration_s / sim.dt_s)))
    log = sim.log()
    ticks = board.switch_ticks
    if len(ticks) < 4:
        raise ValueError(f"relay: only {len(ticks)} cycles in {duration_s} s; no oscillation")
    # Skip the run-up: measure over the last half of the cycles.
    first = ticks[len(ticks) // 2]
    last = ticks[-1]
    cycles = len(ticks) - 1 - len(ticks) // 2
    tu_s = (last - first) / cycles * sim.dt_s
    v = log.vel_dps[first:last]
    amplitude = 0.5 * float(np.max(v) - np.min(v))
    ku = 4.0 * amp_a / (math.pi * amplitude)
    kp_v = 0.45 * ku
    ki_v = kp_v / (tu_s / 1.2)
    kp_p = 2.0 * math.pi / tu_s / 16.0
    gains = start.replace(kp_v_a_per_dps=kp_v, ki_v_a_per_deg=ki_v, kp_p_per_s=kp_p)
    return RelayResult(ku, tu_s, amplitude, cycles, gains)
