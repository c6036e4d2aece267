"""Hypothesis profiles for the whole suite.

The suite is deterministic: property tests draw their examples from a seed derived from each
test (``derandomize=True``), so a run fails or passes the same way every time, on any machine
and under any load. Random exploration, which finds new cases, is a separate, manual run:

    TURNTABLE_HYPOTHESIS=explore python3 -m pytest tests/planner tests/serial_protocol

Every case an exploration run finds is kept in the test as an ``@example``.
Test-specific ``@settings(...)`` (example counts) inherit from the profile loaded here.
"""

import os

from hypothesis import settings

settings.register_profile("suite", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("TURNTABLE_HYPOTHESIS", "suite"))
