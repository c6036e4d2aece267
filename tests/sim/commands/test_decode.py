"""``turntable-sim decode FILE``: a captured stream to CSV, with statistics."""

from __future__ import annotations

import argparse
import csv

import pytest

from serial_protocol.exceptions import CommandError
from serial_protocol.frame import encode, frame_raw
from serial_protocol.messages import Ack, Fault, FaultReport, MsgType, State, Telemetry
from serial_protocol.telemetry_csv import TELEMETRY_CSV_COLUMNS
from sim.commands import decode


def run_decode(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    decode.add_arguments(parser)
    return decode.main(parser.parse_args(argv))


def telemetry(tick: int) -> Telemetry:
    return Telemetry(tick, tick / 100, 2.0, tick / 200, 1.0, 0.5, 0.25, State.MOVING, Fault.NONE)


def test_decode_capture_to_csv(tmp_path, capsys):
    ticks = [0, 2, 4, 6, 10, 12]  # decimation 2, telemetry for tick 8 lost on the line
    frames = [encode(telemetry(t), seq) for seq, t in enumerate(ticks)]
    frames[4] = encode(telemetry(10), 5)  # the lost frame took seq 4
    frames[5] = encode(telemetry(12), 6)
    data = (
        b"\xff\x00"
        + b"".join(frames[:3])
        + encode(Ack(7, MsgType.MOVE), 3)
        + frames[3][:-1]  # tick 6: last byte lost, CRC fails
        + frames[4]
        + encode(FaultReport(11, Fault.OVER_CURRENT, 6.5), 6)
        + frame_raw(0x42, b"\x01\x00", 7)  # good CRC, unknown type
    )
    path = tmp_path / "capture.bin"
    path.write_bytes(data)
    out_csv = tmp_path / "out.csv"
    assert run_decode([str(path), "-o", str(out_csv), "--messages"]) == 0
    rows = list(csv.DictReader(out_csv.open()))
    assert tuple(rows[0]) == TELEMETRY_CSV_COLUMNS
    assert [int(r["tick"]) for r in rows] == [0, 2, 4, 10]
    assert [float(r["pos_deg"]) for r in rows] == [t / 200 for t in (0, 2, 4, 10)]
    assert rows[0]["state"] == "MOVING" and rows[3]["t_s"] == "0.020000"
    report = capsys.readouterr().out
    assert "Ack(cmd_id=7" in report and "FaultReport(tick=11" in report
    assert "Malformed(msg_type=66" in report
    assert "crc errors 1" in report
    assert "telemetry every 2 ticks; 1 irregular steps" in report
    assert "wrote 4 telemetry rows" in report


def test_decode_defaults_to_file_dot_csv(tmp_path):
    path = tmp_path / "cap.raw"
    path.write_bytes(b"".join(encode(telemetry(t), t) for t in range(5)))
    assert run_decode([str(path)]) == 0
    assert len((tmp_path / "cap.raw.csv").read_text().splitlines()) == 6


def test_decode_missing_file_is_a_command_error(tmp_path):
    with pytest.raises(CommandError, match="cannot read"):
        run_decode([str(tmp_path / "nope.bin")])
