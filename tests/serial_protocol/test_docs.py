"""docs/protocol.md agrees with the code: message layouts, sizes and the bandwidth table."""

from __future__ import annotations

import dataclasses
import re
import struct
from pathlib import Path

import pytest

from serial_protocol import frame, messages
from serial_protocol.uart import bytes_per_s, link_utilisation, telemetry_decimation

DOC = (Path(__file__).resolve().parents[2] / "docs" / "protocol.md").read_text()
WIRE_TYPES = {"u8": "B", "u16": "H", "u32": "I", "i16": "h", "i32": "i", "f32": "f"}


def _section(name: str) -> str:
    match = re.search(rf"^#### 0x[0-9A-F]{{2}} `{name}` .*?(?=^#### |^### |^## )", DOC, re.M | re.S)
    assert match, f"no section for {name} in docs/protocol.md"
    return match.group(0)


@pytest.mark.parametrize("cls", list(frame._BY_CLASS), ids=lambda c: c.__name__)
def test_message_table_matches_codec(cls):
    codec = frame._BY_CLASS[cls]
    text = _section(cls.__name__)
    head = re.match(
        r"#### 0x([0-9A-F]{2}) `\w+` \(payload (\d+)(?:, at least (\d+))?, frame (\d+) bytes\)",
        text,
    )
    assert head
    assert int(head.group(1), 16) == codec.msg_type
    assert int(head.group(2)) == codec.payload.size
    assert int(head.group(4)) == codec.payload.size + frame.OVERHEAD_BYTES
    # the extension rule (section 6): the length without the appended fields, and each
    # appended field marked in the table
    if codec.min_size < codec.payload.size:
        assert head.group(3) is not None and int(head.group(3)) == codec.min_size
    else:
        assert head.group(3) is None
    marked = re.findall(r"^\| \d+ \| \d+ \| `(\w+)` \| \w+ \| [^|]* \| \*appended\*", text, re.M)
    assert marked == [f.name for f in frame.wire_fields(cls) if f.appended]
    rows = re.findall(r"^\| (\d+) \| (\d+) \| `(\w+)` \| (\w+) \|", text, re.M)
    names = [f.name for f in frame.wire_fields(cls)]
    assert [r[2] for r in rows] == names
    # every dataclass field is on the wire, and nothing else
    assert sorted(names) == sorted(f.name for f in dataclasses.fields(cls))
    assert "".join(WIRE_TYPES[r[3]] for r in rows) == codec.fmt
    offset = 0
    for row in rows:
        assert int(row[0]) == offset
        assert int(row[1]) == struct.calcsize("<" + WIRE_TYPES[row[3]])
        offset += int(row[1])
    assert offset == codec.payload.size


def test_bandwidth_table_matches_code():
    rows = re.findall(r"^\| (\d{5,7}) \| (.*) \|$", DOC, re.M)
    bauds = [int(r[0]) for r in rows]
    assert bauds == [115200, 460800, 921600]
    n = frame.TELEMETRY_FRAME_BYTES
    for baud, rest in rows:
        cells = [c.strip() for c in rest.split("|")]
        baud = int(baud)
        d = telemetry_decimation(baud, n, 500)
        assert cells[0] == f"{bytes_per_s(baud):.0f}"
        assert cells[1] == f"{n * 500}"
        assert cells[2] == f"{link_utilisation(baud, n, 500) * 100:.1f} %"
        assert cells[3] == f"{d}"
        assert cells[4] == f"{500 / d:.0f}"
        assert cells[5] == f"{link_utilisation(baud, n, 500, d) * 100:.1f} %"
        assert cells[6] == f"{n / bytes_per_s(baud) * 1000:.2f}"


def test_doc_states_check_values_and_sizes():
    assert (
        f"0x{frame.crc32(b'123456789'):08X}" in DOC and f"0x{frame.crc8(b'123456789'):02X}" in DOC
    )
    assert f"Overhead: {frame.OVERHEAD_BYTES} bytes per frame" in DOC
    assert f"**no byte has\n   arrived for {frame.RX_SILENCE_S * 1000:.0f} ms**" in DOC
    assert f"The largest frame is {frame.MAX_FRAME_BYTES} bytes" in DOC
    assert f"One `Telemetry` frame is {frame.TELEMETRY_FRAME_BYTES} bytes" in DOC


