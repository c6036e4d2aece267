"""Beyond the paper: Fig. 7 and Fig. 8 again with the 7-segment S-curve planner (seed 002's
profile, planned time-optimally by ``planner.plan_scurve``), compared with the trapezoid:
peak jerk, peak current and duration.

The paper has no S-curve run, so the jerk limit is our choice: the acceleration ramps from
0 to a_max in ``RAMP_S`` (j_max = 148 / 0.25 = 592 deg/s^3).
"""

from __future__ import annotations

from dataclasses import dataclass

from sim.reproduce import fig7, fig8
from sim.reproduce.experiments import Runner
from sim.reproduce.metrics import RunMetrics

__all__ = ["RAMP_S", "ProfileComparison", "ScurveResult", "compare", "run"]

RAMP_S = 0.25


@dataclass(frozen=True)
class ProfileComparison:
    """One scenario with both profiles. Durations run from the (first) move's start to the
    instant the setpoint reaches the final target (paper scale also under ``--quick``)."""

    name: str
    trapezoid: RunMetrics
    scurve: RunMetrics
    duration_trapezoid_s: float
    duration_scurve_s: float


@dataclass(frozen=True)
class ScurveResult:
    fig7: fig7.Fig7Result
    fig8: fig8.Fig8Result
    comparisons: tuple[ProfileComparison, ...]
    j_max_dps3: float


def _duration(m: RunMetrics, t0: float, k: float) -> float:
    return float("nan") if m.plan_end_t_s is None else (m.plan_end_t_s - t0) * k


def compare(
    trap7: fig7.Fig7Result, trap8: fig8.Fig8Result, sc7: fig7.Fig7Result, sc8: fig8.Fig8Result
) -> tuple[ProfileComparison, ...]:
    out = []
    k = trap7.time_scale
    for a, b in zip(trap7.runs, sc7.runs, strict=True):
        out.append(
            ProfileComparison(
                f"Fig. 7 {a.name}",
                a.metrics,
                b.metrics,
                _duration(a.metrics, a.t_interrupt_s, k),
                _duration(b.metrics, b.t_interrupt_s, k),
            )
        )
    out.append(
        ProfileComparison(
            "Fig. 8",
            trap8.metrics,
            sc8.metrics,
            _duration(trap8.metrics, trap8.trace.command_t_s[0], k),
            _duration(sc8.metrics, sc8.trace.command_t_s[0], k),
        )
    )
    return tuple(out)


def run(runner: Runner, trap7: fig7.Fig7Result, trap8: fig8.Fig8Result) -> ScurveResult:
    sc7 = fig7.run(runner, scurve_ramp_s=RAMP_S)
    sc8 = fig8.run(runner, scurve_ramp_s=RAMP_S)
    return ScurveResult(sc7, sc8, compare(trap7, trap8, sc7, sc8), trap8.a_max_dps2 / RAMP_S)
