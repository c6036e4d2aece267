"""The compiled plant step (sim.plant_kernel) against its recursive definition.

``plant_kernel.step`` walks the dyadic sub-steps with an explicit stack (a bit mask of the
pending levels); the recursion below is how the step was written in Python before it was
compiled (the same rules, written as the docstring of ``Plant.update`` states them). Both
must give the same floats, bit for bit, including the halving budget, the located switches
and their projections (diode blocking, I_CL).
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim import plant as sim_plant
from sim import plant_kernel
from sim.params import PlantParams
from sim.plant import (
    B_DIODE_NEG,
    B_DIODE_POS,
    B_LIMIT_NEG,
    B_LIMIT_POS,
    B_ON,
    MECH_MODES,
    N_X,
    Plant,
)  # fmt: skip

DT_S = 0.002


class _Recursion:
    """The Python recursion, on a plant's tables: (state, n_events, end key)."""

    def __init__(self, plant: Plant) -> None:
        self.plant = plant
        self.n_events = 0
        self.end_key = -1
        self.splits = 0

    def step(self, x: list[float], d: float, en: bool) -> list[float]:
        self.splits = self.plant.split_budget
        return self._advance(x, d, en, self.plant.key(x, d, en), 0)

    def _advance(self, x, d, en, key, level):
        p = self.plant
        rows = p.phi(key, level)
        i, pos, w, tw, wp = x
        # The kernel's order of additions: ((((r0 i + r2 w) + r3 tw) + r4 wp) + r5 d) + r6,
        # with pos added first for the angle.
        xn = [
            rows[r][0] * i + rows[r][2] * w + rows[r][3] * tw + rows[r][4] * wp
            + rows[r][5] * d + rows[r][6]
            for r in range(N_X)
        ]  # fmt: skip
        r1 = rows[1]
        xn[1] = pos + r1[0] * i + r1[2] * w + r1[3] * tw + r1[4] * wp + r1[5] * d + r1[6]
        key_end = p.key(xn, d, en)
        self.end_key = key_end
        h = p.h_s / (1 << level)
        icl = p.co.icl
        on = key // MECH_MODES == B_ON
        crossed = on and -icl <= x[0] <= icl and abs(xn[0]) > icl
        if (
            key_end == key
            and not crossed
            and (
                level >= p.event_levels or self.splits <= 0 or not self._excursion(x, xn, d, key, h)
            )
        ):
            return xn
        if level >= p.event_levels or self.splits <= 0:
            self.n_events += 1
            bridge = key // MECH_MODES
            if (bridge == B_DIODE_POS and xn[0] < 0) or (bridge == B_DIODE_NEG and xn[0] > 0):
                xn[0] = 0.0
            limit = key_end // MECH_MODES
            if xn[0] > icl and (limit == B_LIMIT_POS or (on and x[0] <= icl)):
                xn[0] = icl
            elif xn[0] < -icl and (limit == B_LIMIT_NEG or (on and x[0] >= -icl)):
                xn[0] = -icl
            if (x[2] > 0 and xn[2] <= 0) or (x[2] < 0 and xn[2] >= 0):
                kc = p._consts[0]
                tb = plant_kernel._belt_torque(xn[3], xn[2] / p.co.n - xn[4], kc)
                if (
                    tb != 0.0
                    and plant_kernel._flow_at_rest(p.co.kt * xn[0], tb, p.co.n, p.co.eta)
                    == plant_kernel._F_STUCK
                ):
                    xn[2] = 0.0
            self.end_key = p.key(xn, d, en)
            return xn
        self.splits -= 1
        half = self._advance(x, d, en, key, level + 1)
        return self._advance(half, d, en, p.key(half, d, en), level + 1)

    def _excursion(self, x, xn, d, key, h):
        p = self.plant
        if p._slots[0, key] < 0:
            p._load(0, key)
        row = p._slots[0, key]
        i0, _, w0, t0, p0 = x
        i1, _, w1, t1, p1 = xn
        on = key // MECH_MODES == B_ON
        return plant_kernel._excursion(
            i0, w0, t0, p0, i1, w1, t1, p1, d, on, p._rates, row, h, p._consts[0]
        )


