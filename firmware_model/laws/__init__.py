"""The control law, written once for N members in each arithmetic: ``float64.py`` (float64)
and ``fixed_q.py`` (saturating int32 Q16.16 / Q8.24, as on the FPU-less STM32F103), over the
state layout of ``layout.py``; ``law.py`` holds the state and calls the steps.
``firmware_model/servo.py`` describes what they compute."""

from firmware_model import kernel_cache

kernel_cache.check()  # before any kernel loads from numba's cache

from firmware_model.laws.law import GAIN_NAMES, Law  # noqa: E402

__all__ = ["GAIN_NAMES", "Law"]
