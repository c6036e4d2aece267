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


def check_reaches(prof: object) -> None:
    """Raise ``ValueError`` if a planned profile does not end where it says (beyond rounding).

    Only arguments at the edge of floating point get here (a subnormal limit beside a huge
    distance): their phases overflow or cancel, and a profile that silently jumped to its
    target would be worse than a refusal.
    """
    t0 = prof.t0  # type: ignore[attr-defined]
    p0, p1 = prof.p0, prof.p1  # type: ignore[attr-defined]
    if not t0:
        p_end, scale = p0, abs(p0)
    else:
        i = len(t0) - 1
        big_t = prof.duration  # type: ignore[attr-defined]
        tau = big_t - t0[i]
        p, v, a, j = prof.p[i], prof.v[i], prof.a[i], prof.j[i]  # type: ignore[attr-defined]
        p_end = p + tau * (v + tau * (0.5 * a + tau * j / 6.0))
        # O(1) bound of the distances involved (the rounding scale); no loop: it runs on
        # every plan.
        v0, a0 = prof.v0, prof.a0  # type: ignore[attr-defined]
        scale = abs(p0) + abs(p) + (abs(v0) + abs(v)) * big_t + abs(a0) * big_t * big_t
    # The absolute floor: far below any position resolution (the tests' own floor is 1e-9),
    # above what subnormal intermediate products lose.
    if not abs(p_end - p1) <= 1e-6 * (scale + abs(p1)) + 1e-12:
        raise ValueError(
            f"p1 = {p1!r}: cannot be planned to rounding with these limits "
            f"(the phases end at {p_end!r})"
        )
