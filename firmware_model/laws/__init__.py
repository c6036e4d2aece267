"""The interchangeable implementations of the control law (one per file, same methods and
attributes): ``ScalarLaw`` (floats), ``ScalarFixedLaw`` (Q-format on ints), ``ArrayLaw``
(batch: float64 in the compiled loops of ``array_float.py``, or Q-format on numpy).
``firmware_model/servo.py`` describes what they compute."""

from firmware_model.laws.array import ArrayLaw
from firmware_model.laws.common import GAIN_NAMES, LawBase
from firmware_model.laws.scalar import ScalarLaw
from firmware_model.laws.scalar_fixed import ScalarFixedLaw

__all__ = ["ArrayLaw", "GAIN_NAMES", "LawBase", "ScalarFixedLaw", "ScalarLaw"]
