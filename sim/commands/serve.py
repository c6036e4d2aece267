"""``turntable-sim serve``: the simulated bench behind a pseudo-terminal, a TCP port or a CAN
bus, in real time (or faster).

``--pty``: any PC program (a serial terminal, ``turntable-sim monitor``, the user's own tool)
opens the printed ``/dev/pts/N`` as if it were the board's USB–serial port. The pty is in raw
mode (``tty.setraw``). A pty ignores the baud rate, so the simulator paces the bytes itself:
they cross the emulated UART at the bench's ``[telemetry] baud`` in simulated time, simulated
time follows the wall clock times ``--speed``, and the bytes are written to the pty no faster
than the line carries them in wall time (``LinePacer``: never more than the line's capacity
in any 100 ms window, from the first tick on, however late the process runs; a 50 ms bucket
lets a process that a loaded machine wakes only every few tens of milliseconds keep up).
When the process falls behind by more than ``MAX_LAG_S`` the simulated time slips instead of
catching up in a burst (stated on exit). A PC program that reads too slowly loses whole
frames (the oldest first), never part of one; all of it is counted and printed on exit.

The address is printed on stdout once the server can answer (the compiled kernels loaded,
the first tick done). SIGTERM and SIGHUP stop it as Ctrl-C does (the ``--link`` symlink is
removed).

``--tcp PORT``: the same byte stream on a TCP port (pyserial ``socket://host:PORT``), one
client at a time, with ``TCP_NODELAY``. A second client receives one line of text
(``sim.endpoints.BUSY_MESSAGE``) and is disconnected. The input is drained as it arrives and
kept within a bounded backlog (a client writing faster than the line loses whole frames,
counted); when a client disconnects, what it sent and the board has not yet received is
forgotten, so the next client is not queued behind it. ``--can IF/CHANNEL``: a gateway puts
the board's messages on a CAN bus (docs/protocol.md, section 8) and forwards the commands it
receives to the board.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from sim.commands._common import integer, number, tcp_port

HELP = "run the simulated bench in real time behind a pty (/dev/pts/N), TCP port or CAN bus"

#: At most this many ticks are simulated in one pass of the loop.
MAX_CATCH_UP_TICKS = 50
#: A simulation that falls further behind the wall clock than this slips: simulated time
#: is let go rather than caught up in a burst (counted as ``slipped``).
MAX_LAG_S = 0.1
#: The PC's bytes are handed to the board's RX line while fewer than this wait for it.
FEED_BYTES = 256
#: The output pacer's bucket: this much of the line's time may go out at once (a process
#: woken less often than this falls behind the line and its reader loses frames; the pacer's
#: 100 ms window cap still holds whatever the bucket).
BURST_S = 0.05


def add_arguments(parser: argparse.ArgumentParser) -> None:
    default_bench = Path(__file__).resolve().parents[2] / "bench_configs" / "paper_bench.toml"
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--pty", action="store_true", help="serve on a new pseudo-terminal")
    where.add_argument("--tcp", type=tcp_port, metavar="PORT", help="serve on TCP PORT (0: any)")
    where.add_argument("--can", metavar="IF/CHANNEL", help="gateway to CAN, e.g. socketcan/vcan0")
    parser.add_argument("--host", default="127.0.0.1", help="TCP address to bind (127.0.0.1)")
    parser.add_argument(
        "--bench", default=str(default_bench), help="bench TOML (bench_configs/paper_bench.toml)"
    )
    parser.add_argument(
        "--speed",
        type=number(lo=0.0, lo_open=True, allow_inf=True),
        default=1.0,
        help="simulated seconds per wall second (1 = real time; 'inf' = as fast as possible)",
    )
    parser.add_argument(
        "--duration",
        type=number(lo=0.0, hi=1e9),
        help="stop after this many simulated seconds (default: never)",
    )
    parser.add_argument(
        "--seed", type=integer(0, 2**63 - 1), default=0, help="noise and fault-injection seed"
    )
    parser.add_argument(
        "--baud", type=integer(1), help="UART baud rate (default: the bench's [telemetry] baud)"
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
    parser.add_argument(
        "--capture",
        metavar="FILE",
        help="record the board -> PC bytes with their times (sim/capture.py; decode, plot, "
        "replay read it)",
    )


def main(args: argparse.Namespace) -> int:
    import select
    import signal
    import threading
    import time

    from firmware_model import kernel_cache
    from planner import warm_up
    from serial_protocol.exceptions import CommandError
    from serial_protocol.pacing import LinePacer
    from serial_protocol.uart import bytes_per_s
    from sim import endpoints, plant_kernel
    from sim.config import load_bench
    from sim.loop import Simulation

    if not args.speed > 0:
        raise CommandError(f"--speed {args.speed!r}: must be > 0")
    # keep_log=False: a server runs for hours; the per-tick log would grow ~1.8 GB an hour.
    sim = Simulation(
        load_bench(args.bench), seed=args.seed, overrides=_overrides(args), keep_log=False
    )
    # Load the S-curve planner's compiled kernel now, not at the first S-curve Move: a stall
    # of 0.3-0.9 s in the paced loop below would overflow the link. The tick's kernels load
    # without numba's registries (kernel_cache._KernelCache); the planner's need them: load
    # them without numba's BLAS probe (kernel_cache.prepare).
    kernel_cache.prepare()
    warm_up()
    bench = sim.bench
    dt_s = sim.dt_s
    end_tick = None if args.duration is None else round(args.duration / dt_s)
    baud = bench.firmware.telemetry.baud
    # The line's capacity in wall time: --speed simulated seconds pass per wall second.
    line_bytes_per_s = bytes_per_s(baud) * args.speed
    unpaced = line_bytes_per_s == float("inf")
    pacer = LinePacer(
        1e18 if unpaced else line_bytes_per_s,
        1 << 30 if unpaced else max(1, round(line_bytes_per_s * BURST_S)),
    )
    if args.pty:
        endpoint: endpoints.Endpoint = endpoints.PtyEndpoint(pacer, args.link)
    elif args.tcp is not None:
        endpoint = endpoints.TcpEndpoint(pacer, args.host, args.tcp)
    else:
        endpoint = endpoints.CanEndpoint(args.can)
    capture = None
    try:
        if args.capture:
            from sim.capture import TimestampedCapture

            # each burst with its wall time: replay plays it back at this pace
            capture = TimestampedCapture(open(args.capture, "wb"))  # noqa: SIM115
    except OSError as exc:
        endpoint.close()
        raise CommandError(f"cannot write {args.capture!r}: {exc.strerror}") from exc

    # SIGTERM and SIGHUP end the server as Ctrl-C does (the --link symlink is removed);
    # a handler can only be installed from the main thread.
    stop_signal: list[int] = []
    old_handlers = {}
    if threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGTERM, signal.SIGHUP):
            old_handlers[signum] = signal.signal(signum, lambda n, _f: stop_signal.append(n))

    # Before the address is printed: the compiled kernels are loaded and the first tick is
    # done, so a program that opens the address at once is answered in time.
    plant_kernel.warm_up(bench.loop.event_levels)
    sim.step(1)
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
    # wall time of simulated tick 0 (moved forward when the simulation slips)
    origin_wall_s = start_wall_s - sim.tick * dt_s / args.speed
    max_lag_ticks = None if unpaced else max(1, int(MAX_LAG_S * args.speed / dt_s))
    slipped_ticks = 0
    try:
        while (end_tick is None or sim.tick < end_tick) and not stop_signal:
            now_s = time.monotonic()
            data = endpoint.receive(FEED_BYTES - sim.pc_pending_bytes)
            if endpoint.lost_peer:
                endpoint.lost_peer = False
                sim.pc_discard()  # the next client does not wait behind the last one's input
            if data:
                sim.pc_write(data)
            if max_lag_ticks is None:  # --speed inf: as fast as the simulation goes
                due_tick = sim.tick + MAX_CATCH_UP_TICKS
            else:
                due_tick = int((now_s - origin_wall_s) * args.speed / dt_s)
            if max_lag_ticks is not None and due_tick - sim.tick > max_lag_ticks:
                lost = due_tick - sim.tick - max_lag_ticks
                slipped_ticks += lost
                origin_wall_s += lost * dt_s / args.speed
                due_tick -= lost
            if end_tick is not None:
                due_tick = min(due_tick, end_tick)
            n = min(due_tick - sim.tick, MAX_CATCH_UP_TICKS)
            if n > 0:
                sim.step(n)
                out = sim.pc_read()
                if out:
                    if capture is not None:
                        capture.write(out)
                    endpoint.deliver(out, sim.uart_tx.pending == 0)
            endpoint.service(now_s)
            if n < MAX_CATCH_UP_TICKS and max_lag_ticks is not None:
                next_tick_s = origin_wall_s + (sim.tick + 1) * dt_s / args.speed
                wait_s = next_tick_s - time.monotonic()
                pace_s = endpoint.wait_s()
                if pace_s is not None:
                    wait_s = min(wait_s, pace_s)
                select.select(endpoint.fds(), [], [], max(0.0, min(0.05, wait_s)))
    except KeyboardInterrupt:
        pass
    finally:
        elapsed_wall_s = time.monotonic() - start_wall_s
        if capture is not None:
            capture.close()
        endpoint.close()
        for signum, handler in old_handlers.items():
            signal.signal(signum, handler)
    c = endpoint.counters
    print(
        f"simulated {sim.t_s:.3f} s in {elapsed_wall_s:.3f} s of wall time "
        f"({sim.t_s / max(elapsed_wall_s, 1e-9):.2f}x, {slipped_ticks * dt_s:.3f} s slipped "
        f"behind the wall clock); {endpoint.kind}: "
        f"{c['bytes_from_pc']} bytes in, {c['bytes_to_pc']} out; reader too slow: "
        f"{c['frames_dropped_to_pc']} frames ({c['bytes_dropped_to_pc']} bytes) dropped; "
        f"writer faster than the line: {c['frames_dropped_from_pc']} frames "
        f"({c['bytes_dropped_from_pc']} bytes) dropped; {c['bytes_unheard']} bytes with "
        f"no client; clients {c['clients']}, refused {c['clients_refused']}",
        file=sys.stderr,
    )
    if endpoint.kind != "can" and not unpaced:
        print(
            f"line: peak {pacer.peak_window_bytes} bytes in a {pacer.window_s * 1000:.0f} ms "
            f"window, capacity {pacer.window_cap_bytes} (bucket {pacer.burst_bytes})",
            file=sys.stderr,
        )
    link = sim.link_stats()
    print("link: " + ", ".join(f"{k} {v}" for k, v in link.items() if v), file=sys.stderr)
    return 0


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    """``--baud`` and ``--set TABLE.KEY=VALUE`` as ``{"table.key": value}``."""
    import tomllib

    from serial_protocol.exceptions import CommandError
    from sim.config import sanity_problem

    out: dict[str, Any] = {}
    for item in args.set:
        key, sep, text = item.partition("=")
        if not sep or "." not in key:
            raise CommandError(f"--set {item!r}: expected TABLE.KEY=VALUE")
        try:
            value = tomllib.loads(f"v = {text.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            raise CommandError(f"--set {item!r}: {text!r} is not a TOML value") from None
        table, _, name = key.strip().rpartition(".")
        if isinstance(value, list | dict):
            raise CommandError(f"--set {item!r}: must be a single value")
        reason = sanity_problem(table, name, value)
        if reason:
            raise CommandError(f"--set {item!r}: {reason}")
        out[key.strip()] = value
    if args.baud is not None:
        out["telemetry.baud"] = args.baud
    return out
