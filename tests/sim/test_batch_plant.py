"""BatchPlant's fast paths against the plain rules: the end-state modes read from the signs
of the fused step's boundary columns, the location of many mode switches against the scalar
plant, and the compiled location against the numpy lock-step it replaced (bit for bit)."""

from __future__ import annotations

import numpy as np

from sim.params import PlantParams
from sim.plant import (
    _KEY_OF_SIGNS,
    _SIGN_WEIGHTS,
    B_DIODE_NEG,
    B_DIODE_POS,
    B_LIMIT_NEG,
    B_LIMIT_POS,
    I_A,
    N_X,
    BatchPlant,
    ScalarPlant,
    _mode_key_one,
    mode_keys,
)

DT_S = 0.002


def test_boundary_signs_give_the_mode_keys():
    params = PlantParams()
    n = 4000
    plant = BatchPlant(params, n, DT_S)
    rng = np.random.default_rng(7)
    x = rng.normal(size=(n, N_X)) * np.array([30.0, 1.0, 0.2, 1e-3, 3e-3])
    x[::5, 0] = rng.choice([-80.0, 80.0], size=x[::5].shape[0])  # some beyond I_CL
    duty = rng.uniform(-1, 1, n)
    enable = np.ones(n, dtype=bool)
    keys = mode_keys(x, duty, enable, plant.co)
    c, c0 = plant._boundaries
    signs = _KEY_OF_SIGNS[((x @ c + c0 > 0.0) @ _SIGN_WEIGHTS).astype(np.intp)]
    at_limit = np.abs(x[:, 0]) >= plant.co.icl
    assert np.all(signs[at_limit] == -1)
    np.testing.assert_array_equal(signs[~at_limit], keys[~at_limit])
    assert len(set(keys[~at_limit].tolist())) > 20


