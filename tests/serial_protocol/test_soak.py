"""The link soak, bounded (20,000 frames; benchmarks/soak_link.py runs 1,000,000): the full
fault mix accepts no corrupted frame, recovers every intact one, and every counter of the
decoder equals a naive receiver's (tests/serial_protocol/link_soak.py)."""

from __future__ import annotations

import pytest
from link_soak import FAULT_KINDS, crc_residual, reference_counters, run_soak

from serial_protocol import frame
from serial_protocol.messages import Telemetry


@pytest.mark.parametrize("seed", [1, 2])
def test_soak_accepts_no_corrupted_frame_and_counts_exactly(seed):
    r = run_soak(20_000, seed=seed)
    assert r.problems == []
    assert r.accepted_corrupted == 0
    # The mix really happened: every kind of damage, and about 30 % of the frames damaged.
    assert set(r.damaged_by_kind) == set(FAULT_KINDS)
    assert {"garbage", "fake_sync", "fake_header", "idle"} <= set(r.between_by_kind)
    assert 0.25 < r.damaged / r.frames < 0.35
    assert r.recovery >= 0.9999
    assert r.counters == r.reference_counters
    assert r.counters["crc_errors"] > 1000 and r.counters["header_errors"] > 100
    assert r.counters["partial_discards"] > 0


def test_reference_receiver_accounts_for_every_byte():
    a = frame.encode(Telemetry(1, 0, 0, 0, 0, 0, 0, 0, 0), 0)
    head = bytes((64, 1, 0))
    fake = frame.SYNC + head + bytes((frame.crc8(head),))
    counters = reference_counters([b"\x01\x02" + a + fake, a])
    assert counters["frames"] == 2 and counters["bytes_dropped"] == 2 + len(fake)
    assert counters["partial_discards"] == 1 and counters["seq_gaps"] == 1


def test_crc32_lets_no_damaged_frame_through_where_crc16_would_at_its_rate():
    # A short run of the residual measurement (the long one is in docs/benchmarks.md).
    # 1 to 3 flipped bits: both CRCs detect every such error (Hamming distance >= 4).
    c = crc_residual(5_000, 3, "bit_flip")
    assert c["damaged32"] > 4_900 and c["corrupt32"] == c["corrupt16"] == 0
    # A dropped byte: the CRC-16 lets about 2^-16 through (a handful in 10^5, not tested
    # here), the CRC-32 about 2^-32.
    c = crc_residual(5_000, 4, "drop")
    assert c["damaged32"] == 5_000 and c["corrupt32"] == 0
