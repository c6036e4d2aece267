"""``turntable-sim serve --pty``: the simulated bench behind a pseudo-terminal, a TCP port or
a CAN bus, in real time (or faster).

``--pty``: any PC program (a serial terminal, ``turntable-sim monitor``, the user's own tool)
opens the printed ``/dev/pts/N`` as if it were the board's USB–serial port. The pty is in raw
mode (``tty.setraw``). A pty ignores the baud rate, so the simulator paces the bytes itself:
they cross the emulated UART at the bench's ``[telemetry] baud`` in simulated time, and
simulated time follows the wall clock times ``--speed``.

``--tcp PORT``: the same byte stream on a TCP port (pyserial ``socket://host:PORT``), one
client at a time. ``--can IF/CHANNEL``: a gateway puts the board's messages on a CAN bus
(docs/protocol.md, section 8) and forwards the commands it receives to the board.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

HELP = "run the simulated bench in real time behind a pty (/dev/pts/N), TCP port or CAN bus"

#: At most this many ticks are simulated in one burst when the simulation falls behind.
MAX_CATCH_UP_TICKS = 50
#: Bytes waiting for a PC program that does not read are dropped past this size (a real
#: USB–serial adapter with nobody reading loses them too); counted, never silent.
MAX_PENDING_BYTES = 4096


def add_arguments(parser: argparse.ArgumentParser) -> None:
    default_bench = Path(__file__).resolve().parents[2] / "bench_configs" / "paper_bench.toml"
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--pty", action="store_true", help="serve on a new pseudo-terminal")
    where.add_argument("--tcp", type=int, metavar="PORT", help="serve on TCP PORT (0: any)")
    where.add_argument("--can", metavar="IF/CHANNEL", help="gateway to CAN, e.g. socketcan/vcan0")
    parser.add_argument("--host", default="127.0.0.1", help="TCP address to bind (127.0.0.1)")
    parser.add_argument(
        "--bench", default=str(default_bench), help="bench TOML (bench_configs/paper_bench.toml)"
    )
    parser.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="simulated seconds per wall second (1 = real time; 'inf' = as fast as possible)",
    )
    parser.add_argument(
        "--duration", type=float, help="stop after this many simulated seconds (default: never)"
    )
    parser.add_argument("--seed", type=int, default=0, help="noise and fault-injection seed")
    parser.add_argument(
        "--baud", type=int, help="UART baud rate (default: the bench's [telemetry] baud)"
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="TABLE.KEY=VALUE",
        help="override a bench value, e.g. uart.bit_flip_rate=1e-4 or safety.watchdog_s=0.5 "
        "(TOML syntax; repeatable)",
    )
    parser.add_argument("--link", metavar="PATH", help="with --pty: a symlink PATH -> /dev/pts/N")
    parser.add_argument("--capture", metavar="FILE", help="record the board -> PC bytes")


def main(args: argparse.Namespace) -> int:
    import select
    import time

    from serial_protocol.exceptions import CommandError
    from sim.config import load_bench
    from sim.loop import Simulation

    if not args.speed > 0:
        raise CommandError(f"--speed {args.speed!r}: must be > 0")
    # keep_log=False: a server runs for hours; the per-tick log would grow ~1.8 GB an hour.
    sim = Simulation(
        load_bench(args.bench), seed=args.seed, overrides=_overrides(args), keep_log=False
    )
    bench = sim.bench
    dt_s = sim.dt_s
    end_tick = None if args.duration is None else round(args.duration / dt_s)
    if args.pty:
        endpoint: Any = _PtyEndpoint(args.link)
    elif args.tcp is not None:
        endpoint = _TcpEndpoint(args.host, args.tcp)
    else:
        endpoint = _CanEndpoint(args.can)
    capture = None
    try:
        if args.capture:
            capture = open(args.capture, "wb")  # noqa: SIM115
    except OSError as exc:
        endpoint.close()
        raise CommandError(f"cannot write {args.capture!r}: {exc.strerror}") from exc
    baud = bench.firmware.telemetry.baud
    decimation = getattr(sim.fw, "telemetry_decimation", None)
    print(endpoint.address, flush=True)
    print(
        f"serving {args.bench} on {endpoint.address} (UART {baud} baud, paced by the "
        f"simulator; telemetry every {decimation} tick(s)), speed {args.speed:g}x; "
        "Ctrl-C to stop",
        file=sys.stderr,
        flush=True,
    )

    start_wall_s = time.monotonic()
    try:
        while end_tick is None or sim.tick < end_tick:
            data = endpoint.read()
            if data:
                sim.pc_write(data)
            # simulate up to the wall clock
            due_tick = int((time.monotonic() - start_wall_s) * args.speed / dt_s)
            if end_tick is not None:
                due_tick = min(due_tick, end_tick)
            n = min(due_tick - sim.tick, MAX_CATCH_UP_TICKS)
            if n > 0:
                sim.step(n)
                out = sim.pc_read()
                if out:
                    if capture is not None:
                        capture.write(out)
                    endpoint.write(out)
            endpoint.flush()
            if n < MAX_CATCH_UP_TICKS:
                next_wall_s = start_wall_s + (sim.tick + 1) * dt_s / args.speed
                wait_s = max(0.0, min(0.05, next_wall_s - time.monotonic()))
                select.select(endpoint.fds(), [], [], wait_s)
    except KeyboardInterrupt:
        pass
    finally:
        elapsed_wall_s = time.monotonic() - start_wall_s
        if capture is not None:
            capture.close()
        endpoint.close()
    c = endpoint.counters
    print(
        f"simulated {sim.t_s:.3f} s in {elapsed_wall_s:.3f} s of wall time "
        f"({sim.t_s / max(elapsed_wall_s, 1e-9):.2f}x); {endpoint.kind}: "
        f"{c['bytes_from_pc']} bytes in, {c['bytes_to_pc']} out, "
        f"{c['dropped_bytes']} dropped (no reader)",
        file=sys.stderr,
    )
    link = sim.link_stats()
    print("link: " + ", ".join(f"{k} {v}" for k, v in link.items() if v), file=sys.stderr)
    return 0


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    """``--baud`` and ``--set TABLE.KEY=VALUE`` as ``{"table.key": value}``."""
    import tomllib

    from serial_protocol.exceptions import CommandError

    out: dict[str, Any] = {}
    for item in args.set:
        key, sep, text = item.partition("=")
        if not sep or "." not in key:
            raise CommandError(f"--set {item!r}: expected TABLE.KEY=VALUE")
        try:
            out[key.strip()] = tomllib.loads(f"v = {text.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            raise CommandError(f"--set {item!r}: {text!r} is not a TOML value") from None
    if args.baud is not None:
        out["telemetry.baud"] = args.baud
    return out


def _new_counters() -> dict[str, int]:
    return {"bytes_from_pc": 0, "bytes_to_pc": 0, "dropped_bytes": 0}


class _ByteEndpoint:
    """A byte stream to one PC program; subclasses provide ``_recv`` and ``_send``."""

    kind = "bytes"

    def __init__(self) -> None:
        self.counters = _new_counters()
        self._pending = b""

    def read(self) -> bytes:
        data = self._recv()
        self.counters["bytes_from_pc"] += len(data)
        return data

    def write(self, data: bytes) -> None:
        self._pending += data

    def flush(self) -> None:
        if not self._pending:
            return
        written = self._send(self._pending)
        self.counters["bytes_to_pc"] += written
        rest = self._pending[written:]
        if len(rest) > MAX_PENDING_BYTES:
            self.counters["dropped_bytes"] += len(rest) - MAX_PENDING_BYTES
            rest = rest[-MAX_PENDING_BYTES:]
        self._pending = rest

    def _recv(self) -> bytes:
        raise NotImplementedError

    def _send(self, data: bytes) -> int:
        raise NotImplementedError


class _PtyEndpoint(_ByteEndpoint):
    kind = "pty"

    def __init__(self, link: str | None) -> None:
        import os
        import pty
        import tty

        from serial_protocol.exceptions import CommandError

        super().__init__()
        self._master, self._slave = pty.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.address = os.ttyname(self._slave)
        self._link = link
        if link:
            try:
                if os.path.islink(link):
                    os.unlink(link)
                os.symlink(self.address, link)
            except OSError as exc:
                self.close()
                raise CommandError(f"cannot create the link {link!r}: {exc.strerror}") from exc

    def fds(self) -> list[int]:
        return [self._master]

    def _recv(self) -> bytes:
        import os

        try:
            return os.read(self._master, 4096)
        except OSError:  # EAGAIN: nothing to read; EIO: nobody has the pty open
            return b""

    def _send(self, data: bytes) -> int:
        import os

        try:
            return os.write(self._master, data)
        except OSError:  # EAGAIN: the pty buffer is full (nobody reads)
            return 0

    def close(self) -> None:
        import os

        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
        if self._link and os.path.islink(self._link):
            os.unlink(self._link)


class _TcpEndpoint(_ByteEndpoint):
    kind = "tcp"

    def __init__(self, host: str, port: int) -> None:
        import socket

        from serial_protocol.exceptions import CommandError

        super().__init__()
        try:
            self._server = socket.create_server((host, port))
        except OSError as exc:
            raise CommandError(f"cannot listen on {host}:{port}: {exc.strerror}") from exc
        self._server.setblocking(False)
        bound_host, bound_port = self._server.getsockname()[:2]
        self.address = f"socket://{bound_host}:{bound_port}"
        self._client: Any = None

    def fds(self) -> list[int]:
        return [self._server.fileno()] + ([self._client.fileno()] if self._client else [])

    def _accept(self) -> None:
        if self._client is None:
            try:
                self._client, _ = self._server.accept()
                self._client.setblocking(False)
                self._pending = b""  # a new client does not get the previous one's backlog
            except BlockingIOError:
                pass

    def _drop_client(self) -> None:
        self._client.close()
        self._client = None

    def _recv(self) -> bytes:
        self._accept()
        if self._client is None:
            return b""
        try:
            data = self._client.recv(4096)
        except BlockingIOError:
            return b""
        except OSError:
            data = b""
        if not data:
            self._drop_client()
        return data

    def _send(self, data: bytes) -> int:
        if self._client is None:
            self.counters["dropped_bytes"] += len(data)
            self._pending = b""
            return 0
        try:
            return self._client.send(data)
        except BlockingIOError:
            return 0
        except OSError:
            self._drop_client()
            return 0

    def close(self) -> None:
        if self._client is not None:
            self._drop_client()
        self._server.close()


class _CanEndpoint:
    """Gateway: board bytes -> messages -> CAN frames; CAN commands -> frames -> board."""

    kind = "can"

    def __init__(self, spec: str) -> None:
        from serial_protocol.can_link import CanLink
        from serial_protocol.exceptions import CommandError
        from serial_protocol.frame import Decoder

        interface, _, channel = spec.removeprefix("can://").partition("/")
        if not interface or not channel:
            raise CommandError(f"--can {spec!r}: expected INTERFACE/CHANNEL")
        self.link = CanLink.open(interface, channel)
        self.address = f"can://{interface}/{channel}"
        self.counters = _new_counters()
        self._decoder = Decoder()
        self._seq = 0

    def fds(self) -> list[int]:
        return []

    def read(self) -> bytes:
        from serial_protocol.frame import frame_raw

        out = b""
        for msg_type, payload in self.link.poll_raw(0.0):
            out += frame_raw(msg_type, payload, self._seq)
            self._seq = (self._seq + 1) & 0xFF
        self.counters["bytes_from_pc"] += len(out)
        return out

    def write(self, data: bytes) -> None:
        from serial_protocol.messages import Malformed

        self.counters["bytes_to_pc"] += len(data)
        for msg in self._decoder.feed(data):
            if isinstance(msg, Malformed):
                self.counters["dropped_bytes"] += 1
                continue
            self.link.send(msg)

    def flush(self) -> None:
        return None

    def close(self) -> None:
        self.link.close()
