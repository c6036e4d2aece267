"""The AS5048 14-bit magnetic encoder on the motor tail, as the STM32 reads it over SPI.

A reading is the motor angle ``latency_s`` ago (the chip's internal sampling and filtering:
output rate 10.2-12.4 kHz per the datasheet, so about one 90 us sample old; the plant is
smooth over that interval, so ``theta(t - tau) = theta - w tau`` is used), plus optional
Gaussian noise in LSB (datasheet: at most 0.06 deg = 2.73 LSB rms), truncated to an integer
count and wrapped to ``[0, 2**bits)``. The noise comes from a seeded
``numpy.random.Generator`` owned by the caller, so runs are reproducible.

Integral non-linearity (``inl_counts``): the chip's angle error is a periodic function of
the magnet's angle, i.e. of the motor angle; its first two harmonics (once per turn from an
off-centre magnet, twice per turn from an elliptic field) are added to the reading,
``A1 sin(theta + phi1) + A2 sin(2 theta + phi2)``. At speed they become a velocity ripple at
the motor's rotation frequency in the raw count difference (docs/model.md).
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from sim.params import EncoderParams, per_member
from sim.plant import POS, VEL

__all__ = ["BLOCK", "Encoder", "inl_counts", "inl_params"]

BLOCK = _BLOCK = 4096  # ticks of noise drawn at once (at most)


class Encoder:
    """Reads the counts of N members from plant states ``(N, 5)`` (``read``).

    Noise: standard normals are drawn from ``rng`` in blocks of 4096 ticks x N (row k is
    tick k's draw for every member), the same stream as one draw of N per tick."""

    def __init__(self, params: EncoderParams, rng: np.random.Generator) -> None:
        self.params = params
        self.rng = rng
        self.counts_per_rev = params.counts_per_rev
        self._counts_per_rad = self.counts_per_rev / (2.0 * math.pi)
        self._noisy = bool(np.any(params.noise_rms_lsb))
        self._n = 0
        self._params: tuple[np.ndarray, ...] = ()
        self.block = np.empty((0, 0))
        self.row = 0

    @property
    def noisy(self) -> bool:
        return self._noisy

    def kernel_params(self, n: int) -> tuple[Any, ...]:
        """``(latency_s, offset_counts, noise_lsb)`` as ``(n,)`` arrays, then counts per rad
        and per revolution, then the INL rows (``inl_params``): the arguments of the
        compiled reading after the state."""
        if self._n != n:
            p = self.params
            self._n = n
            self._params = tuple(
                per_member(v, n) for v in (p.latency_s, p.offset_counts, p.noise_rms_lsb)
            )
            self._inl = inl_params(p, n)
        return (*self._params, self._counts_per_rad, self.counts_per_rev, self._inl)

    def refill(self, n: int, rows: int = _BLOCK) -> None:
        """Draw the next block of standard normals (a numpy call per read would cost more
        than the read); ``block`` and ``row`` are the compiled loop's too. ``rows``: ticks
        in the block; the generator's stream is the same whatever the blocks' sizes, so a
        caller whose ``rng`` feeds nothing else may draw only the ticks it will run."""
        self.block = self.rng.standard_normal((rows, n))
        self.row = 0

    def read(self, x: np.ndarray, rows: int = _BLOCK) -> np.ndarray:
        """Counts in ``[0, counts_per_rev)`` (int64 ``(N,)``) for states ``(N, 5)``;
        ``rows``: the size of a block of draws it has to draw (``refill``)."""
        n = x.shape[0]
        params = self.kernel_params(n)
        if self._noisy:
            if self.row == self.block.shape[0]:
                self.refill(n, rows)
            draw = self.block[self.row]
            self.row += 1
        else:
            draw = _NO_DRAW
        counts = np.empty(n, dtype=np.int64)
        latency, offset, noise, counts_per_rad, counts_per_rev, inl = params
        _read(x, latency, offset, noise, draw, counts_per_rad, counts_per_rev, counts, inl)
        return counts


def inl_params(params: EncoderParams, n: int) -> np.ndarray:
    """The INL harmonics of N members as ``(N, 4)``: amplitude (counts) and phase (rad) of
    the first and second harmonic; ``(0, 4)`` when every amplitude is zero (INL off: the
    reading is bit for bit the one without it)."""
    a1, a2 = (per_member(v, n) for v in (params.inl_h1_deg, params.inl_h2_deg))
    if not (np.any(a1) or np.any(a2)):
        return np.empty((0, 4))
    lsb_per_deg = params.counts_per_rev / 360.0
    out = np.empty((n, 4))
    out[:, 0] = a1 * lsb_per_deg
    out[:, 1] = np.radians(per_member(params.inl_h1_phase_deg, n))
    out[:, 2] = a2 * lsb_per_deg
    out[:, 3] = np.radians(per_member(params.inl_h2_phase_deg, n))
    return out


@numba.njit(cache=True)
def inl_counts(theta_rad, a1, p1, a2, p2):
    """The reading's INL error (counts) at motor angle ``theta_rad``: the first two
    harmonics, amplitudes ``a1``, ``a2`` (counts) and phases ``p1``, ``p2`` (rad)."""
    return a1 * math.sin(theta_rad + p1) + a2 * math.sin(2.0 * theta_rad + p2)


_NO_DRAW = np.empty(0)


@numba.njit(cache=True)
def _read(x, latency_s, offset_counts, noise_lsb, draw, counts_per_rad, counts_per_rev, out, inl):
    """The reading of each member; ``draw`` holds one standard normal per member, or
    nothing for a noiseless encoder; ``inl`` the ``inl_params`` rows, or none."""
    noisy = draw.shape[0] > 0
    nonlinear = inl.shape[0] > 0
    for j in range(x.shape[0]):
        theta = x[j, POS] - x[j, VEL] * latency_s[j]
        c = theta * counts_per_rad + offset_counts[j]
        if nonlinear:
            c += inl_counts(theta, inl[j, 0], inl[j, 1], inl[j, 2], inl[j, 3])
        if noisy:
            c += noise_lsb[j] * draw[j]
        out[j] = np.int64(math.floor(c)) % counts_per_rev  # floored modulo, as Python