def test_can_section_matches_the_codec():
    """Section 10's identifier ranges and frames per message follow the message table (they
    went stale when the segment queue's types were added)."""
    from serial_protocol.can_link import DEFAULT_BASE_ID, frames_of_payload

    types = [codec.msg_type for codec in frame._BY_CLASS.values()]
    commands = [t for t in types if t < 0x80]
    answers = [t for t in types if t >= 0x80]
    ranges = (
        f"PC → board 0x{DEFAULT_BASE_ID + min(commands):03X}..0x"
        f"{DEFAULT_BASE_ID + max(commands):03X}, board → PC 0x{DEFAULT_BASE_ID + min(answers):03X}"
        f"..0x{DEFAULT_BASE_ID + max(answers):03X}"
    )
    assert ranges in DOC, f"docs/protocol.md section 10 should say: {ranges}"
    listed = re.search(r"Frames per message: (.*?)\.\s*A payload", DOC, re.S)
    assert listed
    text = " ".join(listed.group(1).split())
    stated = {name: int(n) for name, n in re.findall(r"`(\w+)` (\d+)", text)}
    single = re.search(r"\*\*One frame\*\* for a payload.*?\. (.*?)\.\n", DOC, re.S)
    assert single
    one_frame = set(re.findall(r"`(\w+)`", single.group(1)))
    for cls, codec in frame._BY_CLASS.items():
        n = len(frames_of_payload(codec.msg_type, bytes(codec.payload.size)))
        if n == 1:
            assert cls.__name__ in one_frame, f"section 10: {cls.__name__} is one CAN frame"
        else:
            assert stated.get(cls.__name__) == n, f"section 10: `{cls.__name__}` {n} frames"


# --- docs/architecture.md's message tables and enumerations ------------------------------

ARCH = (Path(__file__).resolve().parents[2] / "docs" / "architecture.md").read_text()
ENUMS = (
    messages.NackCode,
    messages.State,
    messages.Fault,
    messages.FaultFlag,
    messages.Profile,
    messages.Loop,
    messages.QueueAction,
    messages.QueueState,
    messages.StreamAction,
    messages.StreamState,
    messages.Interp,
)


def _arch_rows() -> dict[str, tuple[int, list[str], str]]:
    """``{name: (type code, fields, direction)}`` of architecture.md's two message tables."""
    section = ARCH.split("## Messages", 1)[1]
    rows: dict[str, tuple[int, list[str], str]] = {}
    direction = ""
    for line in section.splitlines():
        head = re.match(r"^\| type \| (PC → board|board → PC) \|", line)
        if head:
            direction = head.group(1)
            continue
        row = re.match(r"^\| 0x([0-9A-F]{2}) \| `(\w+)` \| `([^`]*)` \|", line)
        if row:
            assert row.group(2) not in rows, f"architecture.md lists {row.group(2)} twice"
            fields = [f.strip() for f in row.group(3).split(",")]
            rows[row.group(2)] = (int(row.group(1), 16), fields, direction)
    return rows


def test_architecture_message_tables_match_the_codec():
    """Every message of the codec is in docs/architecture.md's tables, in the right one,
    with its type code and its fields in wire order; nothing else is (the tables went stale
    once: Status, SetLimits and the NACK codes of protocol v2 were missing)."""
    rows = _arch_rows()
    codecs = {cls.__name__: (cls, codec) for cls, codec in frame._BY_CLASS.items()}
    assert sorted(rows) == sorted(codecs)
    for name, (code, fields, direction) in rows.items():
        cls, codec = codecs[name]
        assert code == codec.msg_type, f"{name}: type 0x{codec.msg_type:02X}"
        assert direction == ("PC → board" if codec.msg_type < 0x80 else "board → PC"), name
        assert fields == [f.name for f in frame.wire_fields(cls)], f"{name}: fields"


@pytest.mark.parametrize("enum", ENUMS, ids=lambda e: e.__name__)
def test_architecture_enumerations_match_the_code(enum):
    line = re.search(rf"^- `{enum.__name__}`: `([^`]*)`$", ARCH, re.M)
    assert line, f"docs/architecture.md lists no `{enum.__name__}`"
    assert line.group(1) == ", ".join(f"{m.name} ({int(m)})" for m in enum)


