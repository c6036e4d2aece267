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

The chip's diagnostics: the angle and diagnostics + AGC SPI frames of every reading, in
the layout of ``firmware_model/as5048.py`` (the firmware's driver, which checks them).
:meth:`Encoder.inject` switches a fault on or off per member (the fault-injection
switch of the tests and benchmarks): ``"freeze"`` (the angle stops where it is, the noise
stays: a magnet slipping on its shaft; the chip itself reports nothing), ``"mag_weak"``
(AGC 255, COMP_HIGH, 8x the noise), ``"mag_strong"`` (AGC 0, COMP_LOW), ``"cordic"``
(COF, random angles), ``"parity"`` (one bit of the angle frame flipped on the wire),
``"error_flag"`` (EF set). :meth:`Encoder.spi_frames` gives the frames of the last
reading; it returns None while no member has a fault that shows in the frames (the frames
are then all valid, with OCF set and the nominal AGC), so a healthy run builds none.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from firmware_model.as5048 import (
    ANGLE_MASK,
    COF_BIT,
    COMP_HIGH_BIT,
    COMP_LOW_BIT,
    EF_BIT,
    OCF_BIT,
    parity_bit,
)
from firmware_model.kernel_cache import kernel
from sim.params import EncoderParams, per_member
from sim.plant import POS, VEL

__all__ = [
    "AGC_NOMINAL", "BLOCK", "DIAG_FAULTS", "Encoder", "FAULT_KINDS", "inject_faults",
    "inl_counts", "inl_params",
]  # fmt: skip

BLOCK = _BLOCK = 4096  # ticks of noise drawn at once (at most)
_CHUNKS = 8  # refill's rest of a block is drawn on its thread in this many chunks
#: The AGC value of the magnet at its nominal distance (assumed: mid-range).
AGC_NOMINAL = 128
#: Injectable faults (see the module docstring); the index is the member's fault code.
FAULT_KINDS = ("none", "freeze", "mag_weak", "mag_strong", "cordic", "parity", "error_flag")
#: The faults that show in the SPI frames (all but a frozen magnet).
DIAG_FAULTS = ("mag_weak", "mag_strong", "cordic", "parity", "error_flag")
(
    _F_NONE, _F_FREEZE, _F_MAG_WEAK, _F_MAG_STRONG, _F_CORDIC, _F_PARITY, _F_ERROR_FLAG,
) = range(len(FAULT_KINDS))  # fmt: skip


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
        # refill's draws of the rest of a block into _full, on the drawing thread, if any:
        # (end row, its chunk's future), in order.
        self._rest: list[tuple[int, Future[np.ndarray]]] | None = None
        self._full: np.ndarray | None = None
        self._fault = np.zeros(0, dtype=np.int64)  # per member: index into FAULT_KINDS
        self._frozen_counts = np.zeros(0)
        self._last = np.zeros(0, dtype=np.int64)
        self._spi: tuple[np.ndarray, np.ndarray] | None = None
        self._faulted = False  # the last read had a fault injected
        # The CORDIC fault's random angles: a small generator of the compiled code's own
        # (an LCG state, (1,) int64), seeded from rng at the first injection.
        self._lcg = np.zeros(1, dtype=np.int64)

    def inject(self, kind: str, members: Any = None, x: np.ndarray | None = None) -> None:
        """Switch fault ``kind`` (one of :data:`FAULT_KINDS`; ``"none"`` heals) on for the
        members in ``members`` (an index, a list or a bool mask; all by default). A
        ``"freeze"`` holds the angle of plant state ``x`` (``(N, 5)`` or ``(5,)``), or of the
        last reading.
        """
        if kind not in FAULT_KINDS:
            raise ValueError(f"kind = {kind!r}: must be one of {FAULT_KINDS}")
        self.finish()  # the LCG's seed comes from rng after the noise drawn so far
        if x is not None:
            x = np.atleast_2d(np.asarray(x, dtype=float))
        n = self._n or (x.shape[0] if x is not None else 1)
        if self._fault.shape[0] != n:
            self._fault = np.zeros(n, dtype=np.int64)
            self._frozen_counts = np.zeros(n)
            self._lcg[0] = int(self.rng.integers(1, 1 << 31))
        sel = np.zeros(n, dtype=bool)
        sel[slice(None) if members is None else members] = True
        self._fault[sel] = FAULT_KINDS.index(kind)
        if kind == "freeze":
            if x is not None:
                offset = np.broadcast_to(np.asarray(self.params.offset_counts, float), (n,))
                angle = x[:, POS] * self._counts_per_rad + offset
            else:
                angle = self._last.astype(float) if self._last.shape[0] == n else np.zeros(n)
            self._frozen_counts[sel] = angle[sel]

    @property
    def noisy(self) -> bool:
        return self._noisy

    @property
    def faulty(self) -> bool:
        """Whether a fault is injected (the readings then go through :func:`inject_faults`
        and the firmware gets the SPI frames)."""
        return bool(self._fault.any())

    def fault_args(self, n: int) -> tuple[np.ndarray, ...]:
        """``(fault, frozen_counts, lcg, angle_frames, diag_frames)``: the arguments of
        :func:`inject_faults` after the noise (the compiled tick's too)."""
        if self._fault.shape[0] != n:
            self._fault = np.zeros(n, dtype=np.int64)
            self._frozen_counts = np.zeros(n)
        if self._spi is None or self._spi[0].shape[0] != n:
            self._spi = (np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64))
        return (self._fault, self._frozen_counts, self._lcg, *self._spi)

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

    def refill(self, n: int, rows: int = _BLOCK, head: int = 0) -> None:
        """Draw the next block of standard normals (a numpy call per read would cost more
        than the read); ``block`` and ``row`` are the compiled loop's too. ``rows``: ticks
        in the block; the generator's stream is the same whatever the blocks' sizes, so a
        caller whose ``rng`` feeds nothing else may draw only the ticks it will run.

        ``0 < head < rows``: only the first ``head`` rows are drawn here (``block`` holds
        them) and the rest on a thread, into the same array, in ``_CHUNKS`` chunks, while
        the caller runs the first ones (numpy draws without the GIL, the compiled tick runs
        without it: the draws of a batch run take the second core); ``more()`` extends
        ``block`` by the chunks drawn so far, ``finish()`` waits for them all. The same
        numbers in the same order either way (one thread draws the chunks one after the
        other)."""
        self.finish()
        if 0 < head < rows:
            full = np.empty((rows, n))
            self.rng.standard_normal(out=full[:head])
            draw, size = _drawer().submit, -(-(rows - head) // _CHUNKS)
            self._rest = [
                (min(at + size, rows), draw(self.rng.standard_normal, out=full[at : at + size]))
                for at in range(head, rows, size)
            ]
            self._full = full
            self.block = full[:head]
        else:
            self.block = self.rng.standard_normal((rows, n))
        self.row = 0

    @property
    def drawing(self) -> bool:
        """Whether ``refill`` is still drawing the rest of the block on its thread."""
        return self._rest is not None

    def more(self) -> None:
        """Wait for the next chunk ``refill`` draws on its thread; ``block`` then holds every
        row drawn so far (the rows it held before, unchanged, first)."""
        rest = self._rest
        if rest is None:
            return
        end, chunk = rest.pop(0)
        chunk.result()
        while rest and rest[0][1].done():
            end, chunk = rest.pop(0)
            chunk.result()
        if rest:
            self.block = self._full[:end]
        else:
            self._rest = None
            self.block, self._full = self._full, None

    def finish(self) -> None:
        """Wait for the rows ``refill`` draws on a thread; ``block`` then holds them all
        (nothing else may draw from ``rng`` before: every user of it calls this first)."""
        if self._rest is not None:
            for _, chunk in self._rest:
                chunk.result()
            self._rest = None
            self.block, self._full = self._full, None

    def read(self, x: np.ndarray, rows: int = _BLOCK, head: int = 0) -> np.ndarray:
        """Counts in ``[0, counts_per_rev)`` (int64 ``(N,)``) for states ``(N, 5)``;
        ``rows``, ``head``: the size of a block of draws it has to draw, and of its part
        drawn at once (``refill``)."""
        n = x.shape[0]
        params = self.kernel_params(n)
        if self._noisy:
            if self.row == self.block.shape[0]:
                if self.drawing:
                    self.more()
                elif head:
                    self.refill(n, rows, head)
                else:
                    self.refill(n, rows)
            draw = self.block[self.row]
            self.row += 1
        else:
            draw = _NO_DRAW
        counts = np.empty(n, dtype=np.int64)
        latency, offset, noise, counts_per_rad, counts_per_rev, inl = params
        _read(x, latency, offset, noise, draw, counts_per_rad, counts_per_rev, counts, inl)
        self._faulted = self.faulty
        if self._faulted:
            inject_faults(counts, noise, draw, counts_per_rev, *self.fault_args(n))
        self._last = counts
        return counts

    def spi_frames(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The angle and diagnostics frames (int64 ``(N,)``, 16 bits each) of the last
        :meth:`read`, or None while no fault is injected (every frame valid, OCF set, AGC
        nominal: a healthy run builds none)."""
        return self._spi if self._faulted else None


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


@kernel
def inl_counts(theta_rad, a1, p1, a2, p2):
    """The reading's INL error (counts) at motor angle ``theta_rad``: the first two
    harmonics, amplitudes ``a1``, ``a2`` (counts) and phases ``p1``, ``p2`` (rad)."""
    return a1 * math.sin(theta_rad + p1) + a2 * math.sin(2.0 * theta_rad + p2)


_NO_DRAW = np.empty(0)
_DRAWER: dict[int, ThreadPoolExecutor] = {}


def _drawer() -> ThreadPoolExecutor:
    """The one thread that draws the rest of the encoder's blocks (``Encoder.refill``),
    started at its first use and kept (starting a thread per block cost more than the
    draws it saved); one per process (a forked child has no thread of its parent's)."""
    pid = os.getpid()
    if pid not in _DRAWER:
        _DRAWER.clear()
        _DRAWER[pid] = ThreadPoolExecutor(1, thread_name_prefix="encoder-noise")
    return _DRAWER[pid]


@kernel
def _read(x, latency_s, offset_counts, noise_lsb, draw, counts_per_rad, counts_per_rev, out, inl):
    """The reading of each member; ``draw`` holds one standard normal per member, or
    nothing for a noiseless encoder; ``inl`` the ``inl_params`` rows, or none."""
    noisy = draw.shape[0] > 0
    nonlinear = inl.shape[0] > 0
    # A power of two (the AS5048's 16384): the floored modulo is a mask, not a division.
    mask = counts_per_rev - 1
    pow2 = counts_per_rev > 0 and (counts_per_rev & mask) == 0
    for j in range(x.shape[0]):
        theta = x[j, POS] - x[j, VEL] * latency_s[j]
        c = theta * counts_per_rad + offset_counts[j]
        if nonlinear:
            c += inl_counts(theta, inl[j, 0], inl[j, 1], inl[j, 2], inl[j, 3])
        if noisy:
            c += noise_lsb[j] * draw[j]
        f = np.int64(math.floor(c))
        out[j] = (f & mask) if pow2 else f % counts_per_rev  # floored modulo, as Python


@kernel
def inject_faults(counts, noise_lsb, draw, counts_per_rev, fault, frozen_counts, lcg, angle, diag):
    """The injected faults of N members (``fault``: index into :data:`FAULT_KINDS`) on the
    readings ``counts`` (int64 ``(N,)``, in place), and the SPI frames of every member
    (``angle``, ``diag``, int64 ``(N,)``, in the layout of ``firmware_model/as5048.py``).
    ``draw`` is the reading's standard normals (or none), ``frozen_counts`` the angle a
    frozen magnet holds, ``lcg`` the state of the CORDIC fault's random angles."""
    noisy = draw.shape[0] > 0
    for j in range(counts.shape[0]):
        kind = fault[j]
        noise = noise_lsb[j] * draw[j] if noisy else 0.0
        c = counts[j]
        d = OCF_BIT | AGC_NOMINAL
        a_extra = 0
        if kind == _F_FREEZE:  # the angle stops, the noise stays; the chip says nothing
            c = np.int64(math.floor(frozen_counts[j] + noise)) % counts_per_rev
        elif kind == _F_MAG_WEAK:  # AGC at its end, COMP_HIGH, 8x the noise
            c = (c + np.int64(math.floor(7.0 * noise))) % counts_per_rev
            d = OCF_BIT | COMP_HIGH_BIT | 255
        elif kind == _F_MAG_STRONG:  # AGC 0, COMP_LOW
            d = OCF_BIT | COMP_LOW_BIT
        elif kind == _F_CORDIC:  # COF: the angle is garbage
            lcg[0] = (lcg[0] * 1103515245 + 12345) & 0x7FFFFFFF
            c = (lcg[0] >> 8) % counts_per_rev
            d |= COF_BIT
        elif kind == _F_ERROR_FLAG:
            a_extra = EF_BIT
            d |= EF_BIT
        a = (c & ANGLE_MASK) | a_extra
        a |= parity_bit(a) << 15
        d |= parity_bit(d) << 15
        if kind == _F_PARITY:
            # A bit flipped on the wire after the chip computed the parity.
            a ^= 1 << 13
            c = a & ANGLE_MASK
        counts[j] = c
        angle[j] = a
        diag[j] = d
