"""``turntable-sim monitor URL`` against a TCP board (socket://), and its command parser."""

from __future__ import annotations

import argparse
import csv
import socket
import threading

import pytest

from serial_protocol.exceptions import CommandError
from serial_protocol.frame import Decoder, encode
from serial_protocol.messages import (
    Ack,
    Fault,
    Hello,
    HelloReply,
    Loop,
    Move,
    Profile,
    SetGains,
    State,
    Stop,
    Telemetry,
)
from sim.commands import monitor


class TcpBoard(threading.Thread):
    """Answers Hello and every command, streams telemetry every 5 ms of wall time."""

    def __init__(self) -> None:
        super().__init__(daemon=True)
        self.server = socket.create_server(("127.0.0.1", 0))
        self.url = f"socket://127.0.0.1:{self.server.getsockname()[1]}"
        self.received: list = []

    def run(self) -> None:
        conn, _ = self.server.accept()
        conn.settimeout(0.005)
        decoder, seq, tick = Decoder(), 0, 0
        with conn:
            while True:
                try:
                    data = conn.recv(4096)
                    if not data:
                        return
                except TimeoutError:
                    data = b""
                out = b""
                for msg in decoder.feed(data):
                    self.received.append(msg)
                    if isinstance(msg, Hello):
                        reply = HelloReply(msg.cmd_id, msg.session, 2, 0, 1, 0, 500, 16384, 0,
                                           64, 256, 32, 1, 0, 0, 20, 460800)  # fmt: skip
                    else:
                        reply = Ack(msg.cmd_id, msg.MSG_TYPE)
                    out += encode(reply, seq)
                    seq += 1
                tick += 2
                out += encode(
                    Telemetry(tick, 1.0, 2.0, 3.0, 4.0, 0.5, 0.1, State.MOVING, Fault.NONE), seq
                )
                seq += 1
                try:
                    conn.sendall(out)
                except OSError:
                    return


def run_monitor(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    monitor.add_arguments(parser)
    return monitor.main(parser.parse_args(argv))


def test_monitor_sends_commands_records_csv_and_reports(tmp_path, capsys):
    board = TcpBoard()
    board.start()
    out_csv = tmp_path / "tel.csv"
    capture = tmp_path / "raw.bin"
    argv = [
        board.url,
        "--move", "3000", "--v-max", "990", "--a-max", "148",
        "--gains", "velocity", "0.5", "2", "0",
        "--interrupt", "0.1", "-8000",
        "--stop", "0.2",
        "--duration", "0.3",
        "--csv", str(out_csv),
        "--capture", str(capture),
        "--ack-timeout", "2",
        "--quiet",
    ]  # fmt: skip
    assert run_monitor(argv) == 0
    board.join(timeout=5)
    commands = board.received
    assert isinstance(commands[0], Hello)
    session = commands[0].session
    assert session != 0 and all(m.session == session for m in commands)
    assert commands[1] == SetGains(commands[1].cmd_id, Loop.VELOCITY, 0.5, 2.0, 0.0, session)
    moves = [m for m in commands if isinstance(m, Move)]
    assert [m.target_deg for m in moves] == [3000.0, -8000.0]
    assert moves[0].profile is Profile.TRAPEZOID and moves[0].a_max_dps2 == 148.0
    assert isinstance(commands[-1], Stop)
    rows = list(csv.DictReader(out_csv.open()))
    assert len(rows) > 10
    assert {r["state"] for r in rows} == {"MOVING"}
    # issue #15 §5: the measured current has one name in every CSV, never a bare current_a
    assert "current_meas_a" in rows[0] and "current_a" not in rows[0]
    from sim.capture import read_chunks

    with open(capture, "rb") as f:
        chunks = list(read_chunks(f))
    times = [t for t, _ in chunks]
    assert times == sorted(times) and 0.0 <= times[0] and times[-1] < 30.0  # arrival times
    decoder = Decoder()
    decoded = [m for _, data in chunks for m in decoder.feed(data)]
    assert sum(isinstance(m, Telemetry) for m in decoded) >= len(rows)  # all of it
    assert decoder.stats().crc_errors == 0 and decoder.stats().bytes_dropped == 0
    report = capsys.readouterr().out
    assert "commands 5: acks 4, nacks 0, retries 0, timeouts 0" in report
    assert "crc errors 0" in report and f"wrote {len(rows)} telemetry rows" in report


def test_monitor_without_a_board_fails_cleanly():
    server = socket.create_server(("127.0.0.1", 0))  # accepts, never answers
    url = f"socket://127.0.0.1:{server.getsockname()[1]}"
    with pytest.raises(CommandError, match="no board answers"):
        run_monitor([url, "--ack-timeout", "0.01", "--retries", "1", "--quiet"])
    server.close()


def test_bad_timeouts_are_usage_errors(capsys):
    from sim import cli

    assert cli.main(["monitor", "loop://", "--ack-timeout", "0"]) == 2
    assert "argument --ack-timeout: '0': must be > 0" in capsys.readouterr().err
    assert cli.main(["monitor", "loop://", "--retries", "-1"]) == 2
    assert "argument --retries: '-1': must be in 0 .. 100" in capsys.readouterr().err


class RecordingClient:
    def __getattr__(self, name):
        return lambda *a, **k: (name, a, k)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (
            "move 100",
            (
                "move",
                (),
                {
                    "target_deg": 100.0,
                    "v_max_dps": 990.0,
                    "a_max_dps2": 148.0,
                    "j_max_dps3": 0.0,
                    "profile": Profile.TRAPEZOID,
                },
            ),
        ),
        (
            "move -5 10 20 30 scurve",
            (
                "move",
                (),
                {
                    "target_deg": -5.0,
                    "v_max_dps": 10.0,
                    "a_max_dps2": 20.0,
                    "j_max_dps3": 30.0,
                    "profile": Profile.SCURVE,
                },
            ),
        ),
        ("stop", ("stop", (), {})),
        ("stop 50", ("stop", (50.0,), {})),
        (
            "gains position 3 0 0",
            ("set_gains", (Loop.POSITION,), {"kp": 3.0, "ki": 0.0, "kd": 0.0}),
        ),
        ("getgains current", ("get_gains", (Loop.CURRENT,), {})),
        (
            "limits 990 148 5 10",
            (
                "set_limits",
                (),
                {
                    "v_max_dps": 990.0,
                    "a_max_dps2": 148.0,
                    "current_limit_a": 5.0,
                    "following_error_deg": 10.0,
                },
            ),
        ),
        (
            "limits 990 148 5 10 0 26.5 0 90 110",
            (
                "set_limits",
                (),
                {
                    "v_max_dps": 990.0,
                    "a_max_dps2": 148.0,
                    "current_limit_a": 5.0,
                    "following_error_deg": 10.0,
                    "over_current_trip_a": 0.0,
                    "bus_over_voltage_v": 26.5,
                    "bus_under_voltage_v": 0.0,
                    "thermal_derate_c": 90.0,
                    "thermal_trip_c": 110.0,
                },
            ),
        ),
        (
            "limits 990 148 5 10 0 0 0 0 0 5",
            (
                "set_limits",
                (),
                {
                    "v_max_dps": 990.0,
                    "a_max_dps2": 148.0,
                    "current_limit_a": 5.0,
                    "following_error_deg": 10.0,
                    "over_current_trip_a": 0.0,
                    "bus_over_voltage_v": 0.0,
                    "bus_under_voltage_v": 0.0,
                    "thermal_derate_c": 0.0,
                    "thermal_trip_c": 0.0,
                    "brake_current_limit_a": 5.0,
                },
            ),
        ),
        ("telemetry 2", ("set_telemetry", (2,), {})),
        ("clear", ("clear_fault", (), {})),
        ("enable", ("set_enable", (True,), {})),
    ],
)
def test_parse_command(text, expected):
    assert monitor.parse_command(RecordingClient(), text)() == expected


