"""Runs that keep the plant's inputs: shared by the plant replay tests of this folder (they
import it by name: tests/sim/conftest.py puts the folder on the path)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sim import loop


def recording(run: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[loop.Simulation, Any]:
    """``(simulation, run(*args, **kwargs))`` with every ``loop.Simulation`` that ``run``
    builds (``loop.run`` builds one) recording its plant's inputs (``record_inputs=True``:
    ``sim.inputs()`` gives the ``(duty, enable)`` of every plant step); the last one built is
    returned."""
    built = []

    class Recording(loop.Simulation):
        def __init__(self, *a: Any, **k: Any) -> None:
            k["record_inputs"] = True
            super().__init__(*a, **k)
            built.append(self)

    saved = loop.Simulation
    loop.Simulation = Recording  # type: ignore[misc]
    try:
        result = run(*args, **kwargs)
    finally:
        loop.Simulation = saved  # type: ignore[misc]
    return built[-1], result
