"""The conformance vectors of docs/conformance/vectors.json, run against this project's codec
and board (docs/protocol.md section 12).

Frames are checked both ways with the reference codec and decoded a second time by a small
independent decoder built from the tables of docs/protocol.md (zlib's CRC, struct and the
scaling rules of section 4.1; nothing of ``frame.py``'s message table). Streams go through
the reference ``Decoder`` whole and byte by byte. Exchanges drive the simulated board
(``Firmware`` with the default configuration, encoder and current sense at rest: only the
command handling is exercised). Floats compare at float32 precision.
"""

from __future__ import annotations

import json
import math
import re
import struct
import subprocess
import sys
import zlib
from pathlib import Path
from typing import Any

import pytest

from firmware_model.firmware import Firmware
from firmware_model.params import FirmwareParams
from serial_protocol import frame
from serial_protocol import messages as m

ROOT = Path(__file__).resolve().parents[2]
VECTORS = json.loads((ROOT / "docs" / "conformance" / "vectors.json").read_text())
DOC = (ROOT / "docs" / "protocol.md").read_text()
CLASSES = {cls.__name__: cls for cls in frame._BY_CLASS}
CLASSES["Malformed"] = m.Malformed
WIRE = {"u8": "B", "u16": "H", "u32": "I", "i16": "h", "i32": "i", "f32": "f"}


def _float(v: Any) -> Any:
    return {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}.get(v, v)


def _same(got: Any, want: Any) -> bool:
    want = _float(want)
    if isinstance(want, float) or isinstance(got, float):
        if math.isnan(want):
            return math.isnan(got)
        return got == pytest.approx(want, rel=1e-6, abs=1e-12)
    if hasattr(got, "name") and isinstance(want, str):
        return got.name == want
    return got == want


def _build(type_name: str, fields: dict[str, Any]) -> Any:
    """The message of class ``type_name`` with ``fields`` (enum names, "nan" strings)."""
    cls = CLASSES[type_name]
    if cls is m.Malformed:
        return m.Malformed(fields["msg_type"], fields["seq"], fields["cmd_id"],
                           m.NackCode[fields["code"]], fields["field"])  # fmt: skip
    kw = {}
    for f in frame.wire_fields(cls):
        v = _float(fields[f.name])
        if f.enum is not None and f.enum is not bool and isinstance(v, str):
            v = f.enum[v]
        kw[f.name] = v
    return cls(**kw)


def _matches(msg: Any, want: dict[str, Any]) -> bool:
    if type(msg).__name__ != want["type"]:
        return False
    return all(_same(getattr(msg, k), v) for k, v in want["fields"].items())


# ------------------------------------------------------------------ an independent decoder


def _doc_layout(type_byte: int) -> list[tuple[str, str, str]]:
    """``[(name, wire type, unit)]`` of the message ``type_byte`` from docs/protocol.md."""
    match = re.search(rf"^#### 0x{type_byte:02X} `\w+` .*?(?=^#### |^### |^## )", DOC, re.M | re.S)
    assert match, f"type 0x{type_byte:02X} not in docs/protocol.md"
    rows = re.findall(r"^\| \d+ \| \d+ \| `(\w+)` \| (\w+) \| ([^|]*) \|", match.group(0), re.M)
    return [(name, wire, unit.strip()) for name, wire, unit in rows]


def _doc_scale(wire: str, unit: str) -> float:
    """Section 4.1: i32 positions and velocities in 1e-4, i16 currents in mA, i16 duty 1e-4,
    u16 bus voltage in mV."""
    if wire == "i32":
        return 1e4
    if wire == "u16" and unit == "V":
        return 1e3
    if wire == "i16":
        return 1e3 if unit == "A" else 1e4
    return 1.0