def _states(draw_scale: float, rng: np.random.Generator, n: int) -> np.ndarray:
    """States near the model's boundaries: friction bands, backlash gap, I_CL."""
    co = Plant(PlantParams(), 1, DT_S).co
    x = np.zeros((n, N_X))
    x[:, 0] = rng.choice([-1.0, 1.0], n) * rng.uniform(0, 1.1 * co.icl, n) * draw_scale
    x[:, 1] = rng.uniform(-100, 100, n)
    x[:, 2] = rng.normal(0, 3 * co.wbm, n) + rng.choice([0.0, 50.0, -50.0], n)
    x[:, 3] = rng.uniform(-2.5 * co.half, 2.5 * co.half, n)
    x[:, 4] = rng.normal(0, 3 * co.wbp, n)
    return x


def _one(plant: Plant, x: list[float], d: float, en: bool) -> list[float]:
    """One member's step through ``Plant.update`` (a batch of one)."""
    return plant.update(0.0, np.array([x]), (d, en))[0].tolist()


@pytest.mark.parametrize("levels", [0, 3, 20])
def test_compiled_step_is_the_recursion_bit_for_bit(levels):
    rng = np.random.default_rng(levels * 2)
    plant = Plant(PlantParams(), 1, DT_S, event_levels=levels)
    oracle = _Recursion(plant)
    events = 0
    for x in _states(1.0, rng, 400):
        d = float(rng.choice([rng.uniform(-1, 1), 0.0, 1.0, -1.0]))
        en = bool(rng.random() < 0.8)
        before = plant.n_events
        got = _one(plant, x.tolist(), d, en)
        oracle.n_events = 0
        want = oracle.step(x.tolist(), d, en)
        assert list(got) == want, (x.tolist(), d, en)
        assert plant.n_events - before == oracle.n_events
        assert plant._last_mech[0] == oracle.end_key % MECH_MODES
        events += oracle.n_events
    if levels:
        assert events > 10  # the located-switch branch ran


def test_a_tiny_budget_is_spent_as_the_recursion_spends_it():
    plant = Plant(PlantParams(), 1, DT_S, event_levels=20)
    plant.split_budget = 3
    oracle = _Recursion(plant)
    rng = np.random.default_rng(7)
    for x in _states(1.0, rng, 200):
        got = _one(plant, x.tolist(), 0.3, True)
        assert list(got) == oracle.step(x.tolist(), 0.3, True)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=1, max_size=40),
    st.booleans(),
)
def test_a_fresh_plant_loads_modes_as_it_meets_them(duties, enable):
    # The kernel reports a mode it has no matrices for; update() loads it and steps again.
    # A plant that starts empty must give what a plant that has every mode loaded gives.
    warm = Plant(PlantParams(), 1, DT_S, event_levels=6)
    for key in range(warm._slots.shape[1]):
        warm._load(0, key)
    # Forget the matrices plants share, or the cold plant would start with warm's modes.
    sim_plant._MODE_TABLES.clear()
    cold = Plant(PlantParams(), 1, DT_S, event_levels=6)
    assert cold._n_loaded == 0
    xw = xc = np.array([[2.0, 0.0, 30.0, 0.0, 0.0]])
    for d in duties:
        xw = warm.update(0.0, xw, (d, enable))
        xc = cold.update(0.0, xc, (d, enable))
        np.testing.assert_array_equal(xw, xc)
    assert 0 < cold._n_loaded <= len(duties) * (2 * 6 + 2)


