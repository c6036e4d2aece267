"""``turntable-sim serve --pty`` in another process, driven through pyserial like a board."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from serial_protocol.frame import field_name
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
        assert isinstance(refused, Nack) and refused.code is NackCode.TOO_LOW
        assert field_name(refused.msg_type, refused.field) == "a_max_dps2"
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
            # 115200 baud cannot carry a 40-byte telemetry frame every tick: every 3rd it is
            ticks = [t.tick for t in client.telemetry]
    finally:
        err = _stop(proc)
    assert proc.returncode == 0 and "tcp:" in err
    assert "telemetry every 3 tick(s)" in err  # the decimation is stated in the log
    steps = [b - a for a, b in zip(ticks, ticks[1:], strict=False)]
    assert 3 in steps and all(step > 0 and step % 3 == 0 for step in steps)
    # A frame missing from the client's telemetry is one the server dropped, counted (a
    # reader that a loaded machine slows down falls behind the line; TCP loses nothing).
    missing = sum(step // 3 - 1 for step in steps)
    assert missing <= _summary(err)["frames_dropped_to_pc"], err


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


# ------------------------------------------------------------------ pacing, signals, TCP


def _start(*extra: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "serve", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    address = proc.stdout.readline().strip()
    if not address:
        proc.kill()
        raise AssertionError(proc.communicate(timeout=10)[1])
    return proc, address


def _stop(proc: subprocess.Popen, signum: int = signal.SIGINT) -> str:
    if proc.poll() is None:
        proc.send_signal(signum)
    try:
        _, err = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
        raise AssertionError("serve did not stop: " + err) from None
    return err


def _summary(err: str) -> dict[str, int]:
    """The counters of serve's exit summary."""
    import re

    found = {
        "peak": r"line: peak (\d+) bytes",
        "capacity": r"window, capacity (\d+)",
        "bucket": r"\(bucket (\d+)\)",
        "frames_dropped_to_pc": r"reader too slow: (\d+) frames",
        "bytes_dropped_from_pc": r"writer faster than the line: \d+ frames \((\d+) bytes\)",
        "refused": r"refused (\d+)",
        "clients": r"clients (\d+)",
    }
    out = {}
    for key, pattern in found.items():
        m = re.search(pattern, err)
        if m:
            out[key] = int(m.group(1))
    return out


def test_output_is_paced_to_the_line_from_the_first_tick():
    """The bytes a client receives from its connection on never exceed what the line carries
    in that time plus the pacer's bucket (50 ms of the line), measured by their arrival: this
    bound holds however loaded the machine is (a late client only widens it); the server
    never wrote more than the line's capacity in any 100 ms window. Before pacing, serve
    sent up to 2.7x the line in its first second."""
    import socket
    import time

    from serial_protocol.frame import Decoder

    proc, url = _start("--tcp", "0", "--baud", "115200", "--duration", "60")
    try:
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        t_connect_s = time.monotonic()
        sock = socket.create_connection((host, int(port)))
        sock.settimeout(0.2)
        received = 0
        decoder = Decoder()
        t_last_s = t_connect_s
        # 2 s of the stream, and at least 50 frames however slowly a loaded machine runs it
        while time.monotonic() - t_connect_s < 2.0 or (
            decoder.frames < 50 and time.monotonic() - t_connect_s < 120.0
        ):
            try:
                data = sock.recv(65536)
            except TimeoutError:
                continue
            t_last_s = time.monotonic()
            received += len(data)
            decoder.feed(data)
        sock.close()
        line_bytes_per_s = 115200 / 10
        assert decoder.frames >= 50  # telemetry flowed
        assert received <= line_bytes_per_s * (t_last_s - t_connect_s) + 576
        stats = decoder.stats()
        assert stats.crc_errors == stats.header_errors == stats.bytes_dropped == 0
    finally:
        err = _stop(proc)
    s = _summary(err)
    assert s["capacity"] == 1152 and s["bucket"] == 576
    assert 0 < s["peak"] <= s["capacity"], err


