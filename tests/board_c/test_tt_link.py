"""The C board-side codec (board_c/), built with the system C compiler and driven through
its command-line harness, against the Python codec and the conformance vectors.

- framing: any payload under any type and sequence number frames to the same bytes;
- receiving: any stream (frames, garbage, corruption, truncation, fake headers, silences,
  any chunking) gives the same frames and the same counters as ``frame.Decoder``;
- commands: any payload under any command type decodes to the same fields, or to the same
  NACK code and field as ``Malformed``;
- answers: every board -> PC message encodes to the bytes the Python codec gives;
- the C builds without floating point (``-mgeneral-regs-only``) and without warnings.
"""

from __future__ import annotations

import json
import shutil
import struct
import subprocess
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from serial_protocol import frame, messages
from serial_protocol.frame import (
    MAX_PAYLOAD_BYTES,
    Decoder,
    decode_payload,
    frame_raw,
    payload_size_of_type,
    wire_fields,
)
from serial_protocol.messages import Malformed, MsgType

ROOT = Path(__file__).resolve().parents[2]
BOARD_C = ROOT / "board_c"
SOURCES = [BOARD_C / "tt_link.c", BOARD_C / "harness.c"]
WARNINGS = ["-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wconversion", "-Werror"]
COMMANDS = [t for t in MsgType if t < 0x80]
ANSWERS = [t for t in MsgType if t >= 0x80]
_INT_FMT = {"u8": "B", "u16": "H", "u32": "I", "i16": "h", "i32": "i", "f32": "I"}


def _compiler() -> str | None:
    return shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")


class Harness:
    """The compiled harness as a coprocess: one line in, its answer lines out."""

    def __init__(self, exe: Path) -> None:
        self.proc = subprocess.Popen(
            [str(exe)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1
        )

    def ask(self, *lines: str) -> list[str]:
        """Send ``lines`` then ``C``; return every output line up to the counters."""
        for line in (*lines, "C"):
            self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        out = []
        while True:
            line = self.proc.stdout.readline()
            assert line, "the harness died"
            out.append(line.rstrip("\n"))
            if line.startswith("stats "):
                return out

    def one(self, line: str) -> str:
        """A command that prints one line (E, M)."""
        return self.ask(line)[0]

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=10)


@pytest.fixture(scope="module")
def harness(tmp_path_factory):
    cc = _compiler()
    if cc is None:
        pytest.skip("no C compiler on this machine (.ci/run installs gcc)")
    exe = tmp_path_factory.mktemp("board_c") / "tt_harness"
    build = subprocess.run(
        [cc, *WARNINGS, "-O2", *map(str, SOURCES), "-o", str(exe)], capture_output=True, text=True
    )
    assert build.returncode == 0, build.stderr
    h = Harness(exe)
    yield h
    h.close()


def test_the_codec_has_no_floating_point_and_no_warnings(tmp_path):
    """The framing path and the codec move f32 fields as bit patterns: compiled with the
    general registers only (x86: no SSE/x87), any float operation would not build."""
    cc = _compiler()
    if cc is None:
        pytest.skip("no C compiler on this machine (.ci/run installs gcc)")
    flags = ["-mgeneral-regs-only"] if "86" in _machine(cc) else []
    build = subprocess.run(
        [cc, *WARNINGS, "-O2", *flags, "-c", str(SOURCES[0]), "-o", str(tmp_path / "t.o")],
        capture_output=True,
        text=True,
    )
    assert build.returncode == 0, build.stderr
    assert "malloc" not in SOURCES[0].read_text()


def _machine(cc: str) -> str:
    return subprocess.run([cc, "-dumpmachine"], capture_output=True, text=True).stdout


# ------------------------------------------------------------------ framing


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 255), st.integers(0, 255), st.binary(max_size=MAX_PAYLOAD_BYTES))
def test_frames_are_the_python_codec_s(harness, msg_type, seq, payload):
    assert harness.one(f"E {msg_type} {seq} {payload.hex() or '-'}") == (
        frame_raw(msg_type, payload, seq).hex()
    )


def test_an_over_long_payload_is_refused(harness):
    assert harness.one(f"E 130 0 {bytes(65).hex()}").startswith("error")


def test_the_check_values_of_the_spec(harness):
    """docs/protocol.md section 2: crc8("123456789") = 0xF4, crc32("123456789") =
    0xCBF43926."""
    assert harness.one(f"K {b'123456789'.hex()}") == f"crc {0xF4} {0xCBF43926}"


# ------------------------------------------------------------------ receiving

_frames = st.tuples(st.integers(0, 255), st.binary(max_size=40), st.integers(0, 255)).map(
    lambda t: frame_raw(*t)
)


