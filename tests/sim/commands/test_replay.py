"""``turntable-sim replay``: a capture played back at its recorded pace (the pacing checked
on a fake clock, never on the wall clock), to stdout (into ``decode -``), to a TCP port, and
a CAN log to a virtual CAN bus."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import uuid
from pathlib import Path

import numpy as np
import pytest

from serial_protocol.frame import Decoder, encode
from serial_protocol.messages import Fault, State, Telemetry
from sim import cli
from sim.capture import TimestampedCapture
from sim.commands.replay import raw_times, schedule

ROOT = Path(__file__).resolve().parents[3]


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        self.sleeps.append(s)
        self.now += s


def test_schedule_keeps_the_recorded_times_scaled_by_speed():
    clock = FakeClock()
    items = [(5.0, "a"), (5.5, "b"), (7.0, "c")]
    out = []
    for item in schedule(items, 2.0, clock=clock, sleep=clock.sleep):
        out.append((item, clock.now - 100.0))
    assert out == [("a", 0.0), ("b", 0.25), ("c", 1.0)]


def test_a_late_item_goes_at_once_and_does_not_delay_the_rest():
    clock = FakeClock()
    got = []
    for item in schedule([(0.0, 1), (1.0, 2), (2.0, 3)], 1.0, clock=clock, sleep=clock.sleep):
        got.append(clock.now - 100.0)
        if item == 1:
            clock.now += 1.5  # the receiver blocked for 1.5 s
    assert got == [0.0, 1.5, 2.0]


def test_infinite_speed_never_sleeps():
    clock = FakeClock()
    assert list(schedule([(0.0, 1), (9.0, 2)], float("inf"), clock=clock, sleep=clock.sleep)) == [
        1,
        2,
    ]
    assert clock.sleeps == []


def test_raw_captures_are_paced_by_the_baud_rate():
    timed = list(raw_times([(0.0, bytes(1000))], 10_000))  # 1 ms of line = 1 byte at 10 kBd
    assert sum(len(d) for _, d in timed) == 1000
    np.testing.assert_allclose([t for t, _ in timed][:3], [0.0, 0.001, 0.002])


def _telemetry(n: int) -> list[Telemetry]:
    return [Telemetry(k, k * 0.5, 1.0, k * 0.5, 1.0, 0.5, 0.0, State.MOVING, Fault.NONE)
            for k in range(n)]  # fmt: skip


@pytest.fixture
def capture(tmp_path):
    path = tmp_path / "run.cap"
    clock = iter(np.arange(0.0, 10.0, 0.002))
    with TimestampedCapture(open(path, "wb"), clock=lambda: next(clock)) as cap:
        for k, m in enumerate(_telemetry(200)):
            cap.write(encode(m, k & 0xFF))
    return path


def test_replay_to_stdout_pipes_into_decode(capture, tmp_path):
    out_csv = tmp_path / "back.csv"
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "MPLBACKEND": "Agg"}
    replay = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "replay", str(capture), "--speed", "20"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=ROOT,
    )  # fmt: skip
    decode = subprocess.run(
        [sys.executable, "-m", "sim.cli", "decode", "-", "-o", str(out_csv)],
        stdin=replay.stdout, capture_output=True, text=True, env=env, cwd=ROOT, timeout=120,
    )  # fmt: skip
    replay.stdout.close()
    assert replay.wait(timeout=60) == 0, replay.stderr.read()
    assert decode.returncode == 0, decode.stderr
    assert "replayed" in replay.stderr.read().decode()
    rows = out_csv.read_text().splitlines()
    assert len(rows) == 201 and rows[0].startswith("t_s,tick,")


def test_replay_to_a_tcp_port_sends_the_same_bytes(capture):
    server = socket.create_server(("127.0.0.1", 0))
    got = bytearray()

    def receive() -> None:
        conn, _ = server.accept()
        with conn:
            while data := conn.recv(65536):
                got.extend(data)

    thread = threading.Thread(target=receive, daemon=True)
    thread.start()
    url = f"socket://127.0.0.1:{server.getsockname()[1]}"
    assert cli.main(["replay", str(capture), "--to", url, "--speed", "50", "--quiet"]) == 0
    thread.join(timeout=10)
    server.close()
    msgs = Decoder().feed(bytes(got))
    assert msgs == _telemetry(200)


def test_replay_a_can_log_onto_a_virtual_bus(tmp_path):
    import can

    from serial_protocol.can_link import CanReassembler, can_frames

    log = tmp_path / "bus.asc"
    with can.Logger(str(log)) as logger:
        for k, m in enumerate(_telemetry(20)):
            for arbitration_id, data in can_frames(m, counter=k):
                logger.on_message_received(
                    can.Message(timestamp=k * 0.002, arbitration_id=arbitration_id,
                                data=data, is_extended_id=False)
                )  # fmt: skip
    channel = f"replay-{uuid.uuid4().hex}"
    listener = can.Bus(interface="virtual", channel=channel)
    try:
        assert cli.main(["replay", str(log), "--to", f"can://virtual/{channel}", "--quiet"]) == 0
        reassembler = CanReassembler()
        got = []
        while (frame := listener.recv(timeout=0.5)) is not None:
            msg = reassembler.feed(frame.arbitration_id, bytes(frame.data))
            if msg is not None:
                got.append(msg)
    finally:
        listener.shutdown()
    assert got == _telemetry(20)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["{cap}", "--speed", "0"], "--speed"),
        (["{cap}", "--speed", "nan"], "--speed"),
        (["{cap}", "--speed", "1e-320"], "--speed 1e-320: must be >= 1e-06"),
        (["{cap}", "--to", "can://virtual/x"], "plays to a port"),
        (["missing.cap"], "cannot read"),
        (["{cap}", "--to", "/dev/no-such-port"], "cannot open serial port"),
        (["x.asc", "--to", "-"], "plays to can://"),
    ],
)
def test_bad_input_is_one_line_and_status_2(capture, argv, message, capsys):
    argv = [a.replace("{cap}", str(capture)) for a in argv]
    assert cli.main(["replay", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_serve_captures_with_timestamps(tmp_path):
    from sim.capture import is_timestamped, read_chunks

    cap = tmp_path / "serve.cap"
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "MPLBACKEND": "Agg"}
    done = subprocess.run(
        [sys.executable, "-m", "sim.cli", "serve", "--tcp", "0", "--speed", "4",
         "--duration", "0.4", "--capture", str(cap)],
        capture_output=True, text=True, env=env, cwd=ROOT, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert is_timestamped(cap)
    with open(cap, "rb") as f:
        chunks = list(read_chunks(f))
    times = [t for t, _ in chunks]
    assert len(chunks) > 1 and times == sorted(times)
    decoder = Decoder()
    ticks = [m.tick for _, data in chunks for m in decoder.feed(data) if isinstance(m, Telemetry)]
    assert len(ticks) > 50 and ticks == sorted(ticks)
