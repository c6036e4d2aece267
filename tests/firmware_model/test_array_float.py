"""The compiled float64 batch law (``firmware_model/laws/array_float.py``) against
``ScalarLaw`` member by member, bit for bit: per-member gains, random readings, clamps, the
regenerative clamp, disabled members, limits changing on the way."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from firmware_model.laws import ArrayLaw, ScalarLaw
from firmware_model.params import (
    CurrentLoopGains,
    FirmwareParams,
    PositionLoopGains,
    ServoParams,
    VelocityLoopGains,
)

N = 6
PUBLIC = (
    "count",
    "pos_deg",
    "vel_dps",
    "vel_raw_dps",
    "innovation_counts",
    "stuck_ticks",
    "vel_ref_dps",
    "current_ref_a",
    "current_meas_a",
    "duty",
)
PRIVATE = ("_ep", "_v", "_ad", "_i_v", "_i_i", "_ref_d_last")


def _params(delay: int) -> tuple[FirmwareParams, list[FirmwareParams]]:
    """Gains that differ per member (two of them scalar), and each member's scalar params."""
    rng = np.random.default_rng(delay)

    def spread(value: float) -> np.ndarray:
        return value * rng.uniform(0.5, 2.0, N)

    base = FirmwareParams(servo=ServoParams(compute_delay_ticks=delay))
    cur, vel, pos = base.current, base.velocity, base.position
    params = dataclasses.replace(
        base,
        current=dataclasses.replace(
            cur,
            kp_v_per_a=spread(cur.kp_v_per_a),
            ki_v_per_as=spread(cur.ki_v_per_as),
            back_emf_v_per_dps=spread(cur.back_emf_v_per_dps),
        ),
        velocity=VelocityLoopGains(
            kp_a_per_dps=spread(vel.kp_a_per_dps),
            ki_a_per_deg=spread(vel.ki_a_per_deg),
            acc_ff_a_per_dps2=vel.acc_ff_a_per_dps2,
        ),
        position=PositionLoopGains(kp_per_s=spread(pos.kp_per_s), vel_ff=pos.vel_ff),
    )

    def member(part: object, k: int) -> object:
        values = {
            f.name: float(v[k]) if isinstance(v := getattr(part, f.name), np.ndarray) else v
            for f in dataclasses.fields(part)
        }
        return dataclasses.replace(part, **values)

    members = [
        dataclasses.replace(
            params,
            current=member(params.current, k),
            velocity=member(params.velocity, k),
            position=member(params.position, k),
        )
        for k in range(N)
    ]
    assert isinstance(params.current, CurrentLoopGains)
    return params, members


def _assert_members_equal(batch: ArrayLaw, scalars: list[ScalarLaw], names: tuple[str, ...]):
    for name in names:
        got = np.asarray(getattr(batch, name))
        want = np.array([getattr(s, name) for s in scalars], dtype=got.dtype)
        # Bit for bit (also the sign of zeros): compare the raw bytes.
        assert got.tobytes() == want.tobytes(), (name, got, want)