@pytest.mark.parametrize(
    "text",
    [
        "",
        "fly 3",
        "move",
        "move x",
        "gains elbow 1 2 3",
        "stop 1 2",
        "clear 3",
        "move nan",
        "move 1e400",
        "move 10 -inf",
        "telemetry 2.5",
        "telemetry -1",
        "move 1 2 3 scurve",
        "move 'unclosed",
        "help",
        "quit",
    ],  # fmt: skip
)
def test_parse_command_rejects_bad_input(text):
    with pytest.raises(CommandError):
        monitor.parse_command(RecordingClient(), text)


def test_monitor_over_can_virtual_bus_and_decode_its_log(tmp_path, capsys):
    import uuid

    from serial_protocol.can_link import CanLink
    from sim.commands import decode

    channel = f"monitor-{uuid.uuid4().hex}"
    log, out_csv = tmp_path / "run.blf", tmp_path / "live.csv"
    board = CanLink.open("virtual", channel)
    stop = threading.Event()
    received = []

    def serve() -> None:
        tick = 0
        while not stop.is_set():
            for msg in board.poll(0.01):
                received.append(msg)
                if isinstance(msg, Hello):
                    board.send(HelloReply(msg.cmd_id, msg.session, 2, 0, 1, 0, 500, 16384, 0,
                                          64, 256, 32, 1, 0, 0, 20, 460800))  # fmt: skip
                else:
                    board.send(Ack(msg.cmd_id, msg.MSG_TYPE))
            tick += 5
            board.send(Telemetry(tick, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, State.IDLE, Fault.NONE))

    worker = threading.Thread(target=serve, daemon=True)
    worker.start()
    try:
        argv = [f"can://virtual/{channel}", "--move", "90", "--duration", "0.2", "--quiet"]
        argv += ["--ack-timeout", "2"]
        argv += ["--capture", str(log), "--csv", str(out_csv)]
        assert run_monitor(argv) == 0
    finally:
        stop.set()
        worker.join(timeout=5)
        board.close()
    assert [type(m) for m in received] == [Hello, Move]
    assert received[1].target_deg == 90.0
    report = capsys.readouterr().out
    assert "commands 2: acks 1" in report and "reassembly errors 0" in report
    # the BLF log written by python-can decodes to the same telemetry as the live CSV
    parser = argparse.ArgumentParser()
    decode.add_arguments(parser)
    assert decode.main(parser.parse_args([str(log), "-o", str(tmp_path / "log.csv")])) == 0
    live = out_csv.read_text().splitlines()
    logged = (tmp_path / "log.csv").read_text().splitlines()
    assert len(live) > 3 and logged[: len(live)] == live
    report = capsys.readouterr().out
    assert "HelloReply     1" in report and "Hello          1" in report
    assert "Move           1" in report and "reassembly errors 0" in report


