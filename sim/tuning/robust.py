"""Robustness: every gain set against a spread of the plant, all in one lock-step batch;
the worst case of each cost term.

The spread (:data:`SPREAD`) is the corners of five factors plus the nominal plant:
load (platter) inertia x0.7 / x1.3, friction (motor and platter, Coulomb and viscous)
x0.5 / x2, supply 20 / 26 V (the firmware still assumes 24 V), encoder noise off / on
(1 LSB rms), belt stiffness x0.7 / x1.3: 2^5 + 1 = 33 plants per gain set.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from sim.config import Experiment
from sim.tuning.cost import TERMS, CostWeights
from sim.tuning.evaluate import evaluate
from sim.tuning.gains import GainSet

__all__ = ["SPREAD", "plant_spread", "robust_table", "spread_evaluate"]

#: factor name -> (low, high) multipliers (or values, for supply and noise).
SPREAD: dict[str, tuple[float, float]] = {
    "inertia": (0.7, 1.3),
    "friction": (0.5, 2.0),
    "supply_v": (20.0, 26.0),
    "noise_lsb": (0.0, 1.0),
    "belt": (0.7, 1.3),
}


def plant_spread(exp: Experiment) -> list[dict[str, float]]:
    """The plants of the spread as ``{"table.key": value}`` (nominal first)."""
    p = exp.bench.plant
    nominal = {
        "platter.j_kgm2": p.platter.j_kgm2,
        "motor.coulomb_nm": p.motor.coulomb_nm,
        "motor.viscous_nm_s_rad": p.motor.viscous_nm_s_rad,
        "platter.coulomb_nm": p.platter.coulomb_nm,
        "platter.viscous_nm_s_rad": p.platter.viscous_nm_s_rad,
        "supply.voltage_v": p.supply.voltage_v,
        "encoder.noise_rms_lsb": p.encoder.noise_rms_lsb,
        "belt.stiffness_nm_rad": p.belt.stiffness_nm_rad,
    }
    plants = [dict(nominal)]
    for inertia, friction, supply, noise, belt in itertools.product(*SPREAD.values()):
        q = dict(nominal)
        q["platter.j_kgm2"] = nominal["platter.j_kgm2"] * inertia
        for key in (
            "motor.coulomb_nm",
            "motor.viscous_nm_s_rad",
            "platter.coulomb_nm",
            "platter.viscous_nm_s_rad",
        ):
            q[key] = nominal[key] * friction
        q["supply.voltage_v"] = supply
        q["encoder.noise_rms_lsb"] = noise
        q["belt.stiffness_nm_rad"] = nominal["belt.stiffness_nm_rad"] * belt
        plants.append(q)
    return plants


def spread_evaluate(
    scenarios: Sequence[Experiment],
    sets: Mapping[str, GainSet],
    *,
    weights: CostWeights,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, dict[str, float]]:
    """Per gain set: the worst case (max over the plants where the firmware latched no
    fault) of each term and of the cost, the plant index of the worst cost, and how many
    (and which) plants faulted."""
    plants = plant_spread(scenarios[0])
    labels = list(sets)
    members = [(label, plant) for label in labels for plant in plants]
    plant_ov: dict[str, Any] = {key: [plant[key] for _, plant in members] for key in plants[0]}
    ev = evaluate(
        scenarios,
        [sets[label] for label, _ in members],
        weights=weights,
        seed=seed,
        plant_overrides=plant_ov,
        progress=progress,
    )
    out = {}
    for label in labels:
        sel = np.array([m == label for m, _ in members])
        faulted = sel & (ev.terms["fault"] > 0)
        # A plant the bench cannot drive through the scenario (e.g. 20 V cannot reach
        # 990 deg/s) trips every gain set: count those, judge the gains on the others.
        judged = sel & ~faulted if np.any(sel & ~faulted) else sel
        worst = {t: float(np.max(ev.terms[t][judged])) for t in TERMS}
        worst["cost"] = float(np.max(ev.cost[judged]))
        members_idx = np.nonzero(sel)[0]
        worst["worst_plant"] = int(np.argmax(np.where(judged, ev.cost, -np.inf)[sel]))
        worst["plants_faulted"] = int(np.sum(faulted))
        worst["plants_faulted_list"] = [int(k) for k in np.nonzero(faulted[members_idx])[0]]
        out[label] = worst
    return out


def robust_table(worst: Mapping[str, Mapping[str, Any]]) -> str:
    """Markdown table of the worst cases over the plants that did not fault, which plant
    gave the worst cost (0 = nominal, then the corners in ``itertools.product`` order of
    :data:`SPREAD`) and how many plants faulted."""
    cols = [t for t in TERMS if t != "fault"] + ["cost", "worst_plant", "plants_faulted"]
    rows = ["| gains | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for label, w in worst.items():
        rows.append(f"| {label} | " + " | ".join(f"{w[c]:.4g}" for c in cols) + " |")
    lists = {label: w["plants_faulted_list"] for label, w in worst.items()}
    if any(lists.values()):
        rows.append("")
        for label, plants in lists.items():
            rows.append(f"- {label}: faulted on plants {plants or 'none'}")
    return "\n".join(rows)
