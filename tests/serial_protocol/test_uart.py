"""The emulated UART: pacing, FIFO overflow, fault injection, decimation; the soak."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from serial_protocol.frame import TELEMETRY_FRAME_BYTES, Decoder, encode
from serial_protocol.messages import State, Telemetry
from serial_protocol.uart import (
    EmulatedUart,
    FaultInjection,
    bytes_per_s,
    link_utilisation,
    telemetry_decimation,
)

TICK_S = 0.002

# ------------------------------------------------------------------ pacing


def test_bytes_are_paced_at_baud_over_ten():
    uart = EmulatedUart(baud=115200, fifo_bytes=100_000)
    uart.write(bytes(50_000))
    delivered = [len(uart.advance(TICK_S)) for _ in range(1000)]
    # 11520 bytes/s * 2 ms = 23.04 bytes per tick: 23 per tick, a 24th every 25 ticks
    assert set(delivered) == {23, 24}
    assert sum(delivered) == 23040
    assert uart.stats.sent == sum(delivered) == uart.stats.delivered


@settings(max_examples=60, deadline=None)
@given(
    st.sampled_from([9600, 115200, 460800, 921600]),
    st.lists(st.floats(1e-5, 0.01), min_size=1, max_size=200),
)
def test_fractional_credit_is_carried_over(baud, steps_s):
    uart = EmulatedUart(baud=baud, fifo_bytes=1_000_000)
    uart.write(bytes(1_000_000))
    total = sum(len(uart.advance(dt_s)) for dt_s in steps_s)
    # never ahead of the line, never more than one byte behind it
    exact = sum(steps_s) * baud / 10
    assert exact - 1 - 1e-6 <= total <= exact + 1e-6


def test_data_order_is_preserved_and_fifo_drains():
    uart = EmulatedUart(baud=460800, fifo_bytes=1000)
    payload = bytes(range(256)) * 3
    assert uart.write(payload) == len(payload)
    out = b""
    while uart.pending:
        out += uart.advance(TICK_S)
    assert out == payload
    assert uart.free == 1000


def test_idle_line_does_not_bank_credit():
    uart = EmulatedUart(baud=115200, fifo_bytes=1000)
    for _ in range(100):
        assert uart.advance(TICK_S) == b""
    uart.write(bytes(100))
    assert len(uart.advance(TICK_S)) == 23


def test_overflow_is_counted_never_silent():
    uart = EmulatedUart(baud=115200, fifo_bytes=64)
    assert uart.write(bytes(40)) == 40
    assert uart.free == 24
    assert uart.write(bytes(40)) == 24
    assert uart.free == 0
    assert uart.stats.written == 64
    assert uart.stats.overflow_bytes == 16
    assert uart.stats.overflow_events == 1
    assert uart.write(b"") == 0


def test_telemetry_every_tick_overflows_at_115200_but_not_decimated():
    frame = bytes(TELEMETRY_FRAME_BYTES)
    decimated = telemetry_decimation(115200, len(frame), 500)
    for decimation, overflows in ((1, True), (decimated, False)):
        uart = EmulatedUart(baud=115200, fifo_bytes=256)
        for tick in range(2000):
            if tick % decimation == 0:
                uart.write(frame)
            uart.advance(TICK_S)
        assert (uart.stats.overflow_bytes > 0) is overflows


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"baud": 0}, "baud"),
        ({"baud": 115200.5}, "baud"),
        ({"baud": 115200, "fifo_bytes": 0}, "fifo_bytes"),
    ],
)
def test_bad_arguments_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        EmulatedUart(**kwargs)


@pytest.mark.parametrize("dt_s", [-0.002, float("nan")])
def test_advance_refuses_negative_or_nan_time(dt_s):
    uart = EmulatedUart(baud=115200, fifo_bytes=64)
    uart.write(bytes(10))
    with pytest.raises(ValueError, match="dt_s"):
        uart.advance(dt_s)
    assert uart.pending == 10


def test_fault_injection_checks_its_rates():
    with pytest.raises(ValueError, match="drop_rate"):
        FaultInjection(drop_rate=1.5)
    with pytest.raises(ValueError, match="sum"):
        FaultInjection(drop_rate=0.6, bit_flip_rate=0.6)
    with pytest.raises(ValueError, match="burst_bytes"):
        FaultInjection(burst_rate=0.1, burst_bytes=0)


# ------------------------------------------------------------------ bandwidth


@pytest.mark.parametrize(
    ("baud", "expected"),
    [(9600, 28), (57600, 5), (115200, 3), (230400, 2), (460800, 1), (921600, 1)],
)
def test_telemetry_decimation(baud, expected):
    # 42-byte frames at 500 Hz = 21000 B/s; 80 % of baud/10 available
    assert TELEMETRY_FRAME_BYTES == 42
    assert telemetry_decimation(baud, 42, 500) == expected


@settings(max_examples=200)
@given(
    st.integers(300, 4_000_000),
    st.integers(8, 72),
    st.sampled_from([100, 500, 1000, 2000]),
    st.floats(0.05, 1.0),
)
def test_decimation_is_the_smallest_that_fits(baud, frame_bytes, tick_hz, share):
    d = telemetry_decimation(baud, frame_bytes, tick_hz, share)
    assert link_utilisation(baud, frame_bytes, tick_hz, d) <= share
    if d > 1:
        assert link_utilisation(baud, frame_bytes, tick_hz, d - 1) > share


def test_bandwidth_arithmetic():
    assert bytes_per_s(115200) == 11520.0
    # a 34-byte frame every 2 ms needs 17000 B/s: 148 % of 115200 baud
    assert link_utilisation(115200, 34, 500) == pytest.approx(17000 / 11520)
    assert link_utilisation(921600, 34, 500) == pytest.approx(17000 / 92160)


# ------------------------------------------------------------------ fault injection


def test_fault_injection_is_seeded_and_counted():
    faults = FaultInjection(bit_flip_rate=0.01, drop_rate=0.01, insert_rate=0.01, burst_rate=0.01)
    runs = []
    for _ in range(2):
        uart = EmulatedUart(baud=921600, fifo_bytes=100_000, faults=faults, seed=7)
        uart.write(bytes(50_000))
        out = b"".join(uart.advance(TICK_S) for _ in range(400))
        runs.append((out, uart.stats))
    assert runs[0] == runs[1]
    out, stats = runs[0]
    assert stats.sent == 50_000
    assert stats.delivered == len(out) == stats.sent - stats.dropped + stats.inserted
    # the input is all zeros: a flipped bit, an inserted byte or a burst byte is non-zero
    nonzero = sum(1 for byte in out if byte)
    changed = stats.flipped_bits + stats.burst_bytes
    assert changed <= nonzero <= changed + stats.inserted
    assert stats.burst_bytes == stats.bursts * faults.burst_bytes
    for count in (stats.flipped_bits, stats.dropped, stats.inserted, stats.bursts):
        assert 350 < count < 650  # 1 % of 50 000 bytes each, drawn


@pytest.mark.parametrize("rate", [5e-324, 1e-300, 1e-17])
def test_vanishing_fault_rates_mean_no_faults(rate):
    faults = FaultInjection(bit_flip_rate=rate, burst_rate=rate)
    uart = EmulatedUart(baud=921600, fifo_bytes=10_000, faults=faults, seed=3)
    uart.write(bytes(10_000))
    assert uart.advance(1.0) == bytes(10_000)


def test_different_seeds_give_different_faults():
    faults = FaultInjection(bit_flip_rate=0.01)
    outs = []
    for seed in (1, 2):
        uart = EmulatedUart(baud=921600, fifo_bytes=10_000, faults=faults, seed=seed)
        uart.write(bytes(10_000))
        outs.append(uart.advance(1.0))
    assert outs[0] != outs[1]


def _frame_hit(events, start: int, end: int, burst_bytes: int) -> bool:
    for event in events:
        if event.kind == "burst" and event.index < end and event.index + burst_bytes > start:
            return True
        if event.kind == "insert" and start <= event.index < end - 1:
            return True
        if event.kind in ("flip", "drop") and start <= event.index < end:
            return True
    return False


def test_soak_thousands_of_frames_through_faults():
    """5000 telemetry frames through flips, drops, inserts and bursts, tick by tick.

    Every decoded frame equals a sent one, every frame the faults missed is decoded, and
    the decoder's counters match what the fault log says happened.
    """
    faults = FaultInjection(
        bit_flip_rate=5e-4, drop_rate=2e-4, insert_rate=2e-4, burst_rate=2e-4, burst_bytes=2
    )
    uart = EmulatedUart(baud=460800, fifo_bytes=512, faults=faults, seed=2024, record_faults=True)
    decoder = Decoder()
    msgs = [
        Telemetry(k, k / 1000.0, 2.0, 2 * k / 1000.0, -1.0, 0.5, 0.25, State.MOVING, 0)
        for k in range(5000)
    ]
    received = []
    for seq, msg in enumerate(msgs):
        assert uart.write(encode(msg, seq)) == TELEMETRY_FRAME_BYTES
        received += decoder.feed(uart.advance(TICK_S))
    while uart.pending:
        received += decoder.feed(uart.advance(TICK_S))
    received += decoder.flush()

    n = TELEMETRY_FRAME_BYTES
    log = uart.fault_log
    hit = [_frame_hit(log, k * n, (k + 1) * n, faults.burst_bytes) for k in range(len(msgs))]
    intact = [k for k in range(len(msgs)) if not hit[k]]
    assert 100 < sum(hit) < 400  # the soak really exercised the faults
    assert uart.stats.overflow_bytes == 0

    # zero corrupted frames accepted, every intact frame recovered, in order
    assert received == [msgs[k] for k in intact]
    assert decoder.frames == len(intact)
    assert decoder.malformed == 0
    assert decoder.bytes_dropped == uart.stats.delivered - len(intact) * n
    gaps = [b - a - 1 for a, b in zip(intact, intact[1:], strict=False) if b - a > 1]
    assert decoder.seq_gaps == len(gaps)
    assert decoder.frames_missed == sum(gaps)
    inserted_at = {e.index for e in log if e.kind == "insert"}
    resyncs = sum(
        1 for k in intact if (k > 0 and hit[k - 1]) or (k > 0 and k * n - 1 in inserted_at)
    )
    assert decoder.resyncs == resyncs


@settings(max_examples=30, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.floats(0.0, 5e-3),
    st.floats(0.0, 2e-3),
    st.integers(1, 2),
)
def test_flips_and_short_bursts_never_pass_as_frames(seed, flip_rate, burst_rate, burst_bytes):
    """Bit flips and bursts of up to 16 bits are always detected by the CRC, so whatever the
    seed, the decoded stream is exactly the frames the faults missed."""
    faults = FaultInjection(bit_flip_rate=flip_rate, burst_rate=burst_rate, burst_bytes=burst_bytes)
    uart = EmulatedUart(baud=921600, fifo_bytes=1 << 20, faults=faults, seed=seed,
                        record_faults=True)  # fmt: skip
    msgs = [Telemetry(k, k / 8, 0.0, -k / 16, 1.0, 0.25, 0.5, State.MOVING, 0) for k in range(300)]
    for seq, msg in enumerate(msgs):
        uart.write(encode(msg, seq))
    decoder = Decoder()
    got = decoder.feed(uart.advance(10.0)) + decoder.flush()
    n = TELEMETRY_FRAME_BYTES
    hit = [_frame_hit(uart.fault_log, k * n, (k + 1) * n, burst_bytes) for k in range(len(msgs))]
    assert got == [m for m, h in zip(msgs, hit, strict=True) if not h]
