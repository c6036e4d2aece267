"""The firmware's current limit against the true current of the plant of ``sim/``: Fig. 6's
step without planning (``bench_configs/fig6.toml`` as written), the hardest braking the
bench does. The high-side current sense cannot see the regenerative current, so the limit
there rests on the firmware's regenerative clamp (docs/model.md, "The current loop")."""

from __future__ import annotations

import numpy as np
import pytest

from sim.loop import run
from sim.reproduce.experiments import load, with_duration

# Documented margin (docs/model.md): on a current step the true current overshoots the 5 A
# clamp for a period or two, in the direction the sense sees (1.5 % on the bench, 3.5 % with
# a 26 V supply). Against the duty (regenerating, unseen) it must stay within the limit.
STEP_MARGIN = 0.05


def _regenerative_peak_a(current_a: np.ndarray, duty: np.ndarray) -> float:
    """Largest |true current| flowing against the duty that drove it (or with no duty):
    the state at tick k is the end of the period driven by the duty of tick k - 1."""
    applied = np.concatenate([[0.0], duty[:-1]])
    blind = (current_a * applied < 0.0) | (applied == 0.0)
    return float(np.max(np.abs(current_a[blind])))


@pytest.mark.parametrize(
    "overrides",
    [
        {},
        # The supply 2 V above the 24 V the firmware is configured for (the tuner's spread is
        # 20-26 V). The current PI learns about -1.6 V of model error at cruise; held through
        # the blind braking, it drove the true current to 5.93 A before the clamp.
        {"supply.voltage_v": 26.0},
    ],
    ids=["bench", "supply_26V"],
)
def test_fig6_step_true_current_stays_within_the_limit(overrides):
    exp = with_duration(load("fig6"), 4.0)  # braking ends at 3.4 s
    log = run(exp, overrides=overrides).log
    limit = exp.bench.firmware.limits.current_limit_a
    assert np.all(log.fault == 0)
    assert log.pos_deg[-1] == pytest.approx(3000.0, abs=0.05)
    assert np.max(log.true_vel_dps) > 980.0  # it really ran at the limits
    assert np.min(log.current_a) < -0.9 * limit  # and braked at the limit
    assert np.max(np.abs(log.current_a)) <= (1.0 + STEP_MARGIN) * limit
    assert _regenerative_peak_a(log.current_a, log.duty) <= limit