def test_plants_keep_their_rows_when_the_shared_store_is_replaced(monkeypatch):
    # The shared rows are bounded: past _STORE_MAX_ROWS a new store starts. A plant made
    # before keeps its store, finds its modes there and adds the ones it meets later to it;
    # a plant made after starts empty in the new one. Both step as a plant alone does.
    monkeypatch.setattr(sim_plant, "_STORES", {})
    monkeypatch.setattr(sim_plant, "_MODE_TABLES", {})
    duties = [0.5, -1.0, 0.2, -1.0, 0.0, 0.0, 0.0]  # modes met at 0.2, -1.0 and 0.0
    x0 = np.array([[2.0, 0.0, 30.0, 0.0, 0.0]])

    def steps(plant: Plant, ds: list[float], x: np.ndarray) -> list[np.ndarray]:
        xs = []
        for d in ds:
            x = plant.update(0.0, x, (d, True))
            xs.append(x)
        return xs

    early = Plant(PlantParams(), 1, DT_S)
    xs_early = steps(early, duties[:3], x0)
    old_store = early._store
    met = old_store.used
    monkeypatch.setattr(sim_plant, "_STORE_MAX_ROWS", met)  # full: the next plant starts anew
    late = Plant(PlantParams(), 1, DT_S)
    assert late._store is not old_store and late._n_loaded == 0
    xs_late = steps(late, duties, x0)
    xs_early += steps(early, duties[3:], xs_early[-1])
    assert early._store is old_store and old_store.used > met  # its new modes, in its store
    monkeypatch.setattr(sim_plant, "_STORE_MAX_ROWS", 8192)
    alone = steps(Plant(PlantParams(), 1, DT_S), duties, x0)
    for a, b, c in zip(xs_early, xs_late, alone, strict=True):
        assert np.array_equal(a, c) and np.array_equal(b, c)


