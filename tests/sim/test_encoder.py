"""AS5048 model: quantisation, wrap-around, latency, seeded noise, parameters per member."""

from __future__ import annotations

import math

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
