"""The AS5048 14-bit magnetic encoder on the motor tail, as the STM32 reads it over SPI.

A reading is the motor angle ``latency_s`` ago (the chip's internal sampling and filtering:
output rate 10.2-12.4 kHz per the datasheet, so about one 90 us sample old; the plant is
smooth over that interval, so ``theta(t - tau) = theta - w tau`` is used), plus optional
Gaussian noise in LSB (datasheet: at most 0.06 deg = 2.73 LSB rms), truncated to an integer
count and wrapped to ``[0, 2**bits)``. The noise comes from a seeded
``numpy.random.Generator`` owned by the caller, so runs are reproducible.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sim.params import EncoderParams, per_member
from sim.plant import POS, VEL

__all__ = ["Encoder"]


class Encoder:
    """Reads counts from a plant state; ``read`` for N = 1 lists, ``read_batch`` for (N, 5)."""

    def __init__(self, params: EncoderParams, rng: np.random.Generator) -> None:
        self.params = params
        self.rng = rng
        self.counts_per_rev = params.counts_per_rev
        self._counts_per_rad = self.counts_per_rev / (2.0 * math.pi)
        self._latency_s = params.latency_s
        self._noise = params.noise_rms_lsb
        self._offset = params.offset_counts
        self._block: list[float] = []
        self._noisy = bool(np.any(self._noise))
        self._batch_n = 0
        self._batch_params: tuple[np.ndarray, ...] = ()

    def read(self, x: list[float]) -> int:
        """Counts in ``[0, counts_per_rev)`` for a single state list (fast path)."""
        c = (x[POS] - x[VEL] * self._latency_s) * self._counts_per_rad + self._offset
        if self._noise:
            if not self._block:
                # Drawn in blocks (a numpy call per read would cost more than the read).
                self._block = (self._noise * self.rng.standard_normal(4096)).tolist()[::-1]
            c += self._block.pop()
        return math.floor(c) % self.counts_per_rev

    def read_batch(self, x: np.ndarray) -> np.ndarray:
        """Counts (int64 array (N,)) for states of shape (N, 5)."""
        n = x.shape[0]
        if self._batch_n != n:
            self._batch_n = n
            self._batch_params = tuple(
                per_member(v, n) for v in (self._latency_s, self._offset, self._noise)
            )
        draw = self.rng.standard_normal(n) if self._noisy else _NO_DRAW
        counts = np.empty(n, dtype=np.int64)
        _read_batch(x, *self._batch_params, draw, self._counts_per_rad, self.counts_per_rev, counts)
        return counts


_NO_DRAW = np.empty(0)


@numba.njit(cache=True)
def _read_batch(x, latency_s, offset_counts, noise_lsb, draw, counts_per_rad, counts_per_rev, out):
    """``Encoder.read`` per member (the same operations in the same order); ``draw`` holds
    one standard normal per member, or nothing for a noiseless encoder."""
    noisy = draw.shape[0] > 0
    for j in range(x.shape[0]):
        c = (x[j, POS] - x[j, VEL] * latency_s[j]) * counts_per_rad + offset_counts[j]
        if noisy:
            c += noise_lsb[j] * draw[j]
        out[j] = np.int64(math.floor(c)) % counts_per_rev  # floored modulo, as Python
