"""Does a value fit its field on the wire? Asked of the codec itself, so that the config
loader and the command line refuse exactly what ``serial_protocol.frame.encode`` cannot send.

A scripted command or a command-line option that cannot be encoded (a target of 3e6 deg
beyond the int32 position field, a gain of 1e40 beyond float32, a decimation of -1 below
u16) is a bad input, refused before anything runs, with the field and its range named.
Whether a value that *fits* is acceptable is the board's to decide, with a NACK.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
import typing
from typing import Any

from serial_protocol import frame
from serial_protocol.messages import Message

__all__ = ["field_range", "fits", "wire_problem"]


def _neutral(hint: Any) -> Any:
    """A value every wire field of this type holds (0, False or the first enum member)."""
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        return next(iter(hint))
    if hint is bool:
        return False
    return 0


def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _numeric_fields(cls: type) -> list[str]:
    hints = _hints(cls)
    return [f.name for f in dataclasses.fields(cls) if hints.get(f.name) in (int, float)]


def fits(cls: type, name: str, value: Any) -> bool:
    """Whether field ``name`` of message class ``cls`` can carry ``value`` on the wire."""
    hints = _hints(cls)
    kwargs = {f.name: _neutral(hints.get(f.name)) for f in dataclasses.fields(cls)}
    kwargs[name] = value
    try:
        frame.encode(cls(**kwargs), 0)
    except (ValueError, TypeError):
        return False
    return True


@functools.cache
def field_range(cls: type, name: str) -> tuple[float, float]:
    """``(lowest, highest)`` value of field ``name`` of message class ``cls`` that the codec
    encodes, found by asking it (bisection over floats; exact for integer fields)."""
    is_int = _hints(cls).get(name) is int

    def edge(sign: float) -> float:
        if not fits(cls, name, _as(sign * (1.0 if is_int else 1e-300), is_int)):
            return 0.0
        hi = 1.0
        while hi < 1e300 and fits(cls, name, _as(sign * hi, is_int)):
            hi *= 2.0
        if hi >= 1e300:
            return sign * math.inf
        lo = hi / 2.0
        for _ in range(200):  # bisection to the last representable step
            mid = (lo + hi) / 2.0
            if is_int:
                mid = float(math.floor(mid))
            if mid in (lo, hi):
                break
            if fits(cls, name, _as(sign * mid, is_int)):
                lo = mid
            else:
                hi = mid
        return sign * lo

    return edge(-1.0), edge(1.0)


def _as(value: float, is_int: bool) -> float | int:
    return int(value) if is_int else value


def wire_problem(msg: Message) -> str:
    """Why ``msg`` cannot be sent ('' if it can): the first field that does not fit, with its
    value and the wire range. Non-finite values are refused too (the PC tools send numbers;
    a NaN for a NACK test goes as raw bytes)."""
    cls = type(msg)
    for name in _numeric_fields(cls):
        value = getattr(msg, name)
        if isinstance(value, float) and not math.isfinite(value):
            return f"{name} = {value!r}: must be finite"
        if not fits(cls, name, value):
            lo, hi = field_range(cls, name)
            return (
                f"{name} = {value!r}: does not fit the wire "
                f"({cls.__name__}.{name} holds {lo:.10g} .. {hi:.10g})"
            )
    try:
        frame.encode(msg, 0)
    except (ValueError, TypeError) as exc:
        return str(exc)
    return ""