@pytest.mark.parametrize("delay", [0, 1, 2])
def test_compiled_batch_law_matches_scalar_law_per_member_bit_for_bit(delay):
    params, members = _params(delay)
    batch = ArrayLaw(params, N)
    scalars = [ScalarLaw(p) for p in members]
    rng = np.random.default_rng(100 + delay)
    start = rng.integers(0, 16384, N)
    batch.reset(start)
    for s, c in zip(scalars, batch.count, strict=True):
        s.reset(int(c))
    x = batch.count.astype(float)
    speed = rng.uniform(-4000.0, 4000.0, N)  # up to ~1200 deg/s: the clamps act
    clamps = dict.fromkeys(("current_ref", "vel_ref", "duty", "regen", "disabled"), 0)
    published: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for k in range(600):
        x += speed * math.sin(2 * math.pi * k / 300) + rng.normal(0.0, 1.5, N)
        raw = np.floor(x).astype(np.int64) % 16384
        if k % 97 == 50:
            raw[k % N] = (raw[k % N] + 5000) % 16384  # a glitch: a large innovation
        if k % 41 == 7:
            raw[:2] = batch._raw_prev[:2]  # a stuck reading
        batch.estimate(raw)
        for s, r in zip(scalars, raw.tolist(), strict=True):
            s.estimate(r)
        _assert_members_equal(batch, scalars, PUBLIC + ("_ep", "_v", "_ad"))
        sp = (
            float(batch.pos_deg[0]) + 80.0 * math.sin(k / 23.0),
            300.0 * math.cos(k / 30.0),
            -50.0 * math.sin(k / 30.0),
        )
        v_clamp = 990.0 if k % 150 < 100 else 200.0
        i_limit = 5.0 if k % 200 < 120 else 2.5  # also changes the regenerative bound
        batch.servo(*sp, v_clamp, i_limit)
        for s in scalars:
            s.servo(*sp, v_clamp, i_limit)
        if k % 10 == 0 and k > 50:  # a stale integrator against the motion
            stale = -3.0 * np.sign(speed)
            batch._i_i[:] = stale
            for s, v in zip(scalars, stale.tolist(), strict=True):
                s._i_i = v
        adc = rng.integers(0, 900, N)
        adc[rng.random(N) < 0.4] = rng.integers(0, 3)  # at or below the sense floor: blind
        enabled = rng.random(N) > 0.05
        # The regenerative clamp's condition on the voltage the PI asks for (ScalarLaw.current).
        ref_d = batch._ref_pipe[batch._ref_i]
        i_meas = adc * params.current.a_per_adc * np.sign(batch._steps)
        blind = (adc <= params.current.sense_floor_counts) & (np.sign(ref_d * batch._steps) <= 0)
        e = ref_d - np.where(blind, ref_d, i_meas)
        u = e * batch._kp_i + batch._i_i + batch._iref * batch._r_ff + batch._vel * batch._emf_ff
        d = u - batch._vel * batch._emf_ff
        clamps["regen"] += int(np.sum(enabled & (np.abs(d) > batch._r_lim) & (d * u <= 0.0)))
        duty = batch.current(adc, enabled)
        got = [s.current(int(a), bool(e)) for s, a, e in zip(scalars, adc, enabled, strict=True)]
        assert duty.tobytes() == np.array(got).tobytes()
        _assert_members_equal(batch, scalars, PUBLIC + PRIVATE)
        # What the firmware published last tick (Firmware.signals) never changes afterwards.
        for name, (value, copy) in published.items():
            assert value.tobytes() == copy.tobytes(), name
        published = {name: (getattr(batch, name), getattr(batch, name).copy()) for name in PUBLIC}
        clamps["current_ref"] += int(np.sum(np.abs(batch.current_ref_a) == i_limit))
        clamps["vel_ref"] += int(np.sum(np.abs(batch.vel_ref_dps) == v_clamp))
        clamps["duty"] += int(np.sum(np.abs(batch.duty) == 1.0))
        clamps["disabled"] += int(np.sum(~enabled))
    assert min(clamps.values()) > 0, clamps


def test_compiled_batch_law_disabled_members_reset_like_reset_control():
    params = FirmwareParams()
    law = ArrayLaw(params, 3)
    law.reset(np.array([0, 0, 0]))
    for k in range(30):
        law.estimate(np.array([k, 2 * k, 3 * k]))
        law.servo(10.0, 0.0, 0.0, 990.0, 5.0)
        law.current(np.array([100, 100, 100]), np.array([True, True, True]))
    law.current(np.array([100, 100, 100]), np.array([True, False, True]))
    assert law.duty[1] == 0.0 and law._steps[1] == 0
    assert law._i_v[1] == law._i_i[1] == law.current_ref_a[1] == law.vel_ref_dps[1] == 0.0
    assert not law._pipe[:, 1].any() and not law._ref_pipe[:, 1].any()
    assert law._i_i[0] != 0.0 and law._i_i[2] != 0.0