def _independent_decode(data: bytes) -> tuple[int, int, dict[str, Any]]:
    """``(type, seq, {field: raw or scaled value})`` by the spec alone."""
    assert data[:2] == b"\xa5\x5a"
    length, type_byte, seq, hdr = data[2], data[3], data[4], data[5]
    crc = 0
    for byte in data[2:5]:  # CRC-8/SMBUS, bit by bit
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    assert crc == hdr
    assert len(data) == 6 + length + 4
    assert zlib.crc32(data[2 : 6 + length]) == int.from_bytes(data[6 + length :], "little")
    layout = _doc_layout(type_byte)
    fmt = "<" + "".join(WIRE[w] for _, w, _ in layout)
    payload = data[6 : 6 + length]
    if length < struct.calcsize(fmt):
        # section 6: an older peer's payload ends after the "at least" length or after an
        # appended field; the fields it lacks read as 0
        heading = rf"^#### 0x{type_byte:02X} `\w+` \(payload \d+, at least (\d+),"
        head = re.search(heading, DOC, re.M)
        assert head and length >= int(head.group(1)), "BAD_LENGTH"
        ends = [struct.calcsize("<" + "".join(WIRE[w] for _, w, _ in layout[: k + 1]))
                for k in range(len(layout))]  # fmt: skip
        assert length in ends, "BAD_LENGTH: ends inside a field"
        payload += bytes(struct.calcsize(fmt) - length)
    values = struct.unpack(fmt, payload[: struct.calcsize(fmt)])
    out = {}
    for (name, wire, unit), raw in zip(layout, values, strict=True):
        scale = _doc_scale(wire, unit)
        out[name] = raw / scale if scale != 1.0 else raw
    return type_byte, seq, out


# ------------------------------------------------------------------ the vectors


def test_crc_check_values():
    for case in VECTORS["crc"]:
        data = bytes.fromhex(case["input_hex"])
        fn = frame.crc8 if case["name"].startswith("crc8") else frame.crc32
        assert fn(data) == case["value"]


def test_constants():
    c = VECTORS["constants"]
    assert bytes.fromhex(c["sync_hex"]) == frame.SYNC
    assert (c["header_bytes"], c["crc_bytes"]) == (frame.HEADER_BYTES, frame.CRC_BYTES)
    assert c["max_payload_bytes"] == frame.MAX_PAYLOAD_BYTES
    assert c["rx_silence_ms"] == frame.RX_SILENCE_S * 1000


def test_every_message_type_has_a_frame_vector():
    assert {v["type_byte"] for v in VECTORS["frames"]} == {int(t) for t in m.MsgType}


@pytest.mark.parametrize("case", VECTORS["frames"], ids=lambda c: c["name"])
def test_frame(case):
    data = bytes.fromhex(case["hex"])
    msg = _build(case["type"], case["fields"])
    assert frame.encode(msg, case["seq"]) == data  # the encoder makes exactly these bytes
    [got] = frame.Decoder().feed(data)
    assert _matches(got, case)
    type_byte, seq, raw = _independent_decode(data)
    assert (type_byte, seq) == (case["type_byte"], case["seq"])
    for name, want in case["fields"].items():
        field = next(f for f in frame.wire_fields(type(msg)) if f.name == name)
        if field.enum is not None and field.enum is not bool:
            want = field.enum[want] if isinstance(want, str) else want
        if field.enum is bool:
            want = int(want)
        assert _same(raw[name], want if not hasattr(want, "value") else int(want)), name


@pytest.mark.parametrize(
    ("name", "type_byte"),
    [
        ("older_board_heartbeat", m.MsgType.BOARD_HEARTBEAT),
        ("older_board_telemetry", m.MsgType.TELEMETRY),
    ],
)
def test_the_spec_alone_reads_an_older_board_s_message(name, type_byte):
    """The extension rule as docs/protocol.md states it (the "at least" length, fields it
    lacks read as 0) decodes the vectors' older BoardHeartbeat and Telemetry (without the
    appended bus voltage) as the codec does."""
    [case] = [c for c in VECTORS["streams"] if c["name"].startswith(name)]
    data = bytes.fromhex(case["hex"])
    got_type, _, raw = _independent_decode(data)
    assert got_type == type_byte
    [want] = case["messages"]
    assert raw["bus_voltage_v"] == 0 and raw["tick"] == want["fields"]["tick"]
    [got] = frame.Decoder().feed(data)
    assert _matches(got, want)


