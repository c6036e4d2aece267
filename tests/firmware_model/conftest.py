"""A minimal plant and a PC for the firmware tests (the real plant lives in sim/).

The plant: a DC motor (R, L, Kt = Ke, rotor inertia plus the reflected platter, viscous and
Coulomb friction) behind an ideal averaged H-bridge at 24 V, integrated with 40 sub-steps per
2 ms tick (the current exactly for a frozen speed, the speed by semi-implicit Euler); the
AS5048 reading floor(angle) mod 16384; the BTN7971 IS pin senses the high-side current only.
Good enough to close the loops; not an accuracy reference.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from firmware_model.firmware import Firmware
from serial_protocol import frame
from serial_protocol.messages import Hello

# The UART fuzzers (uart_fuzz.py) are shared with benchmarks/fuzz_firmware.py: importable by
# name from this folder (pytest runs with --import-mode=importlib, which adds no paths).
sys.path.insert(0, str(Path(__file__).resolve().parent))


@dataclass
class MiniPlant:
    n: int = 1
    supply_v: float = 24.0
    r_ohm: float = 1.2
    l_h: float = 0.6e-3
    kt: float = 0.0145
    j_kgm2: float = 1.2625e-5
    b_nms: float = 2e-6
    coulomb_nm: float = 0.004
    a_per_adc: float = 3.3 / 4096 / 1000 * 8500
    theta0_rad: float = 0.0
    substeps: int = 10
    theta_rad: np.ndarray = field(init=False)
    omega_rad_s: np.ndarray = field(init=False)
    i_a: np.ndarray = field(init=False)
    duty: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.theta_rad = np.full(self.n, self.theta0_rad)
        self.omega_rad_s = np.zeros(self.n)
        self.i_a = np.zeros(self.n)
        self.duty = np.zeros(self.n)

    def encoder(self) -> np.ndarray:
        return np.floor(self.theta_rad / (2 * math.pi) * 16384).astype(np.int64) % 16384

    def adc(self) -> np.ndarray:
        high_side = np.where(np.sign(self.i_a) == np.sign(self.duty), np.abs(self.i_a), 0.0)
        return np.minimum(np.round(high_side / self.a_per_adc), 4095).astype(np.int64)

    def step(self, duty, enable, dt_s: float) -> None:
        duty = np.broadcast_to(np.asarray(duty, dtype=float), (self.n,))
        enable = np.broadcast_to(np.asarray(enable, dtype=bool), (self.n,))
        self.duty = np.where(enable, duty, 0.0)
        h = dt_s / self.substeps
        decay = math.exp(-h * self.r_ohm / self.l_h)
        for _ in range(self.substeps):
            i_ss = (self.duty * self.supply_v - self.kt * self.omega_rad_s) / self.r_ohm
            self.i_a = np.where(enable, i_ss + (self.i_a - i_ss) * decay, 0.0)
            torque = self.kt * self.i_a - self.b_nms * self.omega_rad_s
            moving = np.abs(self.omega_rad_s) > 1e-9
            fric = np.where(
                moving,
                self.coulomb_nm * np.sign(self.omega_rad_s),
                np.clip(torque, -self.coulomb_nm, self.coulomb_nm),
            )
            w_new = self.omega_rad_s + h * (torque - fric) / self.j_kgm2
            # Coulomb friction cannot reverse the motion within a sub-step.
            w_new = np.where(moving & (np.sign(w_new) != np.sign(self.omega_rad_s)), 0.0, w_new)
            self.theta_rad = self.theta_rad + h * w_new
            self.omega_rad_s = w_new

    @property
    def axis_deg(self) -> np.ndarray:
        return self.theta_rad * 180 / math.pi / 80.0


class Bench:
    """Firmware + MiniPlant + a PC that sends frames and decodes what the board sends."""

    def __init__(self, fw: Firmware, plant: MiniPlant, tx_free: int = 4096) -> None:
        self.fw = fw
        self.plant = plant
        self.tx_free = tx_free
        self.pc_seq = 0
        self.pc_decoder = frame.Decoder()
        self.received: list = []
        self.log: dict[str, list] = {}
        self.encoder_override = None  # callable(tick, counts) -> counts
        self.adc_override = None  # callable(tick, adc) -> adc
        self.enables: list = []
        self.auto_session = True
        self.session = 0x5E55
        self.opened = False
        self.auto_hellos = 0  # Hellos the bench sent on its own (one HelloReply each)

    def send(self, *msgs) -> bytes:
        """Frame ``msgs``. Like every PC client, the bench opens a session (``Hello``)
        before its first command and stamps its session on the commands that carry 0
        (``auto_session = False`` sends everything as it is)."""
        data = b""
        for msg in msgs:
            if self.auto_session and not isinstance(msg, Hello):
                if getattr(msg, "session", None) == 0:
                    if not self.opened:
                        self.opened = True
                        self.auto_hellos += 1
                        data += frame.encode(Hello(0, session=self.session), self.pc_seq)
                        self.pc_seq = (self.pc_seq + 1) & 0xFF
                    msg = dataclasses.replace(msg, session=self.session)
            elif isinstance(msg, Hello) and self.auto_session:
                self.opened = True
                if msg.session == 0:
                    msg = dataclasses.replace(msg, session=self.session)
            data += frame.encode(msg, self.pc_seq)
            self.pc_seq = (self.pc_seq + 1) & 0xFF
        return data

    def run(self, ticks: int, script: dict | None = None, rx_raw: dict | None = None) -> None:
        fw, plant = self.fw, self.plant
        scalar = fw.batch is None
        for _ in range(ticks):
            k = fw.tick
            rx = b""
            if script and k in script:
                rx += self.send(*script[k])
            if rx_raw and k in rx_raw:
                rx += rx_raw[k]
            enc = plant.encoder()
            if self.encoder_override is not None:
                enc = self.encoder_override(k, enc)
            tx = fw.servo_tick(int(enc[0]) if scalar else enc, rx, self.tx_free)
            self.received.extend(self.pc_decoder.feed(tx))
            m = fw.params.servo.current_loop_multiple
            for _ in range(m):
                adc = plant.adc()
                if self.adc_override is not None:
                    adc = self.adc_override(k, adc)
                duty, en = fw.current_tick(int(adc[0]) if scalar else adc)
                self.enables.append(np.copy(en))
                plant.step(duty, en, fw.dt_s / m)
            for key, value in fw.signals().items():
                self.log.setdefault(key, []).append(np.copy(value))
            self.log.setdefault("true_axis_deg", []).append(plant.axis_deg.copy())
            self.log.setdefault("true_i_a", []).append(plant.i_a.copy())

    def arr(self, key: str) -> np.ndarray:
        return np.asarray(self.log[key])

    def replies(self, cls) -> list:
        return [m for m in self.received if isinstance(m, cls)]


@pytest.fixture
def make_bench():
    def make(params=None, *, batch=None, theta0_rad=0.0, tx_free=4096, **plant_kw):
        from firmware_model.params import FirmwareParams

        params = params or FirmwareParams()
        fw = Firmware(params, batch=batch)
        plant = MiniPlant(n=batch or 1, theta0_rad=theta0_rad, **plant_kw)
        return Bench(fw, plant, tx_free=tx_free)

    return make
