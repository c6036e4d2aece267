"""The law's three steps for compiled callers, chosen by the arithmetic of the state arrays
at compile time: ``S`` of int64 runs ``fixed_q``, of float64 ``float64``. (A compiled
function that took the step functions as arguments could not be cached by numba.)"""

from __future__ import annotations

from numba import types
from numba.extending import overload

from firmware_model.laws import fixed_q, float64

__all__ = ["current", "estimate", "servo"]


def estimate(raw, P, C, S, G, K):  # noqa: N803 - the layout's array names
    """``float64.estimate`` or ``fixed_q.estimate`` (compiled callers only)."""
    raise NotImplementedError("compiled callers only")


def servo(sp_pos_deg, sp_vel_dps, sp_acc_dps2, v_clamp_dps, i_limit_a, P, C, S, G, K):  # noqa: N803
    """``float64.servo`` or ``fixed_q.servo`` (compiled callers only)."""
    raise NotImplementedError("compiled callers only")


def current(adc, enabled, P, C, S, G, K):  # noqa: N803
    """``float64.current`` or ``fixed_q.current`` (compiled callers only)."""
    raise NotImplementedError("compiled callers only")


def _law(S):  # noqa: N803
    return fixed_q if isinstance(S.dtype, types.Integer) else float64


@overload(estimate, inline="always")
def _estimate(raw, P, C, S, G, K):  # noqa: N803
    step = _law(S).estimate
    return lambda raw, P, C, S, G, K: step(raw, P, C, S, G, K)


@overload(servo, inline="always")
def _servo(sp_pos_deg, sp_vel_dps, sp_acc_dps2, v_clamp_dps, i_limit_a, P, C, S, G, K):  # noqa: N803
    step = _law(S).servo
    return lambda sp_pos_deg, sp_vel_dps, sp_acc_dps2, v_clamp_dps, i_limit_a, P, C, S, G, K: step(
        sp_pos_deg, sp_vel_dps, sp_acc_dps2, v_clamp_dps, i_limit_a, P, C, S, G, K
    )


@overload(current, inline="always")
def _current(adc, enabled, P, C, S, G, K):  # noqa: N803
    step = _law(S).current
    return lambda adc, enabled, P, C, S, G, K: step(adc, enabled, P, C, S, G, K)
