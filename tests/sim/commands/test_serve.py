"""``turntable-sim serve --pty`` in another process, driven through pyserial like a board."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from serial_protocol.host import BoardClient
from serial_protocol.messages import Ack, Malformed, MsgType, Nack, NackCode, State, Status
from serial_protocol.transport import SerialLink

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="needs POSIX pseudo-terminals")


@pytest.fixture
def served():
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "serve", "--pty", "--speed", "4", "--duration", "120"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/"), proc.stderr.read()
        yield proc, path
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _wait_status(client: BoardClient, done, timeout_wall_s: float) -> Status:
    status = client.wait_status(done, timeout_wall_s)
    assert isinstance(status, Status)
    return status


def test_a_program_opens_the_pty_and_drives_a_move(served):
    proc, path = served
    with SerialLink.open(path, 460800) as link:
        client = BoardClient(link, ack_timeout_s=1.0)
        hello = client.hello()
        assert hello.tick_hz == 500 and hello.counts_per_rev == 16384
        # bad input on the wire is refused with a specific code, nothing applied
        refused = client.move(30.0, 100.0, 0.0)
        assert isinstance(refused, Nack) and refused.code in (
            NackCode.DISABLED,
            NackCode.OUT_OF_RANGE,
        )
        assert client.set_enable(True) == Ack(client._cmd_id, MsgType.SET_ENABLE)
        start = _wait_status(client, lambda s: s.state is State.IDLE, 5.0)
        target_deg = start.pos_deg + 30.0
        assert client.move(target_deg, 100.0, 400.0) == Ack(client._cmd_id, MsgType.MOVE)
        status = _wait_status(
            client,
            lambda s: s.state is State.HOLDING and abs(s.pos_deg - target_deg) < 0.5,
            20.0,
        )
        assert status.state is State.HOLDING
        assert abs(status.pos_deg - target_deg) < 0.5
        telemetry = list(client.telemetry)
        assert len(telemetry) > 50
        moving = [t for t in telemetry if t.state is State.MOVING]
        assert moving and max(abs(t.vel_dps) for t in moving) > 50.0
        assert not any(isinstance(m, Malformed) for m in telemetry)
        assert link.stats().crc_errors == 0
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0
    assert "simulated" in err and "pty:" in err


def _drive_a_move(client: BoardClient) -> None:
    assert client.hello().tick_hz == 500
    assert isinstance(client.set_enable(True), Ack)
    start = _wait_status(client, lambda s: s.state is State.IDLE, 5.0)
    target_deg = start.pos_deg - 20.0
    assert isinstance(client.move(target_deg, 100.0, 400.0), Ack)
    status = _wait_status(
        client, lambda s: s.state is State.HOLDING and abs(s.pos_deg - target_deg) < 0.5, 20.0
    )
    assert abs(status.pos_deg - target_deg) < 0.5
    assert len(client.telemetry) > 20


def test_serve_on_a_tcp_port():
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "sim.cli",
            "serve",
            "--tcp",
            "0",
            "--speed",
            "4",
            "--baud",
            "115200",
            "--set",
            "uart.fifo_bytes=512",
        ],  # fmt: skip
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("socket://127.0.0.1:"), proc.stderr.read()
        with SerialLink.open(url) as link:
            client = BoardClient(link, ack_timeout_s=1.0)
            _drive_a_move(client)
            # 115200 baud cannot carry a telemetry frame every tick: every 2nd tick it is
            ticks = [t.tick for t in client.telemetry]
            assert {b - a for a, b in zip(ticks, ticks[1:], strict=False)} == {2}
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0 and "tcp:" in err
    assert "telemetry every 2 tick(s)" in err  # the decimation is stated in the log


def test_bad_overrides_are_command_errors():
    import argparse

    from serial_protocol.exceptions import CommandError
    from sim.commands import serve

    parser = argparse.ArgumentParser()
    serve.add_arguments(parser)
    for bad in ("uart.bit_flip_rate", "rate=1", "uart.bit_flip_rate=abc"):
        with pytest.raises(CommandError, match="--set"):
            serve._overrides(parser.parse_args(["--pty", "--set", bad]))
    args = parser.parse_args(["--pty", "--set", "safety.watchdog_s = 0.5", "--baud", "9600"])
    assert serve._overrides(args) == {"safety.watchdog_s": 0.5, "telemetry.baud": 9600}


def test_serve_as_a_can_gateway_on_the_virtual_bus():
    import argparse
    import threading
    import uuid

    from serial_protocol.can_link import CanLink
    from sim.commands import serve

    channel = f"serve-{uuid.uuid4().hex}"
    parser = argparse.ArgumentParser()
    serve.add_arguments(parser)
    args = parser.parse_args(["--can", f"virtual/{channel}", "--speed", "4", "--duration", "12"])
    with CanLink.open("virtual", channel) as pc:
        worker = threading.Thread(target=serve.main, args=(args,), daemon=True)
        worker.start()
        client = BoardClient(pc, ack_timeout_s=1.0, retries=10)
        _drive_a_move(client)
        assert pc.reassembler.stats.reassembly_errors == 0
        worker.join(timeout=30)
        assert not worker.is_alive()


def test_commands_get_through_a_noisy_line():
    """Bit flips and drops in both directions: bad frames are dropped and counted, lost
    commands are retried with the same cmd_id, and the move still completes."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "serve", "--tcp", "0", "--speed", "4",
         "--set", "uart.bit_flip_rate=2e-3", "--set", "uart.drop_rate=5e-4", "--seed", "7"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("socket://"), proc.stderr.read()
        with SerialLink.open(url) as link:
            client = BoardClient(link, ack_timeout_s=0.3, retries=8)
            _drive_a_move(client)
            stats = link.stats()
            assert stats.crc_errors + stats.header_errors > 0
            assert stats.seq_gaps > 0  # frames lost on the line are seen as sequence gaps
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=10)
    assert "board_to_pc_flipped_bits" in err and "pc_to_board_" in err
