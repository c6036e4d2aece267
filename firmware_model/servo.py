"""The control law of one servo tick: encoder unwrap, velocity observer, position P ->
velocity PI -> current PI -> PWM duty, with clamps and anti-windup.

One implementation per arithmetic, each written once for ``N`` members (one axis is
N = 1): ``firmware_model/laws/float64.py`` (float64) and ``firmware_model/laws/fixed_q.py``
(saturating int32 Q16.16 / Q8.24, ``arithmetic = "fixed"``; see
``firmware_model/fixedpoint.py``), both compiled with numba, over the state arrays of
``firmware_model/laws/layout.py``; :class:`Law` holds that state and calls them.

The order of one servo tick (seed 000 Fig. 5), with the firmware's shell around it:

1. :meth:`estimate`: unwrap the 14-bit reading around the observer's *prediction* (so the
   motor may turn more than half a revolution per tick as long as the prediction is within
   half a revolution), then a third-order observer (position, velocity, acceleration
   disturbance; the current of the period that just ended as a known acceleration) gives
   the velocity; the plain
   difference is kept as ``vel_raw_dps``.
2. :meth:`servo`: position error -> ``v_ref = Kp_pos e + vel_ff sp_vel`` clamped to the velocity
   limit -> ``i_ref = Kp_vel (v_ref - vel) + I + acc_ff sp_acc`` clamped to the current limit,
   integrating only when that does not push further into the clamp (conditional integration).
3. :meth:`current` (``current_loop_multiple`` times per tick): the sensed current is the
   BTN7971 IS reading (high side only) signed by the duty being applied (or, while the
   sense is blind to a current against the duty, the reference); the PI error compares it
   with the reference of the duty that produced it; ``u = R i_ref + k_emf vel + Kp e + I``
   volts, clamped to ``duty_limit * supply_v`` with the same anti-windup, divided by the
   supply and quantised to the timer's ARR steps. The duty computed now is returned
   ``compute_delay_ticks`` calls later (the timer loads the compare register at its next
   update event).
"""

from __future__ import annotations

from firmware_model.laws import GAIN_NAMES, Law

__all__ = ["GAIN_NAMES", "Law"]