def test_many_members_switching_together_follow_the_scalar_plant():
    # 64 members cross friction bands, the backlash gap and the power flow together (more
    # than the scalar hand-off threshold): the lock-step location must give what 64
    # ScalarPlants give, sub-step for sub-step.
    params = PlantParams()
    n = 64
    rng = np.random.default_rng(3)
    duties = rng.uniform(-0.9, 0.9, n)
    batch = BatchPlant(params, n, DT_S)
    scalars = [ScalarPlant(params, DT_S) for _ in range(n)]
    for p in scalars:
        p.check_excursions = False  # batch semantics
    x = np.zeros((n, N_X))
    xs = [[0.0] * N_X for _ in range(n)]
    for k in range(300):
        sign = 1.0 if (k // 60) % 2 == 0 else -1.0
        x = batch.update(k * DT_S, x, (sign * duties, True))
        for j in range(n):
            xs[j] = scalars[j].update(k * DT_S, xs[j], (sign * float(duties[j]), True))
    assert batch.n_located > 100
    np.testing.assert_allclose(x, np.array(xs), rtol=1e-9, atol=1e-9)


def _locate_numpy(plant, x, duty, enable, keys):
    """The lock-step numpy location that ``_locate_members`` replaced (the oracle)."""
    co = plant.co
    levels = plant.event_levels
    full = 1 << levels
    m = x.shape[0]
    x = x.copy()
    done = np.zeros(m, dtype=np.int64)  # time taken, in units of h / 2**levels
    level = np.ones(m, dtype=np.int64)  # the whole step (level 0) switched: halve
    budget = np.full(m, plant.split_budget - 1, dtype=np.int64)
    key = keys.copy()
    live = np.arange(m)
    while live.size:
        lv = level[live]
        k0 = key[live]
        d, e = duty[live], enable[live]
        xa = np.empty((live.size, N_X + 2))
        xa[:, :N_X] = x[live]
        xa[:, N_X] = d
        xa[:, N_X + 1] = 1.0
        slots = k0 * 64 + lv
        plant._load_slots(slots)
        out = np.einsum("nj,nji->ni", xa, plant._stack[plant._slot_row[slots]])
        xn = out[:, :N_X]
        # End modes from the boundary signs (as in update); mode_keys where the bridge
        # is off or a current reached I_CL.
        k1 = _KEY_OF_SIGNS[((out[:, N_X + 2 :] > 0.0) @ _SIGN_WEIGHTS).astype(np.intp)]
        other = (k1 < 0) | ~e
        if other.any():
            k1[other] = mode_keys(xn[other], d[other], e[other], co)
        switched = k1 != k0
        final = (lv >= levels) | (budget[live] <= 0)
        halve = switched & ~final
        if halve.any():
            j = live[halve]
            budget[j] -= 1
            level[j] += 1
        take = ~halve
        located = switched & final
        if located.any():
            # Located to h / 2**levels: accept, as ScalarPlant._advance does. A current
            # freewheeling through a diode stops at zero; one that reached the chip's
            # limitation is held at I_CL. The next sub-step starts in the mode of the
            # projected state.
            plant.n_located += int(located.sum())
            i = xn[:, I_A]
            b0, b1 = k0 // 54, k1 // 54
            blocked = ((b0 == B_DIODE_POS) & (i < 0)) | ((b0 == B_DIODE_NEG) & (i > 0))
            xn[located & blocked, I_A] = 0.0
            xn[located & (b1 == B_LIMIT_POS) & (i > co.icl), I_A] = co.icl
            xn[located & (b1 == B_LIMIT_NEG) & (i < -co.icl), I_A] = -co.icl
            k1[located] = mode_keys(xn[located], d[located], e[located], co)
        j = live[take]
        x[j] = xn[take]
        key[j] = k1[take]
        now = done[j] + (full >> lv[take])
        done[j] = now
        # Next: the longest aligned sub-step from the new time (its lowest set bit).
        low = now & -now
        level[j] = levels - (np.frexp(low.astype(float))[1] - 1)
        live = live[done[live] < full]
    return x


def test_mode_key_of_one_member_is_mode_keys():
    params = PlantParams()
    plant = BatchPlant(params, 1, DT_S)
    rng = np.random.default_rng(11)
    n = 20000
    x = rng.normal(size=(n, N_X)) * np.array([30.0, 1.0, 0.2, 1e-3, 3e-3])
    x[::5, 0] = rng.choice([-80.0, 80.0], size=x[::5].shape[0])  # beyond I_CL
    x[::7, 0] = 0.0  # no current: open bridge or diodes by the back-emf
    x[::11, 2] = rng.choice([-1.0, 1.0], size=x[::11].shape[0]) * 3000.0
    duty = rng.uniform(-1, 1, n)
    enable = rng.random(n) < 0.7
    keys = mode_keys(x, duty, enable, plant.co)
    one = [
        _mode_key_one(*x[j, [0, 2, 3, 4]], duty[j], enable[j], plant._key_consts) for j in range(n)
    ]
    np.testing.assert_array_equal(one, keys)
    assert len(set(keys.tolist())) > 60


def test_compiled_location_gives_the_numpy_lock_step_bit_for_bit():
    params = PlantParams()
    n = 300
    rng = np.random.default_rng(5)
    x = rng.normal(size=(n, N_X)) * np.array([10.0, 1.0, 30.0, 4e-3, 0.2])
    x[::4, 0] = (
        rng.choice([-1.0, 1.0], size=x[::4].shape[0]) * 0.999 * PlantParams().bridge.current_limit_a
    )
    x[::9, 2] = 0.0
    duty = rng.uniform(-1, 1, n)
    enable = rng.random(n) < 0.8
    fast, slow = BatchPlant(params, n, DT_S), BatchPlant(params, n, DT_S)
    keys = mode_keys(x, duty, enable, fast.co)
    got = fast._locate(x, duty, enable, keys)
    want = _locate_numpy(slow, x, duty, enable, keys)
    assert got.tobytes() == want.tobytes()
    assert fast.n_located == slow.n_located > 50