def test_interactive_session_from_stdin():
    import subprocess
    import sys

    board = TcpBoard()
    board.start()
    script = (
        "help\nhelp move\nstatus\nmove 45 100 200\nfly away\nmove nan\nmove 1e400\n"
        "gains position 2 0 0\nquit\n"
    )
    done = subprocess.run(
        [sys.executable, "-m", "sim.cli", "monitor", board.url, "--interactive",
         "--ack-timeout", "2", "--quiet"],
        input=script, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    board.join(timeout=5)
    assert done.returncode == 0, done.stderr
    assert "move the gearmotor output shaft" in done.stdout  # the help text
    assert "usage: move TARGET_DEG" in done.stdout  # help for one command
    assert "error: 'fly away': unknown command" in done.stdout
    assert "error: 'move nan': target_deg = 'nan' is not a finite number" in done.stdout
    assert "error: 'move 1e400': target_deg = '1e400' is not a finite number" in done.stdout
    assert "move: ok" in done.stdout and "gains: ok" in done.stdout  # replies in words
    names = [type(m).__name__ for m in board.received]
    assert names == ["Hello", "GetStatus", "Move", "SetGains"]
    assert board.received[2] == Move(board.received[2].cmd_id, 45.0, 100.0, 200.0,
                                     session=board.received[0].session)  # fmt: skip
    assert "commands 4: acks 3" in done.stdout


def test_gains_from_a_tuned_toml_reach_the_board_in_one_step(tmp_path, capsys, monkeypatch):
    import io
    from pathlib import Path

    from sim.tuning.gains import GainSet
    from sim.tuning.report import write_tuned_toml

    bench = Path(__file__).resolve().parents[3] / "bench_configs" / "paper_bench.toml"
    tuned = GainSet(0.1, 150.0, 0.06, 1.5, 12.0)
    toml = write_tuned_toml(bench, tmp_path / "tuned.toml", tuned, "tuned (test)")
    # the monitor reads commands from a pipe after the scripted ones: read the gains back
    monkeypatch.setattr("sys.stdin", io.StringIO("getgains current\ngetgains velocity\n"
                                                   "getgains position\nquit\n"))  # fmt: skip
    argv = ["sim://", "--gains-from", str(toml), "--interactive", "--ack-timeout", "2"]
    assert run_monitor(argv) == 0
    out = capsys.readouterr().out
    assert out.count(": ok") == 3  # three SetGains acknowledged
    assert "getgains: current loop: kp 0.1, ki 150, kd 0" in out
    assert "getgains: velocity loop: kp 0.06, ki 1.5, kd 0" in out
    assert "getgains: position loop: kp 12, ki 0, kd 0" in out


def test_a_bad_gains_file_sends_nothing(tmp_path):
    from serial_protocol.exceptions import ConfigError

    bad = tmp_path / "bad.toml"
    bad.write_text("[controller.velocity]\nkp_a_per_dps = 'x'\n")
    server = socket.create_server(("127.0.0.1", 0))  # would accept, but is never reached
    url = f"socket://127.0.0.1:{server.getsockname()[1]}"
    with pytest.raises(ConfigError, match="bad.toml"):
        run_monitor([url, "--gains-from", str(bad), "--quiet"])
    server.settimeout(0.0)
    with pytest.raises(BlockingIOError):
        server.accept()  # nobody connected
    server.close()


def test_limits_option_takes_four_to_ten_numbers(capsys):
    # The appended thresholds of SetLimits after the four motion limits; a wrong count is
    # one line and exit 2, before any board is opened.
    from sim import cli

    assert cli.main(["monitor", "loop://", "--limits", "990", "148", "5"]) == 2
    err = capsys.readouterr().err
    assert "--limits 990.0 148.0 5.0: takes 4 to 10 numbers" in err and "Traceback" not in err
    eleven = ["990", "148", "5", "10", "0", "26", "0", "90", "110", "5", "1"]
    assert cli.main(["monitor", "loop://", "--limits", *eleven]) == 2
    assert "takes 4 to 10 numbers" in capsys.readouterr().err
