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

import numpy as np

from sim.params import EncoderParams
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
        cpr = self.counts_per_rev
        self._wrap_mask = cpr - 1 if cpr & (cpr - 1) == 0 else None

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
        # The arithmetic of read(), in place (each numpy call costs more than its work).
        c = x[:, VEL] * self._latency_s
        np.subtract(x[:, POS], c, out=c)
        c *= self._counts_per_rad
        c += self._offset
        if self._noisy:
            c += self._noise * self.rng.standard_normal(x.shape[0])
        np.floor(c, out=c)
        counts = c.astype(np.int64)
        if self._wrap_mask is not None:
            counts &= self._wrap_mask  # the floored modulo of a power of two
            return counts
        return counts % self.counts_per_rev
