"""The firmware's AS5048A driver: the SPI frame layout and the checks of each reading.

AS5048A datasheet, SPI interface: every 16-bit frame carries an even parity bit (bit 15,
over bits 14..0) and the error flag EF (bit 14: the previous SPI command failed). The angle
frame holds the 14-bit angle; the diagnostics + AGC register (0x3FFD) holds COMP_HIGH
(bit 11: the magnetic field is too weak), COMP_LOW (bit 10: too strong), COF (bit 9: CORDIC
overflow, the angle is invalid), OCF (bit 8: offset compensation finished, 1 after
power-up) and the AGC value (bits 7..0: 0 = strongest field, 255 = weakest).

The plant's encoder (``sim/encoder.py``) builds the frames with this layout; the firmware
checks them with :func:`check_reading` every tick (compiled, once for N members: the
firmware's Python tick and the simulation's compiled tick call the same function).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from firmware_model.kernel_cache import kernel
from firmware_model.laws.layout import C_D, C_RAW_PREV, REV

__all__ = [
    "AGC_MASK",
    "ANGLE_MASK",
    "ANGLE_UNUSABLE",
    "COF_BIT",
    "COMP_HIGH_BIT",
    "COMP_LOW_BIT",
    "EF_BIT",
    "ERROR_NAMES",
    "OCF_BIT",
    "PAR_BIT",
    "check_reading",
    "clear_diag",
    "frame_errors",
    "parity_bit",
    "reading_errors",
    "with_parity",
]

PAR_BIT = 1 << 15
EF_BIT = 1 << 14
COMP_HIGH_BIT = 1 << 11
COMP_LOW_BIT = 1 << 10
COF_BIT = 1 << 9
OCF_BIT = 1 << 8
ANGLE_MASK = (1 << 14) - 1
AGC_MASK = 0xFF

#: The bits of :func:`frame_errors`, in order (bit k is ``ERROR_NAMES[k]``).
ERROR_NAMES = (
    "angle_parity",  # the angle frame fails its parity: corrupted on the wire
    "diag_parity",  # the diagnostics frame fails its parity
    "error_flag",  # EF: the chip saw a bad command
    "cordic_overflow",  # COF: the angle is invalid
    "field_weak",  # COMP_HIGH: the magnet too far or missing
    "field_strong",  # COMP_LOW: the magnet too close
    "not_ready",  # OCF clear: offset compensation not finished
)
(
    _ERR_ANGLE_PARITY, _ERR_DIAG_PARITY, _ERR_EF, _ERR_COF, _ERR_WEAK, _ERR_STRONG,
    _ERR_NOT_READY,
) = range(len(ERROR_NAMES))  # fmt: skip
#: The errors after which the angle of the frame is not used.
ANGLE_UNUSABLE = (1 << _ERR_ANGLE_PARITY) | (1 << _ERR_EF) | (1 << _ERR_COF)


@kernel
def parity_bit(frame):
    """The even-parity bit over bits 14..0 of one frame."""
    bit = 0
    for b in range(15):
        bit ^= (frame >> b) & 1
    return bit


@kernel
def reading_errors(angle_frame, diag_frame):
    """The errors of one reading as bits of :data:`ERROR_NAMES` (0 = a valid angle from a
    healthy chip)."""
    bits = 0
    if parity_bit(angle_frame) != (angle_frame >> 15) & 1:
        bits |= 1 << _ERR_ANGLE_PARITY
    if parity_bit(diag_frame) != (diag_frame >> 15) & 1:
        bits |= 1 << _ERR_DIAG_PARITY
    if (angle_frame | diag_frame) & EF_BIT:
        bits |= 1 << _ERR_EF
    if diag_frame & COF_BIT:
        bits |= 1 << _ERR_COF
    if diag_frame & COMP_HIGH_BIT:
        bits |= 1 << _ERR_WEAK
    if diag_frame & COMP_LOW_BIT:
        bits |= 1 << _ERR_STRONG
    if not diag_frame & OCF_BIT:
        bits |= 1 << _ERR_NOT_READY
    return bits


def with_parity(frames: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """``frames`` (bits 14..0) with bit 15 set so that each has even parity."""
    frames = np.asarray(frames, dtype=np.int64) & 0x7FFF
    return frames | (np.array([parity_bit(f) for f in frames.ravel()], dtype=np.int64)
                     .reshape(frames.shape) << 15)  # fmt: skip


def frame_errors(
    angle_frames: npt.NDArray[np.int64], diag_frames: npt.NDArray[np.int64]
) -> npt.NDArray[np.int64]:
    """The errors of one reading per member as bits of :data:`ERROR_NAMES` (int64 ``(N,)``,
    0 = a valid angle from a healthy chip)."""
    a = np.asarray(angle_frames, dtype=np.int64)
    d = np.asarray(diag_frames, dtype=np.int64)
    return np.array([reading_errors(x, y) for x, y in zip(a, d, strict=True)], dtype=np.int64)


@kernel
def check_reading(angle_frames, diag_frames, counts, C, diag_ticks, diag_errors, booted):
    """The firmware's check of one reading per member (every tick it gets the frames):
    ``diag_errors`` (int64 ``(N,)``) gets the error bits, ``diag_ticks`` counts the readings
    in a row with an error (the ``ENCODER_DIAG`` trip compares it with ``encoder_diag_ticks``),
    and a reading whose angle cannot be trusted (parity, EF, CORDIC overflow) is replaced in
    ``counts`` by the prediction (the last reading plus the last step, from the law's ``C``),
    so that one corrupt frame neither jumps the position nor trips the jump check. Before
    the boot (``booted`` False) there is no prediction: the reading stays."""
    for j in range(counts.shape[0]):
        bits = reading_errors(angle_frames[j], diag_frames[j])
        diag_errors[j] = bits
        diag_ticks[j] = diag_ticks[j] + 1 if bits else 0
        if booted and bits & ANGLE_UNUSABLE:
            counts[j] = (C[C_RAW_PREV, j] + C[C_D, j]) % REV


@kernel
def clear_diag(diag_ticks, diag_errors):
    """Every member's chip read valid frames (no error this tick)."""
    for j in range(diag_ticks.shape[0]):
        diag_ticks[j] = 0
        diag_errors[j] = 0
