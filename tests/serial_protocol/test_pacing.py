"""The line pacer (token bucket, peak window) and the whole-frame queue of ``serve``."""

from __future__ import annotations

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from serial_protocol.frame import Decoder, frame_raw
from serial_protocol.pacing import FrameQueue, LinePacer, frame_length_at

# ------------------------------------------------------------------ LinePacer


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(st.floats(0.0, 0.05), st.integers(0, 5000)), min_size=1, max_size=300),
    st.floats(100.0, 100_000.0),
    st.integers(1, 20_000),
)
def test_pacer_never_grants_more_than_the_line_in_any_window(steps, rate, burst):
    """Whatever the caller's timing (stalls, bursts of requests), the bytes granted in any
    interval of w seconds are at most burst + rate * w, and in any 100 ms window at most
    what the line carries in 100 ms, whatever the bucket; the pacer's own peak figure is
    the largest 100 ms window of what was spent."""
    pacer = LinePacer(rate, burst)
    t = 0.0
    writes = []
    for dt, want in steps:
        t += dt
        n = min(want, pacer.allowance(t))
        pacer.spend(t, n)
        if n:
            writes.append((t, n))
    for k, (t0, _) in enumerate(writes):
        for w in (0.001, 0.01, 0.1, 1.0):
            sent = sum(n for t1, n in writes[k:] if t1 - t0 <= w)
            assert sent <= burst + rate * w * (1 + 1e-9) + 1e-6
        in_window = sum(n for t1, n in writes[k:] if t1 - t0 < 0.1)
        assert in_window <= max(1, int(rate * 0.1)) == pacer.window_cap_bytes
    peak = max((sum(n for t1, n in writes if t0 - 0.1 < t1 <= t0) for t0, _ in writes), default=0)
    assert pacer.peak_window_bytes == peak
    assert pacer.bytes_spent == sum(n for _, n in writes)


def test_pacer_refill_wait_and_misuse():
    pacer = LinePacer(1000.0, 10)
    assert pacer.allowance(0.0) == 10
    pacer.spend(0.0, 10)
    assert pacer.allowance(0.0) == 0
    assert pacer.wait_s(5) == pytest.approx(0.005)
    assert pacer.allowance(0.005) == 5
    assert pacer.allowance(100.0) == 10  # the bucket never holds more than its size
    with pytest.raises(ValueError, match="allowance"):
        pacer.spend(100.0, 11)
    # a bucket larger than the window: the window caps what goes out, and says how long to
    # wait for room
    pacer = LinePacer(1000.0, 500)
    assert pacer.window_cap_bytes == 100
    assert pacer.allowance(0.0) == 100
    pacer.spend(0.0, 60)
    pacer.spend(0.05, 40)
    assert pacer.allowance(0.05) == 0
    assert pacer.wait_s(30) == pytest.approx(0.05)  # the 60 bytes of t = 0 leave at 0.1
    assert pacer.wait_s(100) == pytest.approx(0.1)  # all of it once t = 0.05 has left
    assert pacer.allowance(0.1) == 60
    assert pacer.allowance(0.16) == 100
    for bad in ((0.0, 1), (float("nan"), 1), (10.0, 0)):
        with pytest.raises(ValueError):
            LinePacer(*bad)


# ------------------------------------------------------------------ FrameQueue

frames_st = st.lists(
    st.tuples(st.integers(1, 0xFF), st.binary(max_size=64)).map(
        lambda tp: frame_raw(tp[0], tp[1], len(tp[1]))
    ),
    min_size=1,
    max_size=40,
)


def _units(stream: bytes) -> list[bytes]:
    """The frames of a clean stream of concatenated frames."""
    out, i = [], 0
    while i < len(stream):
        n = frame_length_at(stream, i)
        assert n is not None
        out.append(stream[i : i + n])
        i += n
    return out


def _chunks(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(data) + 1) for c in cuts} | {0, len(data)})
    return [data[a:b] for a, b in zip(points, points[1:], strict=False)]


@settings(max_examples=150, deadline=None)
@given(
    frames_st,
    st.lists(st.integers(0, 10_000), max_size=20),
    st.lists(st.integers(0, 300), min_size=1, max_size=50),
    st.integers(80, 600),
)
def test_output_queue_drops_whole_frames_only(frames, cuts, reads, max_bytes):
    """A reader that takes bytes at any pace gets a subsequence of the frames, each whole,
    in order; the frames dropped are counted exactly; nothing started is ever dropped."""
    stream = b"".join(frames)
    queue = FrameQueue(max_bytes, drop_oldest=True)
    got = bytearray()
    for k, chunk in enumerate(_chunks(stream, cuts)):
        queue.push(chunk)
        got += queue.pop(reads[k % len(reads)])
    queue.flush_tail()
    got += queue.pop(len(stream))
    assert len(queue) == 0
    received = _units(bytes(got))
    it = iter(frames)
    assert all(any(f == g for g in it) for f in received)  # an ordered subsequence
    assert queue.dropped_frames == len(frames) - len(received)
    assert queue.dropped_bytes == len(stream) - len(got)
    decoder = Decoder()
    decoder.feed(bytes(got))
    assert decoder.stats().bytes_dropped == 0 and decoder.stats().crc_errors == 0