def test_protocol_enumeration_tables_match_the_code():
    """docs/protocol.md 4.2: the NackCode and Fault tables (code, name, flag bit) and the
    small enumeration tables hold every member of the code's enumerations, and no other."""
    nack_part = DOC[DOC.index("`NackCode` (u8):") : DOC.index("**The travel tolerance.**")]
    nacks = re.findall(r"^\| (\d+) \| ([A-Z_]+) \|", nack_part, re.M)
    assert [(int(c), n) for c, n in nacks] == [(int(m), m.name) for m in messages.NackCode]
    fault_part = DOC[DOC.index("`Fault` (u8):") : DOC.index("`fault_flags` (u32)")]
    faults = re.findall(
        r"^\| (\d+) \| ([A-Z_]+) \| (—|(\d+) \(0x([0-9A-F]{8})\)) \|", fault_part, re.M
    )
    assert sorted((int(c), n) for c, n, *_ in faults) == [(int(m), m.name) for m in messages.Fault]
    for _code, name, _, bit, mask in faults:
        if name == "NONE":
            continue
        flag = messages.FaultFlag[name]
        assert int(bit) == int(flag).bit_length() - 1 and int(mask, 16) == int(flag), name
    # The side-by-side tables: each enumeration's column pairs (code, name).
    small = [e for e in ENUMS if e not in (messages.NackCode, messages.Fault, messages.FaultFlag)]
    for enum in small:
        table = re.search(
            rf"^\|[^\n]*`{enum.__name__}` \(u8\)[^\n]*\n\|[-|]+\|\n((?:\|.*\n)+)", DOC, re.M
        )
        assert table, f"docs/protocol.md has no `{enum.__name__}` (u8) table"
        header = [c.strip() for c in table.group(0).splitlines()[0].strip("|").split("|")]
        col = header.index(f"`{enum.__name__}` (u8)")
        found = []
        for line in table.group(1).splitlines():
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if cells[col]:
                found.append((int(cells[col]), cells[col + 1].split(" ")[0]))
        assert found == [(int(m), m.name) for m in enum], enum.__name__


def _names(text: str) -> list[str]:
    return re.findall(r"`(\w+)`", text)


def test_protocol_lists_of_messages_match_the_code():
    """The lists in docs/protocol.md's prose that name messages by a property of the code:
    the mutating commands of the duplicate rule (5.3), the messages with appended fields
    (section 6 and section 11's rows), the type ranges (section 13)."""
    from firmware_model.firmware import _MUTATING

    mutating = re.search(r"a mutating command \((.*?)\)\s+whose type", DOC, re.S)
    assert mutating and sorted(_names(mutating.group(1))) == sorted(c.__name__ for c in _MUTATING)
    extended = [cls for cls, c in frame._BY_CLASS.items() if c.min_size < c.payload.size]
    answers = sorted(c.__name__ for c in extended if frame._BY_CLASS[c].msg_type >= 0x80)
    commands = sorted(c.__name__ for c in extended if frame._BY_CLASS[c].msg_type < 0x80)
    section6 = re.search(r"appended fields in board → PC messages \((.*?)\) and in one command,"
                         r"\s+`(\w+)`", DOC, re.S)  # fmt: skip
    assert section6
    assert sorted(_names(section6.group(1))) == answers and [section6.group(2)] == commands
    row = re.search(r"^\| \(PC side\) a (.*?) that ends after", DOC, re.M)
    assert row and sorted(_names(row.group(1))) == answers
    for name in commands:
        assert re.search(rf"^\| a `{name}` that ends after its version 2.0 fields", DOC, re.M)
    types = [c.msg_type for c in frame._BY_CLASS.values()]
    ranges = (
        f"0x{min(t for t in types if t < 0x80):02X}..0x{max(t for t in types if t < 0x80):02X}, "
        f"0x{min(t for t in types if t >= 0x80):02X}..0x{max(t for t in types if t >= 0x80):02X}"
    )
    assert f"| message numbering | 0x01..0x0B, 0x81..0x88 | {ranges} (section 4) |" in DOC


def test_protocol_states_the_payload_ceiling_and_the_room_left():
    """Section 2's 64-byte ceiling is the codec's, and section 6's room to append lists the
    four longest payloads with their size and what is left of the ceiling."""
    top = frame.MAX_PAYLOAD_BYTES
    assert f"payload length in bytes, 0..{top}" in DOC
    assert (
        f"with `len > {top}` is invalid" in DOC and f"reject the candidate if `len > {top}`" in DOC
    )
    room = re.search(
        r"\*\*Room to append\.\*\* A payload is at most (\d+) bytes(.*?)\n-", DOC, re.S
    )
    assert room and int(room.group(1)) == top
    listed = re.findall(r"`(\w+)` (\d+) \((\d+)", " ".join(room.group(2).split()))
    longest = sorted(frame._BY_CLASS.items(), key=lambda kv: -kv[1].payload.size)[:4]
    want = [(cls.__name__, c.payload.size, top - c.payload.size) for cls, c in longest]
    assert [(n, int(size), int(left)) for n, size, left in listed] == want, (
        f"docs/protocol.md section 6, 'Room to append', should list (name, payload, left): {want}"
    )
