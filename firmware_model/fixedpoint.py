"""Saturating int32 Q-format arithmetic, as the FPU-less STM32F103 would run the control law.

Two formats (a Cortex-M3 does the 32 x 32 -> 64 bit product in one ``SMULL``):

==========  ===========  =========================  ==================================
format      raw type     range                      resolution
==========  ===========  =========================  ==================================
``Q16.16``  int32        +-32768                    1.5e-5   signals: axis deg, deg/s,
                                                              deg/s^2, A, V, duty, counts
``Q8.24``   int32        +-128                      6.0e-8   gains and constants
==========  ===========  =========================  ==================================

A signal times a gain is ``(s * g + 2^23) >> 24`` (round half up, arithmetic shift) and is
saturated to int32, as are all sums (``QADD``-style saturation, done in C with a compare).
One motor encoder count is exactly 18 raw units of Q16.16 axis degrees
(``360 * 2^16 / (16384 * 80) = 18``), so positions need no rounding on the way in.

The arrays here are int64 numpy arrays that always hold int32-range values: numpy gives the
64-bit intermediate product that ``SMULL`` gives the MCU.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = [
    "GAIN_FRAC_BITS",
    "INT32_MAX",
    "INT32_MIN",
    "SIG_FRAC_BITS",
    "from_sig",
    "mul_gain",
    "sat32",
    "to_gain",
    "to_sig",
]

SIG_FRAC_BITS = 16
GAIN_FRAC_BITS = 24
INT32_MIN = -(1 << 31)
INT32_MAX = (1 << 31) - 1
_SIG_ONE = float(1 << SIG_FRAC_BITS)
_GAIN_ONE = float(1 << GAIN_FRAC_BITS)
_GAIN_HALF = 1 << (GAIN_FRAC_BITS - 1)
# numpy scalars: np.clip with Python-int bounds looks up integer limits on every call.
_LO = np.int64(INT32_MIN)
_HI = np.int64(INT32_MAX)

IntArray = npt.NDArray[np.int64]


def sat32(x: IntArray) -> IntArray:
    """Saturate int64 values to the int32 range."""
    return np.minimum(np.maximum(x, _LO), _HI)


def to_sig(x: float | npt.ArrayLike) -> IntArray:
    """A float (array) as Q16.16 raw integers, rounded to nearest and saturated."""
    scaled = np.round(np.asarray(x, dtype=float) * _SIG_ONE)
    return np.minimum(np.maximum(scaled, float(INT32_MIN)), float(INT32_MAX)).astype(np.int64)


def to_gain(x: float | npt.ArrayLike) -> IntArray:
    """A float (array) as Q8.24 raw integers, rounded to nearest and saturated."""
    scaled = np.round(np.asarray(x, dtype=float) * _GAIN_ONE)
    return np.minimum(np.maximum(scaled, float(INT32_MIN)), float(INT32_MAX)).astype(np.int64)


def from_sig(q: IntArray) -> npt.NDArray[np.float64]:
    """Q16.16 raw integers back to floats."""
    return np.asarray(q, dtype=float) / _SIG_ONE


def mul_gain(sig: IntArray, gain: IntArray) -> IntArray:
    """Q16.16 signal times Q8.24 gain -> Q16.16, rounded half up and saturated."""
    return sat32((sig * gain + _GAIN_HALF) >> GAIN_FRAC_BITS)