@settings(max_examples=150, deadline=None)
@given(
    st.lists(st.one_of(frames_st.map(b"".join), st.binary(max_size=40)), max_size=12),
    st.lists(st.integers(0, 10_000), max_size=20),
    st.lists(st.integers(0, 300), min_size=1, max_size=50),
    st.integers(1, 400),
)
@example(  # found by a random run: a whole Stop frame whose a_max is NaN
    parts=[b"\xa5Z\x08\x04\x08=\x00\x00\x00\x00\x00\x00\x81\x7f\xc5a\x8b\xe3"],
    cuts=[],
    reads=[0],
    max_bytes=18,
)
def test_input_queue_never_passes_part_of_a_frame(parts, cuts, reads, max_bytes):
    """A writer faster than the line: whatever is dropped, every frame the consumer sees
    was sent whole, the consumer's decoder finds every frame that got through, and the
    counters add up."""
    stream = b"".join(parts)
    queue = FrameQueue(max_bytes, drop_oldest=False)
    got = bytearray()
    for k, chunk in enumerate(_chunks(stream, cuts)):
        queue.push(chunk)
        got += queue.pop(reads[k % len(reads)])
        assert len(queue) <= max_bytes
    queue.flush_tail()
    got += queue.pop(len(stream) + 1)
    assert queue.dropped_bytes == len(stream) - len(got)
    sent = Decoder()
    sent_msgs = sent.feed(stream) + sent.flush()
    seen = Decoder()
    seen_msgs = seen.feed(bytes(got)) + seen.flush()
    # Compared by repr: a message may carry a NaN field (a Stop with a_max NaN is a frame
    # like any other here), and NaN != NaN.
    it = iter(map(repr, sent_msgs))
    assert all(any(m == s for s in it) for m in map(repr, seen_msgs))
    assert seen.stats().crc_errors <= sent.stats().crc_errors


def test_input_queue_flood_is_dropped_until_the_next_frame():
    good = frame_raw(0x08, b"\x01\x00", 0)
    queue = FrameQueue(3 * len(good), drop_oldest=False)
    queue.push(good * 3)
    queue.push(good[:5])  # full: this frame is cut, its start dropped...
    assert queue.pop(1000) == good * 3
    queue.push(good[5:] + b"\x00\xa5\x5a" + good)  # ...and its rest, up to the next frame
    assert queue.pop(1000) == good
    assert queue.dropped_frames == 0  # the frame cut was dropped as bytes, not counted
    assert queue.dropped_bytes == len(good) + 3


def test_output_queue_keeps_a_started_frame_and_restarts_at_a_frame_after_clear():
    a, b, c = (frame_raw(0x82, bytes(26), k) for k in range(3))
    queue = FrameQueue(len(a), drop_oldest=True)
    queue.push(a)
    head = queue.pop(10)
    queue.push(b + c)  # over the size: b goes, the started a and the newest c stay
    assert head + queue.pop(1000) == a + c
    assert queue.dropped_frames == 1
    queue.push(a[:7])
    queue.clear()
    queue.push(a[7:] + b)  # a new reader: the rest of a is not a frame it can use
    assert queue.pop(1000) == b


def test_a_reader_that_falls_behind_loses_telemetry_before_an_answer():
    """serve's output queue: frames of an expendable type (telemetry) and noise go first,
    oldest first; an answer goes only when the queue holds nothing else."""
    tel = [frame_raw(0x82, bytes(26), k) for k in range(6)]
    ack = frame_raw(0x83, bytes(4), 99)
    queue = FrameQueue(3 * len(tel[0]), drop_oldest=True, expendable_types=frozenset({0x82}))
    for frame in (tel[0], ack, tel[1], b"\x00\x01", tel[2], tel[3]):
        queue.push(frame)
        queue.flush_tail()
    assert queue.pop(10_000) == ack + b"\x00\x01" + tel[2] + tel[3]
    assert (queue.dropped_frames, queue.dropped_bytes) == (2, 2 * len(tel[0]))
    queue.push(b"\x00\x01")  # noise, then more telemetry: the noise goes first
    queue.flush_tail()
    queue.push(tel[4] + tel[5] + tel[0])
    assert queue.pop(10_000) == tel[4] + tel[5] + tel[0]
    # only answers queued: the oldest answer goes (the queue stays within its size)
    acks = [frame_raw(0x83, bytes(26), k) for k in range(4)]
    for frame in acks:
        queue.push(frame)
    assert queue.pop(10_000) == b"".join(acks[1:])
    # without expendable types the oldest goes, whatever it is
    plain = FrameQueue(3 * len(tel[0]), drop_oldest=True)
    for frame in (tel[0], ack, tel[1], tel[2], tel[3]):
        plain.push(frame)
    assert plain.pop(10_000) == tel[1] + tel[2] + tel[3]


def test_a_new_reader_starts_at_a_frame_that_passes_its_check():
    """After clear() the stream restarts at the first whole frame: a sync pair and a valid
    header inside the rest of a cut frame (it passes the 8-bit header check) is not one."""
    real = frame_raw(0x82, bytes(26), 5)
    fake_header = frame_raw(0x82, bytes(26), 9)[:6]  # a header whose claimed frame is cut
    queue = FrameQueue(1000, drop_oldest=True)
    queue.clear()
    queue.push(b"\x01\x02" + fake_header + bytes(10) + real + real)
    assert queue.pop(1000) == real + real
