"""AS5048 model: quantisation, wrap-around, latency, seeded noise, parameters per member."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from sim.encoder import Encoder
from sim.params import EncoderParams

COUNT_RAD = 2 * math.pi / 16384


def _enc(**kw) -> Encoder:
    kw.setdefault("latency_s", 0.0)
    return Encoder(EncoderParams(**kw), np.random.default_rng(0))


class _One:
    """Reads one state (a list of 5) through ``Encoder.read`` as a batch of one."""

    def __init__(self, enc: Encoder) -> None:
        self.enc = enc

    def read(self, x) -> int:
        return int(self.enc.read(np.array([x], dtype=float))[0])


def test_quantisation_truncates_to_counts():
    enc = _One(_enc())
    assert enc.read([0, 0.0, 0, 0, 0]) == 0
    assert enc.read([0, 0.999 * COUNT_RAD, 0, 0, 0]) == 0
    assert enc.read([0, 1.001 * COUNT_RAD, 0, 0, 0]) == 1
    assert enc.read([0, 100.5 * COUNT_RAD, 0, 0, 0]) == 100


def test_wraps_around_both_ways():
    enc = _One(_enc())
    assert enc.read([0, 2 * math.pi + 3.5 * COUNT_RAD, 0, 0, 0]) == 3
    assert enc.read([0, -0.5 * COUNT_RAD, 0, 0, 0]) == 16383
    assert enc.read([0, -5 * 2 * math.pi + 10.5 * COUNT_RAD, 0, 0, 0]) == 10
    many = np.linspace(-50, 50, 1001)
    counts = [enc.read([0, float(p), 0, 0, 0]) for p in many]
    assert min(counts) >= 0 and max(counts) <= 16383


def test_latency_reads_the_angle_of_tau_ago():
    enc = _One(_enc(latency_s=1e-4))
    w = 1000.0  # rad/s
    pos = 5.0
    expected = math.floor((pos - w * 1e-4) / COUNT_RAD) % 16384
    assert enc.read([0, pos, w, 0, 0]) == expected
    assert enc.read([0, pos, 0.0, 0, 0]) == math.floor(pos / COUNT_RAD) % 16384


def test_noise_is_seeded_and_has_the_configured_rms():
    p = EncoderParams(latency_s=0.0, noise_rms_lsb=2.0)
    x = [0, 1000.5 * COUNT_RAD, 0, 0, 0]
    a = [_One(Encoder(p, np.random.default_rng(7))).read(x) for _ in range(1)]
    enc1 = _One(Encoder(p, np.random.default_rng(7)))
    enc2 = _One(Encoder(p, np.random.default_rng(7)))
    r1 = np.array([enc1.read(x) for _ in range(4000)])
    r2 = np.array([enc2.read(x) for _ in range(4000)])
    np.testing.assert_array_equal(r1, r2)
    assert a[0] == r1[0]
    assert np.std(r1) == pytest.approx(2.0, rel=0.1)  # + truncation noise (1/12 LSB^2)
    assert np.mean(r1) == pytest.approx(1000.0, abs=0.2)


def test_batch_read_gives_each_member_its_own_reading():
    enc = _enc(latency_s=1e-4)
    rng = np.random.default_rng(3)
    x = np.zeros((500, 5))
    x[:, 1] = rng.uniform(-100, 100, 500)
    x[:, 2] = rng.uniform(-1500, 1500, 500)
    counts = enc.read(x)
    assert counts.dtype == np.int64
    assert [_One(enc).read(list(row)) for row in x] == counts.tolist()


def test_batch_read_with_parameters_per_member_matches_the_formula():
    rng = np.random.default_rng(4)
    n = 300
    latency, offset = rng.uniform(0.0, 3e-4, n), rng.uniform(0.0, 40.0, n)
    noise = rng.uniform(0.0, 2.5, n)
    batch = Encoder(
        EncoderParams(latency_s=latency, offset_counts=offset, noise_rms_lsb=noise),
        np.random.default_rng(8),
    )
    x = np.zeros((n, 5))
    x[:, 1] = rng.uniform(-100, 100, n)
    x[:, 2] = rng.uniform(-1500, 1500, n)
    first, second = batch.read(x), batch.read(x)
    # The draws: blocks of 4096 ticks x n standard normals from the seeded generator, row
    # k for tick k (the stream of one draw of n per tick).
    draws = np.random.default_rng(8).standard_normal((2, n))
    for k, counts in enumerate((first, second)):
        c = (x[:, 1] - x[:, 2] * latency) * (16384 / (2 * math.pi)) + offset + noise * draws[k]
        np.testing.assert_array_equal(counts, np.floor(c).astype(np.int64) % 16384)


def test_inl_adds_the_configured_harmonics_of_the_motor_angle():
    a1, p1, a2, p2 = 0.5, 20.0, 0.1, -45.0  # motor degrees, phase degrees
    enc = _enc(inl_h1_deg=a1, inl_h1_phase_deg=p1, inl_h2_deg=a2, inl_h2_phase_deg=p2)
    theta = np.random.default_rng(3).uniform(0.0, 2 * math.pi, 20000)
    x = np.zeros((theta.size, 5))
    x[:, 1] = theta
    counts = enc.read(x)
    lsb = 16384 / 360.0
    inl = a1 * lsb * np.sin(theta + math.radians(p1)) + a2 * lsb * np.sin(
        2 * theta + math.radians(p2)
    )
    expected = np.floor(theta / COUNT_RAD + inl).astype(np.int64) % 16384
    np.testing.assert_array_equal(counts, expected)
    # Least squares on the reading's error recovers amplitudes and phases (the truncation
    # adds a -0.5 LSB mean and a sawtooth uncorrelated with the harmonics).
    err = (counts - theta / COUNT_RAD + 8192) % 16384 - 8192
    basis = np.stack(
        [np.ones_like(theta), np.sin(theta), np.cos(theta), np.sin(2 * theta), np.cos(2 * theta)]
    ).T
    coef = np.linalg.lstsq(basis, err, rcond=None)[0]
    assert coef[0] == pytest.approx(-0.5, abs=0.01)
    assert math.hypot(coef[1], coef[2]) / lsb == pytest.approx(a1, abs=0.01 / lsb)
    assert math.degrees(math.atan2(coef[2], coef[1])) == pytest.approx(p1, abs=0.05)
    assert math.hypot(coef[3], coef[4]) / lsb == pytest.approx(a2, abs=0.01 / lsb)
    assert math.degrees(math.atan2(coef[4], coef[3])) == pytest.approx(p2, abs=0.3)


def test_inl_makes_a_velocity_ripple_at_the_motor_turn_rate():
    # Constant 990 deg/s at the axis (79,200 deg/s at the motor: 158.4 deg per 2 ms tick).
    # The raw count difference per tick deviates from the true speed by
    # 2 A1 sin(w dt / 2) cos(...) / dt: +-6.0 axis deg/s for A1 = 0.489 deg.
    dt_s, a1 = 0.002, 0.489
    w = math.radians(990.0 * 80)
    enc = _enc(inl_h1_deg=a1)
    x = np.zeros((1, 5))
    readings = []
    for k in range(400):
        x[0, 1], x[0, 2] = w * k * dt_s, w
        readings.append(int(enc.read(x)[0]))
    diff = (np.diff(readings) + 8192) % 16384 - 8192
    vel_axis_dps = diff * (360.0 / 16384) / dt_s / 80
    ripple = vel_axis_dps - 990.0
    bound = 2 * a1 * math.sin(w * dt_s / 2) / dt_s / 80
    assert bound == pytest.approx(6.0, abs=0.02)
    quant = 2 * (360.0 / 16384) / dt_s / 80  # one count either side
    assert np.max(np.abs(ripple)) <= bound + quant
    assert np.max(np.abs(ripple)) >= bound - quant


def test_inl_off_reads_as_before():
    theta = np.linspace(-50.0, 50.0, 1001)
    x = np.zeros((theta.size, 5))
    x[:, 1] = theta
    plain = _enc().read(x)
    zero = _enc(inl_h1_deg=0.0, inl_h2_deg=0.0, inl_h1_phase_deg=33.0).read(x)
    np.testing.assert_array_equal(plain, zero)
    np.testing.assert_array_equal(plain, np.floor(theta / COUNT_RAD).astype(np.int64) % 16384)


def _batch_run_digest(head: bool) -> str:
    """A batch run whose encoder noise (N = 128 x 300 ticks: ~38k draws, one block) is drawn
    partly on the thread (``head``) or at once: the hash of its log and PC bytes."""
    import dataclasses
    import hashlib
    from pathlib import Path

    from sim import loop
    from sim.config import load_experiment

    fig8 = load_experiment(Path(__file__).resolve().parents[2] / "bench_configs" / "fig8.toml")
    exp = dataclasses.replace(fig8, duration_s=0.6)
    saved = loop.Simulation._head
    if not head:
        loop.Simulation._head = lambda self, rows: 0
    try:
        res = loop.run(exp, batch=128)
    finally:
        loop.Simulation._head = saved
    h = hashlib.sha256(res.pc_bytes)
    for f in loop.LOG_FIELDS:
        h.update(np.ascontiguousarray(getattr(res.log, f)).tobytes())
    return h.hexdigest()


def test_a_batch_runs_noise_drawn_on_the_thread_is_the_noise_drawn_at_once(monkeypatch):
    # Encoder.refill's head: a 32nd of the block at once, the rest on the drawing
    # thread, in chunks, while the compiled tick runs; the same numbers in the same order.
    from sim import encoder

    used = []
    drawer = encoder._drawer
    monkeypatch.setattr(encoder, "_drawer", lambda: used.append(1) or drawer())
    on_thread = _batch_run_digest(True)
    assert used  # the thread drew the rest of the block
    assert on_thread == _batch_run_digest(False)


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform")
def test_a_forked_child_draws_on_its_own_thread():
    # A child forked after the parent used the drawing thread has none of it: it must start
    # its own (the parent's executor would take the work and never run it).
    import multiprocessing

    parent = _batch_run_digest(True)
    with multiprocessing.get_context("fork").Pool(1) as pool:
        child = pool.apply_async(_batch_run_digest, (True,)).get(timeout=300)
    assert child == parent