@st.composite
def _streams(draw) -> list[tuple[str, bytes]]:
    """Chunks of a noisy stream and silences: [("F", bytes) | ("S", b"")]."""
    parts = []
    for _ in range(draw(st.integers(1, 12))):
        kind = draw(st.sampled_from(["frame", "frame", "frame", "garbage", "flip", "cut", "fake"]))
        f = draw(_frames)
        if kind == "frame":
            parts.append(f)
        elif kind == "garbage":
            parts.append(draw(st.binary(max_size=20)))
        elif kind == "flip":
            k = draw(st.integers(0, len(f) * 8 - 1))
            parts.append(f[: k // 8] + bytes((f[k // 8] ^ (1 << (k % 8)),)) + f[k // 8 + 1 :])
        elif kind == "cut":
            parts.append(f[: draw(st.integers(0, len(f) - 1))])
        else:  # a header that passes its check and claims up to the longest payload
            length = draw(st.integers(0, MAX_PAYLOAD_BYTES))
            parts.append(frame_raw(0x82, bytes(length), 0)[:6])
    stream = b"".join(parts)
    cuts = sorted(draw(st.lists(st.integers(0, len(stream)), max_size=8)))
    out: list[tuple[str, bytes]] = []
    last = 0
    for c in [*cuts, len(stream)]:
        out.append(("F", stream[last:c]))
        last = c
        if draw(st.integers(0, 4)) == 0:
            out.append(("S", b""))
    return out


def _python(ops: list[tuple[str, bytes]]) -> tuple[list, tuple]:
    decoder = Decoder()
    msgs: list = []
    for op, data in ops:
        msgs += decoder.feed(data) if op == "F" else decoder.flush()
    s = decoder.stats()
    counters = (
        s.frames, s.header_errors, s.crc_errors, s.resyncs, s.bytes_dropped, s.seq_gaps,
        s.frames_missed, s.partial_discards, decoder.pending_bytes,
    )  # fmt: skip
    return msgs, counters


def _c(harness: Harness, ops: list[tuple[str, bytes]]) -> tuple[list, tuple, list[str]]:
    lines = ["R"] + [f"F {data.hex() or '-'}" if op == "F" else "S" for op, data in ops]
    out = harness.ask(*lines)
    msgs = []
    cmds = []
    for line in out[:-1]:
        word, *rest = line.split()
        if word == "frame":
            msg_type, seq, payload = int(rest[0]), int(rest[1]), rest[2]
            data = b"" if payload == "-" else bytes.fromhex(payload)
            msgs.append(decode_payload(msg_type, data, seq))
        elif word == "cmd":
            cmds.append(line)
    counters = tuple(int(x) for x in out[-1].split()[1:])
    return msgs, counters, cmds


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_streams())
def test_any_stream_gives_the_python_decoder_s_frames_and_counters(harness, ops):
    py_msgs, py_counters = _python(ops)
    c_msgs, c_counters, _ = _c(harness, ops)
    # compared as text: a NaN field (a Stop's a_max_dps2 from random bytes) is never == itself
    assert repr(c_msgs) == repr(py_msgs)
    assert c_counters == py_counters


def test_the_silence_rule_counts_servo_ticks(harness):
    """tt_decoder_tick: a false header is given up after 10 ticks without a byte, not 9,
    and the command after it is delivered."""
    fake = frame_raw(0x82, bytes(64), 0)[:6]
    good = frame_raw(MsgType.GET_STATUS, bytes(4), 1)
    out = harness.ask("R", f"F {fake.hex()}", "T 1", *["T 0"] * 9)
    assert out[-1].split()[-1] == "6"  # still held after 9 quiet ticks
    out = harness.ask("T 0", f"F {good.hex()}")
    assert out[0].startswith(f"frame {int(MsgType.GET_STATUS)} 1 ")
    assert out[-1].split()[8] == "1"  # one silence discard


# ------------------------------------------------------------------ commands


_CLASS_OF_TYPE = {
    cls.MSG_TYPE: cls
    for cls in vars(messages).values()
    if isinstance(cls, type) and isinstance(getattr(cls, "MSG_TYPE", None), int)
}


def _layout(msg_type: int) -> tuple[str, list]:
    """The struct format (f32 as u32) and the fields of a type, from Python's table."""
    fields = wire_fields(_CLASS_OF_TYPE[msg_type])
    return "<" + "".join(_INT_FMT[f.wire] for f in fields), list(fields)


@settings(max_examples=400, deadline=None)
@given(
    st.one_of(st.sampled_from(COMMANDS), st.sampled_from(ANSWERS), st.integers(0, 255)),
    st.data(),
)
def test_any_payload_decodes_as_the_python_codec_decodes_it(harness, msg_type, data):
    """Under any type: the same NACK code and field as Python's Malformed (unknown type,
    short payload, undefined enum byte), NOT_A_COMMAND for a board -> PC type, else the same
    field values (f32 as bit patterns), with any extra bytes of a newer version ignored."""
    size = payload_size_of_type(msg_type)
    if size is not None and data.draw(st.booleans()):
        # SetLimits: from its version 2.0 length on (an older PC's shorter payloads too)
        low = frame._BY_TYPE[msg_type].min_size if msg_type < 0x80 else size
        payload = data.draw(st.binary(min_size=low, max_size=min(size + 6, MAX_PAYLOAD_BYTES)))
    else:
        payload = data.draw(st.binary(max_size=MAX_PAYLOAD_BYTES))
    _, _, cmds = _c(harness, [("F", frame_raw(msg_type, payload, 0))])
    (line,) = cmds
    code, field, cmd_id, session, *values = (int(x) for x in line.split()[1:])
    py = decode_payload(msg_type, payload)
    if len(payload) >= 2:
        assert cmd_id == int.from_bytes(payload[:2], "little")
    if msg_type >= 0x80:
        assert code == 8  # NOT_A_COMMAND: the board never takes a board -> PC type
        return
    if isinstance(py, Malformed):
        assert (code, field) == (int(py.code), py.field)
        if int(py.code) != 4:  # OUT_OF_RANGE still reports the fields it read
            return
    else:
        assert (code, field) == (0, 255)
    fmt, _ = _layout(msg_type)
    # an older PC's payload: the appended fields it lacks are 0 (the extension rule)
    wire = struct.unpack_from(fmt, payload + bytes(max(0, struct.calcsize(fmt) - len(payload))))
    assert (cmd_id, session, *values) == wire


# ------------------------------------------------------------------ answers


def _wire_value(wire: str):
    return {
        "u8": st.integers(0, 0xFF),
        "u16": st.integers(0, 0xFFFF),
        "u32": st.integers(0, 0xFFFFFFFF),
        "f32": st.integers(0, 0xFFFFFFFF),
        "i16": st.integers(-(2**15), 2**15 - 1),
        "i32": st.integers(-(2**31), 2**31 - 1),
    }[wire]


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(ANSWERS), st.integers(0, 255), st.data())
def test_every_answer_encodes_as_the_python_codec_encodes_it(harness, msg_type, seq, data):
    fmt, fields = _layout(msg_type)
    values = [data.draw(_wire_value(f.wire)) for f in fields]
    line = harness.one(f"M {msg_type} {seq} " + " ".join(str(v) for v in values))
    expected = frame_raw(msg_type, struct.pack(fmt, *values), seq)
    assert line == expected.hex()


