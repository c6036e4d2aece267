"""The five feedback gains the tuner adjusts, as one frozen dataclass.

The feed-forward terms (``resistance_ohm``, ``back_emf_v_per_dps``, ``acc_ff_a_per_dps2``,
``vel_ff``) come from the nominal model and are left as the config has them.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from sim.config import BenchConfig

__all__ = ["GAIN_FIELDS", "GainSet", "LOOP_FIELDS", "batch_overrides"]

#: GainSet field -> dotted ``table.key`` of the bench (``sim.loop.apply_overrides``).
GAIN_FIELDS: dict[str, str] = {
    "kp_i_v_per_a": "controller.current.kp_v_per_a",
    "ki_i_v_per_as": "controller.current.ki_v_per_as",
    "kp_v_a_per_dps": "controller.velocity.kp_a_per_dps",
    "ki_v_a_per_deg": "controller.velocity.ki_a_per_deg",
    "kp_p_per_s": "controller.position.kp_per_s",
}

#: Loop name -> the GainSet fields it owns (inner to outer).
LOOP_FIELDS: dict[str, tuple[str, ...]] = {
    "current": ("kp_i_v_per_a", "ki_i_v_per_as"),
    "velocity": ("kp_v_a_per_dps", "ki_v_a_per_deg"),
    "position": ("kp_p_per_s",),
}


@dataclass(frozen=True)
class GainSet:
    """Feedback gains of the three loops (units of ``firmware_model.params``).

    Attributes:
        kp_i_v_per_a: current PI proportional gain (V per A).
        ki_i_v_per_as: current PI integral gain (V per A*s).
        kp_v_a_per_dps: velocity PI proportional gain (A per axis deg/s).
        ki_v_a_per_deg: velocity PI integral gain (A per axis deg).
        kp_p_per_s: position P gain (axis deg/s per deg).
    """

    kp_i_v_per_a: float
    ki_i_v_per_as: float
    kp_v_a_per_dps: float
    ki_v_a_per_deg: float
    kp_p_per_s: float

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"{f.name} = {value!r}: must be a number")
            if not math.isfinite(value) or value < 0.0:
                raise ValueError(f"{f.name} = {value!r}: must be finite and >= 0")
            object.__setattr__(self, f.name, float(value))

    @classmethod
    def from_bench(cls, bench: BenchConfig) -> GainSet:
        """The gains a bench config holds (scalar gains only)."""
        fw = bench.firmware
        values = {
            "kp_i_v_per_a": fw.current.kp_v_per_a,
            "ki_i_v_per_as": fw.current.ki_v_per_as,
            "kp_v_a_per_dps": fw.velocity.kp_a_per_dps,
            "ki_v_a_per_deg": fw.velocity.ki_a_per_deg,
            "kp_p_per_s": fw.position.kp_per_s,
        }
        for name, value in values.items():
            if not isinstance(value, float | int):
                raise ValueError(f"{name} = {value!r}: the tuner needs scalar gains in the config")
        return cls(**values)

    def replace(self, **changes: float) -> GainSet:
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict[str, float]:
        return dataclasses.asdict(self)

    def overrides(self) -> dict[str, float]:
        """``{"table.key": value}`` for ``sim.loop.Simulation(overrides=...)``."""
        return {GAIN_FIELDS[name]: value for name, value in self.as_dict().items()}

    def firmware_names(self) -> dict[str, float]:
        """The run-time names of ``firmware_model.servo.GAIN_NAMES`` (``kp_i, ki_i, ...``),
        as ``firmware_model.stability.unstable_reason`` takes them."""
        return {
            "kp_i": self.kp_i_v_per_a,
            "ki_i": self.ki_i_v_per_as,
            "kp_v": self.kp_v_a_per_dps,
            "ki_v": self.ki_v_a_per_deg,
            "kp_p": self.kp_p_per_s,
        }


def batch_overrides(sets: list[GainSet]) -> dict[str, Any]:
    """Overrides giving member k of a batch the gains ``sets[k]`` (``(N,)`` lists)."""
    return {dotted: [getattr(g, name) for g in sets] for name, dotted in GAIN_FIELDS.items()}
