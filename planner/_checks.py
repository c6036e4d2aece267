"""Argument checks shared by the planners: a bad value raises ValueError naming it."""

from __future__ import annotations

import math


def check_finite(**values: float) -> None:
    """Raise ``ValueError("name = value: ...")`` for the first non-finite or non-number."""
    for name, value in values.items():
        if not isinstance(value, int | float) or not math.isfinite(value):
            raise ValueError(f"{name} = {value!r}: must be a finite number")


def check_positive(**values: float) -> None:
    """Raise ``ValueError("name = value: ...")`` for the first value not finite and > 0."""
    for name, value in values.items():
        if not isinstance(value, int | float) or not (value > 0.0 and math.isfinite(value)):
            raise ValueError(f"{name} = {value!r}: must be a finite number > 0")