def test_sigterm_removes_the_link_as_ctrl_c_does(tmp_path):
    import os

    link = tmp_path / "turntable"
    proc, path = _start("--pty", "--link", str(link))
    assert os.path.islink(link) and os.readlink(link) == path
    err = _stop(proc, signal.SIGTERM)
    assert proc.returncode == 0, err
    assert not os.path.lexists(link)
    assert "simulated" in err  # the exit summary, as after Ctrl-C


@pytest.mark.parametrize("where", ["--pty", "--tcp"])
def test_a_reader_that_falls_behind_loses_whole_frames(where):
    """A client that stops reading: the server drops the oldest whole frames (counted) and
    never part of one, so the client's decoder sees sequence gaps but no CRC error, no header
    error and not one byte outside a frame. (Before, serve kept the last 4096 bytes of its
    backlog, cutting a frame: the CRC error test_serve saw on a loaded machine.)"""
    import os
    import select
    import socket
    import time

    from serial_protocol.frame import Decoder

    proc, address = _start(where, *(["0"] if where == "--tcp" else []), "--speed", "4")
    try:
        if where == "--tcp":
            host, port = address.removeprefix("socket://").rsplit(":", 1)
            sock = socket.socket()
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            sock.connect((host, int(port)))
            fd = sock.fileno()
        else:  # serve made the pty raw; opening it does not flush what it holds
            fd = os.open(address, os.O_RDWR | os.O_NOCTTY)
        decoder = Decoder()
        deadline_s = time.monotonic() + 120.0
        # Stop reading for 2 s (8 simulated seconds of telemetry: far more than the kernel's
        # buffers and serve's queue hold), then read what is there; again until the stream
        # shows the frames serve dropped (a loaded machine may run serve slowly).
        while decoder.stats().seq_gaps == 0 and time.monotonic() < deadline_s:
            time.sleep(2.0)
            for _ in range(1000):  # what is there now (the server keeps writing)
                if not select.select([fd], [], [], 0.0)[0]:
                    break
                data = os.read(fd, 65536)
                if not data:
                    break
                decoder.feed(data)
        if where == "--tcp":
            sock.close()
        else:
            os.close(fd)
    finally:
        err = _stop(proc)
    stats = decoder.stats()
    assert stats.frames > 100
    assert stats.crc_errors == stats.header_errors == stats.bytes_dropped == 0
    assert stats.seq_gaps >= 1
    assert _summary(err)["frames_dropped_to_pc"] > 0, err


def test_a_second_tcp_client_is_refused_with_a_message():
    import socket

    from serial_protocol.exceptions import LinkError

    proc, url = _start("--tcp", "0", "--speed", "4")
    try:
        with SerialLink.open(url) as first:
            assert BoardClient(first, ack_timeout_s=1.0, retries=5).hello().tick_hz == 500
            host, port = url.removeprefix("socket://").rsplit(":", 1)
            with socket.create_connection((host, int(port)), timeout=10) as second:
                said = b""
                while chunk := second.recv(1000):  # the server closes after its message
                    said += chunk
            assert said.startswith(b"turntable-sim serve: busy") and b"one client" in said
            with pytest.raises(LinkError, match="busy"):
                with SerialLink.open(url) as third:
                    for _ in range(100):
                        third.poll(0.1)
            # the first client is not disturbed
            assert BoardClient(first, ack_timeout_s=1.0, retries=5).hello().tick_hz == 500
    finally:
        err = _stop(proc)
    assert _summary(err)["refused"] == 2 and _summary(err)["clients"] == 1