def test_an_older_pc_reads_the_telemetry_with_the_bus_voltage():
    """An older PC knows only the version 2.0 fields of ``Telemetry`` (the rows not marked
    *appended*); by the extension rule it decodes them from the first bytes of the longer
    payload and ignores the rest: the same values as the new decoder's."""
    [case] = [c for c in VECTORS["frames"] if c["name"] == "telemetry"]
    data = bytes.fromhex(case["hex"])
    section = re.search(r"^#### 0x82 `Telemetry` .*?(?=^#### )", DOC, re.M | re.S).group(0)
    old_rows = [
        (name, wire, unit.strip())
        for name, wire, unit, meaning in re.findall(
            r"^\| \d+ \| \d+ \| `(\w+)` \| (\w+) \| ([^|]*) \| ([^|]*) \|", section, re.M
        )
        if not meaning.strip().startswith("*appended*")
    ]
    fmt = "<" + "".join(WIRE[w] for _, w, _ in old_rows)
    length = data[2]
    assert length > struct.calcsize(fmt)  # the new frame is longer than an older PC expects
    values = struct.unpack_from(fmt, data, 6)  # its first bytes: the fields it knows
    [new] = frame.Decoder().feed(data)
    for (name, wire, unit), raw in zip(old_rows, values, strict=True):
        scale = _doc_scale(wire, unit)
        assert _same(raw / scale if scale != 1.0 else raw, _wire_of(getattr(new, name))), name
    assert new.bus_voltage_v == case["fields"]["bus_voltage_v"] > 0


def _wire_of(value: Any) -> Any:
    return int(value) if hasattr(value, "value") else value


def _counters(decoder: frame.Decoder) -> dict[str, int]:
    return dict(vars(decoder.stats()))


@pytest.mark.parametrize("case", VECTORS["streams"], ids=lambda c: c["name"])
@pytest.mark.parametrize("bytewise", [False, True], ids=["whole", "byte_by_byte"])
def test_stream(case, bytewise):
    data = bytes.fromhex(case["hex"])
    decoder = frame.Decoder()
    if bytewise:
        got = [msg for k in range(len(data)) for msg in decoder.feed(data[k : k + 1])]
    else:
        got = decoder.feed(data)
    if case["flush"]:
        got += decoder.flush()
    assert len(got) == len(case["messages"])
    for msg, want in zip(got, case["messages"], strict=True):
        assert _matches(msg, want), (msg, want)
    assert _counters(decoder) == case["counters"]
    assert decoder.pending_bytes == case["pending_bytes"]


def _run_exchange(steps: list[dict[str, Any]]) -> list[tuple[list[Any], list[Any]]]:
    """Each step's (answers, expected) on a freshly booted default board at rest."""
    fw = Firmware(FirmwareParams())
    pc = frame.Decoder()
    out = []
    for step in steps:
        data = bytes.fromhex(step["raw_hex"] if "raw_hex" in step else step["send"]["hex"])
        got = []
        for k in range(max(1, step["wait_ms"] // 2)):
            tx = fw.servo_tick(0, data if k == 0 else b"", 4096)
            fw.current_tick(0)
            got += [
                msg for msg in pc.feed(tx) if not isinstance(msg, m.Telemetry | m.BoardHeartbeat)
            ]
        out.append((got, step["expect"]))
    return out


@pytest.mark.parametrize("case", VECTORS["exchanges"], ids=lambda c: c["name"])
def test_exchange(case):
    for k, (got, expected) in enumerate(_run_exchange(case["steps"])):
        assert len(got) == len(expected), (k, got, expected)
        for msg, want in zip(got, expected, strict=True):
            assert _matches(msg, want), (k, msg, want)


def test_the_send_hex_of_each_step_is_its_message():
    for case in VECTORS["exchanges"]:
        for step in case["steps"]:
            if "send" in step:
                [msg] = frame.Decoder().feed(bytes.fromhex(step["send"]["hex"]))
                assert _matches(msg, step["send"])


def test_vectors_file_is_what_the_generator_writes():
    script = ROOT / "docs" / "conformance" / "make_vectors.py"
    done = subprocess.run([sys.executable, str(script), "--check"], cwd=ROOT, timeout=120)
    assert done.returncode == 0, "vectors.json is stale: run docs/conformance/make_vectors.py"