def test_every_answer_type_and_command_type_is_covered():
    assert set(ANSWERS) == {t for t in MsgType if t >= 0x80}
    assert {int(t) for t in COMMANDS} == set(range(1, 1 + len(COMMANDS)))


# ------------------------------------------------------------------ conformance vectors

VECTORS = ROOT / "docs" / "conformance" / "vectors.json"


def _vectors() -> dict:
    return json.loads(VECTORS.read_text())


@pytest.mark.skipif(not VECTORS.exists(), reason="docs/conformance/vectors.json not written")
def test_the_conformance_frames(harness):
    """Every frame of the vectors: the C decoder finds it, and frames it back to the same
    bytes from its type, sequence number and payload."""
    for vector in _vectors()["frames"]:
        raw = bytes.fromhex(vector["hex"])
        out = harness.ask("R", f"F {raw.hex()}")
        (frame_line,) = [x for x in out if x.startswith("frame ")]
        _, msg_type, seq, payload = frame_line.split()
        assert (int(msg_type), int(seq)) == (vector["type_byte"], vector["seq"])
        assert harness.one(f"E {msg_type} {seq} {payload}") == raw.hex()


@pytest.mark.skipif(not VECTORS.exists(), reason="docs/conformance/vectors.json not written")
def test_the_conformance_streams(harness):
    """Every stream of the vectors: the messages and counters the vectors expect, the same
    as the Python decoder gives."""
    for vector in _vectors()["streams"]:
        ops = [("F", bytes.fromhex(vector["hex"]))]
        if vector.get("flush"):
            ops.append(("S", b""))
        c_msgs, c_counters, _ = _c(harness, ops)
        py_msgs, py_counters = _python(ops)
        assert c_msgs == py_msgs and c_counters == py_counters, vector.get("name")
