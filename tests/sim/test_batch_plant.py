"""BatchPlant's fast paths against the plain rules: the end-state modes read from the signs
of the fused step's boundary columns, and the lock-step location of many mode switches."""

from __future__ import annotations

import numpy as np

from sim.params import PlantParams
from sim.plant import _KEY_OF_SIGNS, _SIGN_WEIGHTS, N_X, BatchPlant, ScalarPlant, mode_keys

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
