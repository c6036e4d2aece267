"""The cost of a closed-loop run: terms measured on the simulator's log, a weighted sum.

Terms (per batch member; axis units; the true axis angle ``true_pos_deg`` is what is judged):

``itae_deg_s2``
    time-weighted absolute tracking error ``sum (t - t_cmd) |sp_pos - pos| dt`` where
    ``t_cmd`` is the time of the latest command: the weight restarts at every replan, so a
    persistent error costs more the longer it lasts, whatever the move.
``overshoot_deg``
    after each arrival (the planner's setpoint reaching its target and staying there until
    the next command or the end), the largest excursion past the target.
``settling_s``
    after each arrival, the time until the position stays within ``settle_band_deg`` of
    the target (the rest of the window if it never does); the largest over arrivals.
``current_limit_s``
    time the velocity loop asks for the full current limit (its output clamped).
``chatter_duty``
    mean ``|duty[k] - duty[k-1]|`` per tick: the duty noise the encoder's quantisation
    (and noise) drives through the observer and the gains.
``current_error_a``
    mean ``|i_ref(k - d - 1) - i(k)|``: how well the current follows its reference (the
    reference of ``d + 1`` ticks ago, the one that produced the sample).
``fault``
    1 if the firmware latched any fault (over-current, following error, ...), else 0.

``cost = sum(weight * term)``; the weights (``CostWeights``) are settable from the command
line (``--weight name=value``) and documented in docs/tuning.md. The defaults make each term
count about 1 for the config's default gains on the quick Fig. 8 scenario.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from sim.config import Experiment
from sim.loop import RunLog

__all__ = ["TERMS", "CostWeights", "combine", "cost_terms"]

TERMS = (
    "itae_deg_s2",
    "overshoot_deg",
    "settling_s",
    "current_limit_s",
    "chatter_duty",
    "current_error_a",
    "fault",
)


@dataclass(frozen=True)
class CostWeights:
    """Weight of each cost term (cost units per term unit) and the settling band."""

    itae_deg_s2: float = 2.0
    overshoot_deg: float = 20.0
    settling_s: float = 2.0
    current_limit_s: float = 10.0
    chatter_duty: float = 100.0
    current_error_a: float = 10.0
    fault: float = 1000.0
    settle_band_deg: float = 0.01

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not v >= 0.0:
                raise ValueError(f"{f.name} = {v!r}: must be a number >= 0")
            object.__setattr__(self, f.name, float(v))
        if self.settle_band_deg <= 0.0:
            raise ValueError(f"settle_band_deg = {self.settle_band_deg!r}: must be > 0")

    def with_updates(self, pairs: list[str]) -> CostWeights:
        """A copy with ``["name=value", ...]`` applied (the ``--weight`` option)."""
        changes = {}
        names = {f.name for f in dataclasses.fields(self)}
        for pair in pairs:
            name, sep, value = pair.partition("=")
            if not sep or name not in names:
                raise ValueError(f"--weight {pair!r}: use name=value, name one of {sorted(names)}")
            try:
                changes[name] = float(value)
            except ValueError:
                raise ValueError(f"--weight {pair!r}: {value!r} is not a number") from None
        return dataclasses.replace(self, **changes)


def _windows(exp: Experiment, t_s: np.ndarray) -> list[tuple[int, int]]:
    """Tick ranges ``[k0, k1)`` between consecutive commands (and the end)."""
    dt = float(t_s[1] - t_s[0]) if len(t_s) > 1 else 1.0
    n = len(t_s)
    starts = sorted({int(np.ceil(c.t_s / dt - 1e-9)) for c in exp.commands} | {0})
    starts = [k for k in starts if k < n]  # commands after the end of the log
    ends = starts[1:] + [n]
    return [(a, b) for a, b in zip(starts, ends, strict=True) if b > a]


def cost_terms(
    log: RunLog,
    exp: Experiment,
    *,
    current_limit_a: float,
    delay_ticks: int,
    settle_band_deg: float = CostWeights.settle_band_deg,
    pos_offset_deg: float = 0.0,
) -> dict[str, np.ndarray]:
    """Every term of :data:`TERMS` for each member, ``{name: (N,)}`` (``(1,)`` for a
    single-axis log). ``pos_offset_deg`` is added to the true position to bring it into the
    firmware's frame (an encoder zero offset)."""

    def rows(x: np.ndarray) -> np.ndarray:
        return x if x.ndim == 2 else x[None, :]

    t = log.t_s
    dt = float(t[1] - t[0])
    sp, pos = rows(log.sp_pos_deg), rows(log.true_pos_deg) + pos_offset_deg
    sp_vel = rows(log.sp_vel_dps)
    err = np.abs(sp - pos)
    n = sp.shape[0]
    itae = np.zeros(n)
    overshoot = np.zeros(n)
    settling = np.zeros(n)
    for k0, k1 in _windows(exp, t):
        age = t[k0:k1] - t[k0]
        itae += np.sum(age * err[:, k0:k1], axis=1) * dt
        # Arrival: the setpoint stops moving inside the window and stays put to its end
        # (shared setpoint: the same for every member).
        moving = np.nonzero(sp_vel[0, k0:k1] != 0.0)[0]
        if moving.size == 0 or k0 + moving[-1] + 1 >= k1:
            continue
        ka = k0 + moving[-1] + 1
        target = sp[0, ka]
        direction = np.sign(sp_vel[0, k0 + moving[-1]])
        past = direction * (pos[:, ka:k1] - target)
        overshoot = np.maximum(overshoot, np.max(np.maximum(past, 0.0), axis=1))
        outside = np.abs(pos[:, ka:k1] - target) > settle_band_deg
        last_out = np.where(
            outside.any(axis=1), outside.shape[1] - np.argmax(outside[:, ::-1], axis=1), 0
        )
        # Never inside the band: the whole rest of the window counts.
        settling = np.maximum(settling, last_out * dt)
    i_ref = rows(log.current_ref_a)
    at_limit = np.abs(i_ref) >= current_limit_a * (1.0 - 1e-9)
    duty = rows(log.duty)
    chatter = np.mean(np.abs(np.diff(duty, axis=1)), axis=1)
    shift = delay_ticks + 1
    i_true = rows(log.current_a)
    cur_err = np.mean(np.abs(i_ref[:, :-shift] - i_true[:, shift:]), axis=1)
    fault = (rows(log.fault) != 0).any(axis=1).astype(float)
    return {
        "itae_deg_s2": itae,
        "overshoot_deg": overshoot,
        "settling_s": settling,
        "current_limit_s": np.sum(at_limit, axis=1) * dt,
        "chatter_duty": chatter,
        "current_error_a": cur_err,
        "fault": fault,
    }


def combine(terms: dict[str, np.ndarray], weights: CostWeights) -> np.ndarray:
    """The weighted sum, ``(N,)``; NaN terms (a run that blew up) count as +inf."""
    total = sum(getattr(weights, name) * terms[name] for name in TERMS)
    return np.where(np.isfinite(total), total, np.inf)