def test_plants_in_threads_share_the_store(monkeypatch):
    # Runs may share a process (a server's threads): plants made and stepped in several
    # threads at once, the store replaced again and again (a bound of a few rows), step as
    # a plant alone does, and nothing raises.
    import threading

    monkeypatch.setattr(sim_plant, "_STORES", {})
    monkeypatch.setattr(sim_plant, "_MODE_TABLES", {})
    monkeypatch.setattr(sim_plant, "_BATCH_SETS", {})
    duties = [0.5, -1.0, 0.2, -1.0, 0.0, 0.0, 0.0, 0.7, -0.4]
    x0 = np.array([[2.0, 0.0, 30.0, 0.0, 0.0]])

    def steps() -> np.ndarray:
        plant = Plant(PlantParams(), 1, DT_S)
        x = x0
        for d in duties:
            x = plant.update(0.0, x, (d, True))
        return x

    alone = steps()
    monkeypatch.setattr(sim_plant, "_STORE_MAX_ROWS", 3)
    results: list[np.ndarray] = []
    errors: list[BaseException] = []

    def worker() -> None:
        try:
            for _ in range(5):
                results.append(steps())
        except BaseException as exc:  # reported below, not lost in the thread
            errors.append(exc)

    threads = [threading.Thread(target=worker) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors and len(results) == 20
    for x in results:
        assert np.array_equal(x, alone)


def test_a_batch_s_sets_are_found_once_and_not_across_stores(monkeypatch):
    # A Monte-Carlo batch's sets and their tables are kept by the batch's coefficients: a
    # second plant of the same batch gets the same objects (and every mode the first met);
    # another batch does not; once the shared store is replaced, not the old tables either.
    monkeypatch.setattr(sim_plant, "_STORES", {})
    monkeypatch.setattr(sim_plant, "_MODE_TABLES", {})
    monkeypatch.setattr(sim_plant, "_BATCH_SETS", {})
    n = 20
    params = _params(n, per_member=True)
    x0 = np.tile(_RUNNING, (n, 1))
    d, en = np.full(n, _RUNNING_DUTY), np.ones(n, dtype=bool)
    first = Plant(params, n, DT_S)
    x_first = first.update(0.0, first.update(0.0, x0, (d, en)), (d, en))
    second = Plant(params, n, DT_S)
    assert all(a is b for a, b in zip(second._sets, first._sets, strict=True))
    assert second._n_loaded == first._n_loaded > 0
    other = dataclasses.replace(params, motor=dataclasses.replace(params.motor, r_ohm=1.3))
    assert Plant(other, n, DT_S)._sets[0] is not first._sets[0]
    x_second = second.update(0.0, second.update(0.0, x0, (d, en)), (d, en))
    assert np.array_equal(x_first, x_second)
    monkeypatch.setattr(sim_plant, "_STORE_MAX_ROWS", first._store.used)  # full: a new one
    third = Plant(params, n, DT_S)
    assert third._store is not first._store and third._n_loaded == 0
    kept = [tables for sets, tables in sim_plant._BATCH_SETS.values() if sets[0] is third._sets[0]]
    assert len(kept) == 1 and all(t.store is third._store for t in kept[0])
    x_third = third.update(0.0, third.update(0.0, x0, (d, en)), (d, en))
    assert np.array_equal(x_first, x_third)


def test_plants_with_the_same_coefficients_share_the_modes_met():
    # A second plant with the same coefficients starts with every mode the first loaded (its
    # compiled step does not stop for them), the same numbers; other coefficients do not.
    sim_plant._MODE_TABLES.clear()
    first = Plant(PlantParams(), 1, DT_S)
    x = np.array([[2.0, 0.0, 30.0, 0.0, 0.0]])
    xs = [x]
    for d in (0.5, -1.0, 0.0, 1.0):
        xs.append(first.update(0.0, xs[-1], (d, True)))
    assert first._n_loaded > 0
    second = Plant(PlantParams(), 1, DT_S)
    assert second._n_loaded == first._n_loaded
    for key in np.flatnonzero(first._slots[0] >= 0):
        np.testing.assert_array_equal(second.phi(key, 3), first.phi(key, 3))
    assert second._n_loaded == first._n_loaded  # phi() found every mode loaded
    y = x
    for d, want in zip((0.5, -1.0, 0.0, 1.0), xs[1:], strict=True):
        y = second.update(0.0, y, (d, True))
        np.testing.assert_array_equal(y, want)
    other = dataclasses.replace(PlantParams(), motor=dataclasses.replace(
        PlantParams().motor, r_ohm=2 * PlantParams().motor.r_ohm))  # fmt: skip
    assert Plant(other, 1, DT_S)._n_loaded == 0


def test_consts_follow_the_coefficients():
    plant = Plant(PlantParams(), 1, DT_S)
    co = dataclasses.asdict(plant.co)
    kc = plant._consts[0]
    assert plant._consts.shape == (1, plant_kernel.N_CONSTS)
    assert kc[plant_kernel._ICL] == co["icl"] and kc[plant_kernel._INV_N] == co["inv_n"]
    assert kc[plant_kernel._JP] == co["jp"] and kc[plant_kernel._H_S] == DT_S


def test_warm_up_loads_the_signatures_the_plant_calls():
    # In a fresh interpreter (other tests may have called the kernels with other types):
    # one specialisation each after warm_up and a plant step, so what warm_up loaded is what
    # a run uses (a second one would be compiled, ~1.5 s, inside the timed run).
    code = """
from sim import plant_kernel
from sim.params import PlantParams
import numpy as np
from sim.plant import Plant
plant_kernel.warm_up(20)
plant = Plant(PlantParams(), 1, 0.002, event_levels=20)
x = plant.update(0.0, np.zeros((1, 5)), (np.array([0.5]), np.array([True])))
x = plant.update(0.0, x, (np.array([0.5]), np.array([True])))
plant.key(x[0], 0.5, True)
print(len(plant_kernel.step_members.signatures), len(plant_kernel.key.signatures))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["1", "1"]


_MAGNITUDE = st.floats(-12.0, 6.0).map(lambda e: 10.0**e)


@settings(max_examples=300, deadline=None)
@given(
    wmax=_MAGNITUDE, ai=_MAGNITUDE, tbmax=_MAGNITUDE, apmax=_MAGNITUDE, level=st.integers(0, 20),
    scale=st.lists(st.floats(0.05, 20.0), min_size=6, max_size=6), stiction=st.booleans(),
)  # fmt: skip
def test_the_excursion_gates_quick_bounds_are_never_below_the_gates(
    wmax, ai, tbmax, apmax, level, scale, stiction
):
    # _excursion skips its exact gates (two divisions in a row) when both speeds are beyond
    # the bounds: bit-identical only if a bound is never below its gate, whatever the
    # rounding (R, Ke, Kt, J_m, J_p, supply scaled; with and without stiction).
    r, ke, kt, jm, jp, vs = scale
    base = PlantParams()
    motor = dataclasses.replace(
        base.motor, r_ohm=1.2 * r, ke_v_s_rad=0.0145 * ke, kt_nm_a=0.0145 * kt,
        stiction_nm=0.006 if stiction else 0.0, stribeck_rad_s=0.5 if stiction else 0.0,
    )  # fmt: skip
    params = dataclasses.replace(base, motor=motor)
    co = Plant(params, 1, DT_S).co
    co = dataclasses.replace(co, jm=co.jm * jm, jp=co.jp * jp, vs=co.vs * vs)
    kc = plant_kernel.pack_consts(co, DT_S)
    h = DT_S / (1 << level)
    gates = plant_kernel.gates.py_func(wmax, ai, tbmax, apmax, h, kc)
    bounds = plant_kernel.gate_bounds.py_func(wmax, ai, tbmax, apmax, h, kc)
    assert bounds[0] >= gates[0] and bounds[1] >= gates[1]


# A member of a 32-member Fig. 8 batch 0.4 s into its move (i, angle, w_m, twist, w_p) and
# its duty: accelerating in one mode, every boundary apart (the sweep accepts it).
_RUNNING = np.array([0.6424, 16.37, 82.31, 0.0010154, 0.2061])
_RUNNING_DUTY = 0.0822


def _steps(plant: Plant, x0: np.ndarray, duty: np.ndarray, enable: np.ndarray):
    """Three steps from ``x0`` (the later ones with the modes known, as a run's are: the
    second fills the sweep's coefficient rows, the third finds most of them filled)."""
    x = plant.update(0.0, x0, (duty, enable))
    x = plant.update(0.0, x, (duty, enable))
    return plant.update(0.0, x, (duty, enable)), plant._last_mech.copy(), plant.n_events


def _done(plant: Plant) -> np.ndarray:
    """Whether the last step's sweep accepted each member (its scratch's row ``_DONE``)."""
    lanes = plant_kernel._LANES
    rows = plant._scratch[:, plant_kernel._DONE * lanes : (plant_kernel._DONE + 1) * lanes]
    return rows.ravel()[: plant.n]


def _params(n: int, per_member: bool) -> PlantParams:
    """The paper's plant, or with the motor's R per member (a Monte-Carlo batch: a
    parameter set per member)."""
    p = PlantParams()
    if per_member:
        r = np.linspace(1.0, 1.6, n)
        p = dataclasses.replace(p, motor=dataclasses.replace(p.motor, r_ohm=r))
    return p


@settings(max_examples=60, deadline=None)
@given(
    spread=st.floats(0.0, 1.0), seed=st.integers(0, 2**32 - 1), off=st.integers(0, 8),
    duty=st.floats(-0.2, 0.4), gap=st.booleans(), per_member=st.booleans(),
    n=st.sampled_from([40, 70, 130]),
)  # fmt: skip
def test_the_sweep_of_a_batch_is_the_member_loop_bit_for_bit(
    spread, seed, off, duty, gap, per_member, n
):
    # step_members sweeps the common case of a batch (_sweep, each member in its known mode
    # from its coefficient rows); the member loop alone (no scratch) must give the same
    # floats, end modes and event counts: members around one state, some in other modes
    # (spread, a belt in its gap, bridges disabled), some at rest; one parameter set or one
    # per member; one scratch block or several, the last one partly used.
    rng = np.random.default_rng(seed)
    x0 = _RUNNING + spread * rng.standard_normal((n, N_X)) * np.array([1.0, 1.0, 20.0, 1e-4, 0.1])
    if gap:  # a belt in its backlash gap
        x0[: n // 4, 3] = 0.0
    x0[rng.random(n) < 0.1, 2] = 0.0
    d = np.clip(duty + 0.1 * spread * rng.standard_normal(n), -1.0, 1.0)
    en = np.ones(n, dtype=bool)
    en[:off] = False
    swept = Plant(_params(n, per_member), n, DT_S)
    alone = Plant(_params(n, per_member), n, DT_S)
    alone._scratch = plant_kernel.sweep_scratch(0)
    xs, ks, es = _steps(swept, x0, d, en)
    xa, ka, ea = _steps(alone, x0, d, en)
    assert np.array_equal(xs.view(np.int64), xa.view(np.int64))
    assert np.array_equal(ks, ka) and es == ea


@pytest.mark.parametrize("per_member", [False, True])
def test_the_sweep_takes_the_members_in_a_known_mode(per_member):
    # The sweep is exercised (not skipped): members in one mode away from every edge are
    # all accepted by it, with a parameter set per member too.
    n = 70
    plant = Plant(_params(n, per_member), n, DT_S)
    x0 = _RUNNING + 1e-6 * np.arange(n)[:, None]
    _steps(plant, x0, np.full(n, _RUNNING_DUTY), np.ones(n, dtype=bool))
    assert plant_kernel.SWEEP_MIN <= n
    assert np.all(_done(plant) == 1.0)
    small = Plant(PlantParams(), plant_kernel.SWEEP_MIN - 1, DT_S)
    assert small._scratch.shape[0] == 0


def test_a_member_s_rows_follow_its_parameter_set():
    # The rows kept between steps are those of the member's set and mode: sim.thermal
    # moves a member to another set between steps, and the sweep then takes the new set's
    # coefficients (as the member loop alone does), not the rows it kept.
    n = 32
    base = PlantParams()
    hot = dataclasses.replace(base, motor=dataclasses.replace(base.motor, r_ohm=1.5))
    x0 = _RUNNING + 1e-6 * np.arange(n)[:, None]
    d, en = np.full(n, _RUNNING_DUTY), np.ones(n, dtype=bool)

    def third(sweep: bool, move: bool) -> np.ndarray:
        plant = Plant(base, n, DT_S)
        if not sweep:
            plant._scratch = plant_kernel.sweep_scratch(0)
        g = plant.add_group(sim_plant.Coefficients.from_params(hot))
        x = plant.update(0.0, plant.update(0.0, x0, (d, en)), (d, en))
        if move:
            plant._group[::2] = g
        x = plant.update(0.0, x, (d, en))
        if sweep:
            assert np.all(_done(plant) == 1.0)
        return x

    moved = third(True, True)
    assert np.array_equal(moved.view(np.int64), third(False, True).view(np.int64))
    assert not np.array_equal(moved[::2], third(True, False)[::2])


_CONFIGS = Path(__file__).resolve().parents[2] / "bench_configs"


@pytest.mark.parametrize(
    "name, config, batch, overrides",
    [
        # the tuner's batch: gains per member, the plant shared; encoder noise on
        ("gains", "fig8.toml", 24, {"controller.position.kp_per_s": list(np.linspace(8, 40, 24)),
                                    "encoder.noise_rms_lsb": 2.0}),
        # the bus model's exact period and its sub-steps (sim.supply.step_period), braking
        ("bus", "fig6.toml", 20, {"supply.bus_model": True}),
        # a Monte-Carlo batch: the motor's R per member (a parameter set per member)
        ("spread", "fig8.toml", 24, {"motor.r_ohm": list(np.linspace(1.0, 1.6, 24)),
                                     "encoder.noise_rms_lsb": 2.0}),
        # the winding's heat: members move to other parameter sets as they warm
        ("heat", "fig8.toml", 20, {"thermal.model": True,
                                   "motor.r_ohm": list(np.linspace(1.0, 1.4, 20))}),
    ],
)  # fmt: skip
def test_runs_with_and_without_the_sweep_are_the_same(monkeypatch, name, config, batch, overrides):
    # Whole runs through the compiled tick: the plant's sweep (a batch of SWEEP_MIN or more
    # members) changes no bit of the log nor of the PC's bytes.
    from sim.config import load_experiment
    from sim.loop import LOG_FIELDS, run

    exp = load_experiment(_CONFIGS / config)
    exp = dataclasses.replace(exp, duration_s=min(exp.duration_s, 0.6))
    swept = run(exp, batch=batch, overrides=overrides)
    monkeypatch.setattr(plant_kernel, "SWEEP_MIN", 10**9)  # Plant's scratch: no block
    alone = run(exp, batch=batch, overrides=overrides)
    for f in LOG_FIELDS:
        np.testing.assert_array_equal(getattr(swept.log, f), getattr(alone.log, f), err_msg=f)
    assert swept.pc_bytes == alone.pc_bytes and swept.firmware_counters == alone.firmware_counters
    assert np.ptp(swept.log.motor_pos_rad) > 1.0  # the axis moved
