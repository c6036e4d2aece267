"""feed_columns' bulk pass (many frames checked at once with numpy) against the frame by
frame scan: the same telemetry columns, messages, counters and pending bytes, on long
streams with replies, sequence gaps, bad codes, damaged and inserted bytes, in chunks."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from serial_protocol import frame
from serial_protocol.frame import Decoder
from serial_protocol.messages import Ack, BoardHeartbeat, Fault, State, Status, Telemetry


def _stream(rng: np.random.Generator, n_frames: int) -> bytes:
    out = bytearray()
    seq = 0
    for k in range(n_frames):
        r = rng.random()
        if r < 0.03:
            seq = (seq + int(rng.integers(1, 255))) & 0xFF  # a gap
        if r < 0.9:
            vals = rng.normal(0.0, [100.0, 100.0, 100.0, 100.0, 2.0, 0.3])
            raw = bytearray(
                frame.encode_telemetry_fields(
                    seq, k, *vals.tolist(), int(rng.integers(0, 5)), int(rng.integers(0, 7)),
                    int(rng.integers(0, 1 << 32)), float(rng.uniform(0.0, 30.0)),
                )
            )  # fmt: skip
            other = rng.random()
            if other < 0.05:  # the extension rule: an older board's (the 2.0 fields only) or
                # a newer board's telemetry (3 bytes more): columns as well
                payload = bytes(raw[6:-4])
                payload = payload[:_TEL_MIN] if other < 0.03 else payload + b"\x01\x02\x03"
                raw = bytearray(frame.frame_raw(int(Telemetry.MSG_TYPE), payload, seq))
            if rng.random() < 0.02:  # a state code out of range, CRC good: Malformed
                raw[frame._STATE_AT] = 0xEE
                raw[-4:] = frame.crc32(bytes(raw[2:-4])).to_bytes(4, "little")
        elif r < 0.94:
            raw = frame.encode(Ack(k & 0xFFFF, 3), seq)
        elif r < 0.97:
            raw = (
                frame.encode(BoardHeartbeat(k, 1, State.MOVING, 0, k, 0, 0, 0, 0, 0, 0), seq)
                if _HB_FIELDS == 11
                else frame.encode(Ack(k & 0xFFFF, 4), seq)
            )
        else:
            raw = frame.encode(Status(k & 0xFFFF, k, State.HOLDING, Fault.NONE, 1.0, 2.0, 3.0), seq)
        out += raw
        seq = (seq + 1) & 0xFF
    return bytes(out)


_HB_FIELDS = len(dataclasses.fields(BoardHeartbeat))
_TEL_MIN = frame._BY_CLASS[Telemetry].min_size


def _damage(rng: np.random.Generator, data: bytes, n_damage: int) -> bytes:
    buf = bytearray(data)
    for _ in range(n_damage):
        at = int(rng.integers(0, max(1, len(buf))))
        kind = rng.integers(0, 4)
        if kind == 0:
            buf[at] ^= 1 << int(rng.integers(0, 8))
        elif kind == 1:
            buf[at:at] = bytes(rng.integers(0, 256, int(rng.integers(1, 30)), dtype=np.uint8))
        elif kind == 2:
            del buf[at : at + int(rng.integers(1, 50))]
        else:
            buf[at:at] = b"\xa5\x5a" + bytes(rng.integers(0, 256, 6, dtype=np.uint8))
    return bytes(buf)


def _decode_all(data: bytes, chunks: list[int], bulk: bool) -> tuple:
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(frame, "_BULK_MIN_BYTES", 2048 if bulk else 1 << 62)
        return _decode_chunks(data, chunks)


def _decode_chunks(data: bytes, chunks: list[int]) -> tuple:
    dec = Decoder()
    cols: dict[str, list] = {}
    others: list = []
    at = 0
    for size in chunks + [len(data)]:
        c, o = dec.feed_columns(data[at : at + size])
        at += size
        for name, v in c.items():
            cols.setdefault(name, []).extend(v.tolist())
        others += o
        if at >= len(data):
            break
    return cols, others, dec.stats(), dec.pending_bytes


def _same_messages(a: list, b: list) -> bool:
    if len(a) != len(b):
        return False
    for x, y in zip(a, b, strict=True):
        if type(x) is not type(y):
            return False
        for f in dataclasses.fields(x):
            u, v = getattr(x, f.name), getattr(y, f.name)
            if u != v and not (isinstance(u, float) and math.isnan(u) and math.isnan(v)):
                return False
    return True


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_frames=st.integers(50, 1500),
    n_damage=st.sampled_from([0, 0, 1, 3, 20]),
    chunked=st.booleans(),
)
def test_bulk_pass_decodes_as_the_frame_by_frame_scan(seed, n_frames, n_damage, chunked):
    rng = np.random.default_rng(seed)
    data = _damage(rng, _stream(rng, n_frames), n_damage)
    chunks = [int(c) for c in rng.integers(1, 9000, 20)] if chunked else []
    bulk = _decode_all(data, chunks, True)
    scan = _decode_all(data, chunks, False)
    assert bulk[0] == scan[0]
    assert _same_messages(bulk[1], scan[1])
    assert bulk[2] == scan[2] and bulk[3] == scan[3]
    # and what feed() gives, as objects
    objects = Decoder().feed(data)
    tel = [m for m in objects if isinstance(m, Telemetry)]
    assert bulk[0]["tick"] == [m.tick for m in tel]
    assert bulk[0]["pos_deg"] == [m.pos_deg for m in tel]
    assert bulk[0]["bus_voltage_v"] == [m.bus_voltage_v for m in tel]


def test_bulk_pass_takes_a_clean_stream_whole(monkeypatch):
    rng = np.random.default_rng(1)
    data = _stream(rng, 3000)
    calls = []
    real = frame._bulk_frames

    def counting(*args):
        out = real(*args)
        calls.append(out[0].shape[0])
        return out

    monkeypatch.setattr(frame, "_bulk_frames", counting)
    dec = Decoder()
    cols, others = dec.feed_columns(data)
    assert dec.stats().frames == 3000 and dec.pending_bytes == 0
    assert sum(calls) == 3000 and len(calls) <= 8  # a few growing windows, no frame by frame


def test_crc_tables_give_zlib_crc32():
    rng = np.random.default_rng(2)
    zero, table = frame._crc32_tables()
    size = frame.TELEMETRY_FRAME_BYTES - 6
    for _ in range(200):
        msg = rng.integers(0, 256, size, dtype=np.uint8)
        crc = zero
        for p in range(size):
            crc ^= int(table[p, msg[p]])
        assert crc == frame.crc32(msg.tobytes())


def test_an_older_and_a_newer_board_s_telemetry_decode_as_columns():
    """The extension rule in ``feed_columns``: an older board's telemetry (without the
    appended bus voltage) is a row with the bus voltage 0, a newer board's (more bytes
    after it) a row with the fields this codec knows; as ``feed`` gives them."""
    now = frame.encode_telemetry_fields(0, 7, 1.0, 2.0, 3.0, 4.0, 0.5, 0.25, 2, 0, 0, 24.517)
    payload = now[6:-4]
    old = frame.frame_raw(int(Telemetry.MSG_TYPE), payload[:_TEL_MIN], 1)
    new = frame.frame_raw(int(Telemetry.MSG_TYPE), payload + b"\xff" * 6, 2)
    data = (now + old + new) * 200  # enough for the bulk pass
    cols, others = Decoder().feed_columns(data)
    assert others == [] and len(cols["tick"]) == 600
    assert cols["bus_voltage_v"][:3].tolist() == [24.517, 0.0, 24.517]
    assert cols["pos_deg"][:3].tolist() == [3.0, 3.0, 3.0]
    objects = Decoder().feed(data)
    assert [m.bus_voltage_v for m in objects[:3]] == [24.517, 0.0, 24.517]
    assert objects[1] == Telemetry(7, 1.0, 2.0, 3.0, 4.0, 0.5, 0.25, State.MOVING, Fault.NONE)