def _vm_hwm_kb(pid: int) -> int:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    raise AssertionError("no VmHWM")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/PID/status")
def test_a_flooding_client_neither_grows_the_server_nor_holds_back_the_next():
    """64 MiB of commands as fast as loopback takes them: the server drains them into a
    bounded backlog (its peak memory grows by a few MB at most), drops what the line cannot
    carry (counted), and the next client's first Hello is answered at its first attempt.
    benchmarks/bench_link.py floods 400 MiB and times the next client's answer."""
    import socket

    from serial_protocol.frame import encode
    from serial_protocol.messages import GetStatus

    proc, url = _start("--tcp", "0", "--speed", "4")
    try:
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        with SerialLink.open(url) as link:  # the server's memory in steady state
            BoardClient(link, ack_timeout_s=1.0, retries=5).hello()
        before_kb = _vm_hwm_kb(proc.pid)
        block = encode(GetStatus(7), 0) * (1 << 16) + bytes(range(256)) * 64
        flood_bytes = 0
        with socket.create_connection((host, int(port))) as sock:
            while flood_bytes < 64 << 20:
                sock.sendall(block)
                flood_bytes += len(block)
        with SerialLink.open(url) as link:
            client = BoardClient(link, ack_timeout_s=10.0, retries=0)
            assert client.hello().tick_hz == 500
        grown_mb = (_vm_hwm_kb(proc.pid) - before_kb) / 1024
        assert grown_mb < 20, f"peak memory grew by {grown_mb:.1f} MB"
    finally:
        err = _stop(proc)
    assert _summary(err)["bytes_dropped_from_pc"] > 32 << 20, err


# What runs inside the served process: serve itself, with a numba event listener that counts
# every time numba takes its compiler lock (which it does to compile a kernel and to load one
# from the cache) after the first line reaches stdout (the address).
_SERVE_WATCHING_NUMBA = """
import sys
import numba.core.event as ev
from sim.cli import main

printed = []
after = []

class CompilerLock(ev.Listener):
    def on_start(self, event):
        if printed:
            import traceback
            after.append(" <- ".join(f.name for f in traceback.extract_stack()[-12:-3][::-1]))
    def on_end(self, event):
        pass

class Stdout:
    def __init__(self, stream):
        self.stream = stream
    def write(self, text):
        if text.strip():
            printed.append(text)
        return self.stream.write(text)
    def __getattr__(self, name):
        return getattr(self.stream, name)

ev.register("numba:compiler_lock", CompilerLock())
sys.stdout = Stdout(sys.stdout)
try:
    rc = main(sys.argv[1:])
finally:
    print(f"compiler lock taken after the address: {len(after)}", file=sys.stderr)
    for where in after[:5]:
        print("  " + where, file=sys.stderr)
sys.exit(rc)
"""


def test_the_address_is_printed_once_the_board_can_answer():
    """serve prints its address only when it can answer at once: the socket is listening (one
    connection attempt, no retry), the board has ticked, and every compiled kernel the served
    loop uses is loaded. Checked by events, not by time: after the address is printed, numba
    never takes its compiler lock again (to compile or load a kernel from the cache) while a
    client opens a session, enables, runs a trapezoid and an S-curve move, stops and disables.
    Printing the address before the kernels were loaded left the first command waiting 0.4-1 s
    (seconds on a cold cache) behind the load, and the first commands of a client that opens
    the address at once timed out."""
    import socket

    from serial_protocol.messages import Profile

    proc = subprocess.Popen(
        [sys.executable, "-c", _SERVE_WATCHING_NUMBA, "serve", "--tcp", "0", "--speed", "4"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("socket://127.0.0.1:"), proc.communicate(timeout=20)[1]
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        # one attempt: a refused connection fails the test (the socket listens before the print)
        socket.create_connection((host, int(port)), timeout=10).close()
        with SerialLink.open(url) as link:
            client = BoardClient(link, ack_timeout_s=1.0)
            _drive_a_move(client)
            start = _wait_status(client, lambda s: s.state is State.HOLDING, 20.0)
            target_deg = start.pos_deg + 10.0
            ack = client.move(target_deg, 100.0, 400.0, 4000.0, Profile.SCURVE)
            assert isinstance(ack, Ack), ack
            _wait_status(
                client,
                lambda s: s.state is State.HOLDING and abs(s.pos_deg - target_deg) < 0.5,
                20.0,
            )
            assert isinstance(client.stop(), Ack)
            assert isinstance(client.set_enable(False), Ack)
    finally:
        err = _stop(proc)
    assert "compiler lock taken after the address: 0" in err, err
