"""``turntable-sim monitor URL``: the PC-side tool, against ``serve --pty`` or a real board.

Connects through pyserial (``/dev/ttyUSB0``, ``/dev/pts/N``, ``socket://host:port``,
``loop://``) or CAN (``can://INTERFACE/CHANNEL``, e.g. ``can://socketcan/can0``), sends the
commands given as options (in the order clear-fault, enable, limits, gains, telemetry, move,
then the timed interrupts and stop), shows a live status line, records telemetry to CSV, and
prints the link statistics at the end. ``--interactive`` reads commands from stdin instead
(type ``help``).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from serial_protocol import messages as _msg
from sim.commands._common import integer, number, wire_number

#: --jog's default timeout (ms): the board stops the jog this long after the monitor exits.
JOG_TIMEOUT_MS = 500

HELP = "talk to a board or to 'serve --pty': send commands, show status, record telemetry CSV"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "url",
        help="serial port or pyserial URL, can://INTERFACE/CHANNEL, or sim:// (a simulated "
        "board in this process; sim://BENCH.toml for another bench)",
    )
    parser.add_argument(
        "--baud", type=integer(1, 100_000_000), default=460800, help="serial baud rate (460800)"
    )
    parser.add_argument(
        "--move",
        type=wire_number(_msg.Move, "target_deg"),
        metavar="TARGET_DEG",
        help="move to this target (axis degrees; the paper's 3e6 is millidegrees: 3000)",
    )
    parser.add_argument(
        "--v-max", type=wire_number(_msg.Move, "v_max_dps"), default=990.0,
        help="v_max in deg/s (990)",
    )  # fmt: skip
    parser.add_argument(
        "--a-max", type=wire_number(_msg.Move, "a_max_dps2"), default=148.0,
        help="a_max in deg/s^2 (148)",
    )  # fmt: skip
    parser.add_argument(
        "--j-max", type=wire_number(_msg.Move, "j_max_dps3"), default=0.0,
        help="j_max in deg/s^3 (s-curve)",
    )  # fmt: skip
    parser.add_argument("--profile", choices=("trapezoid", "scurve", "step"), default="trapezoid")
    parser.add_argument(
        "--interrupt",
        nargs=2,
        type=wire_number(_msg.Move, "target_deg"),
        action="append",
        default=[],
        metavar=("AFTER_S", "TARGET_DEG"),
        help="after AFTER_S seconds send a new move to TARGET_DEG (the paper's interrupt); "
        "repeatable",
    )
    parser.add_argument(
        "--stop",
        type=number(lo=0.0, hi=1e6),
        metavar="AFTER_S",
        help="send a stop after AFTER_S seconds",
    )
    parser.add_argument(
        "--gains",
        nargs=4,
        action="append",
        default=[],
        metavar=("LOOP", "KP", "KI", "KD"),
        help="set gains of current|velocity|position; repeatable",
    )
    parser.add_argument(
        "--limits",
        nargs="+",
        type=wire_number(_msg.SetLimits, "v_max_dps"),
        metavar="V",
        help="set the limits: V_MAX A_MAX CURRENT_A FOLLOW_DEG, then optionally TRIP_A "
        "BUS_OVER_V BUS_UNDER_V DERATE_C THERMAL_TRIP_C BRAKE_A (0 keeps the board's)",
    )
    parser.add_argument(
        "--gains-from",
        metavar="TOML",
        help="send the three loops' gains of this bench TOML (e.g. tune's *_tuned.toml)",
    )
    parser.add_argument("--clear-fault", action="store_true", help="clear a latched fault")
    enable = parser.add_mutually_exclusive_group()
    enable.add_argument("--enable", action="store_true", help="enable the bridge")
    enable.add_argument("--disable", action="store_true", help="disable the bridge")
    parser.add_argument(
        "--telemetry",
        type=wire_number(_msg.SetTelemetry, "decimation"),
        metavar="DECIMATION",
        help="set decimation (1 = every tick, 0 = off)",
    )
    parser.add_argument(
        "--duration",
        type=number(lo=0.0, hi=1e6),
        default=5.0,
        help="seconds to listen after the commands (5)",
    )
    parser.add_argument(
        "--program",
        metavar="FILE",
        help="send a motion program file (TOML [[segment]] tables: target_deg, v_max_dps, "
        "dwell_s) into the board's queue with flow control (sim/motionfile.py)",
    )
    parser.add_argument(
        "--stream",
        metavar="FILE",
        help="stream a point file (TOML with period_s, pos_deg [, vel_dps]; or CSV with a "
        "pos_deg[,vel_dps] header and --stream-period) at its fixed period",
    )
    parser.add_argument(
        "--stream-period", type=number(lo=0.0, lo_open=True, hi=60.0), metavar="S",
        help="period between the stream's points (s); overrides the file's",
    )  # fmt: skip
    parser.add_argument(
        "--jog", type=wire_number(_msg.Jog, "vel_dps"), metavar="VEL_DPS",
        help="jog at this velocity (deg/s, signed) until --stop, the travel end or the "
        "monitor's exit (the jog's timeout, see --jog-timeout)",
    )  # fmt: skip
    parser.add_argument(
        "--jog-accel", type=wire_number(_msg.Jog, "a_max_dps2"), metavar="A_MAX",
        help="the jog's acceleration and its braking at a timeout (deg/s^2; default --a-max)",
    )  # fmt: skip
    parser.add_argument(
        "--jog-timeout", type=wire_number(_msg.Jog, "timeout_ms"), default=None, metavar="MS",
        help=f"the board stops the jog after MS without a frame from this monitor, which "
        f"sends heartbeats while it listens: the jog stops MS after the monitor exits "
        f"(default {JOG_TIMEOUT_MS}; 0: never, the jog runs on until a Stop)",
    )  # fmt: skip
    parser.add_argument("--csv", metavar="FILE", help="record the telemetry to this CSV")
    parser.add_argument(
        "--capture",
        metavar="FILE",
        help="record the received bytes with their arrival times (serial; sim/capture.py, "
        "read by decode, plot and replay), or every CAN frame (can://; .asc or .blf, "
        "python-can's writers)",
    )
    parser.add_argument("--interactive", action="store_true", help="read commands from stdin")
    parser.add_argument(
        "--plot",
        action="store_true",
        help="live plot: planned and measured velocity and position, current (a window)",
    )
    parser.add_argument(
        "--plot-window", type=float, default=10.0, metavar="S", help="rolling window (10 s)"
    )
    parser.add_argument(
        "--plot-fps", type=float, default=25.0, metavar="FPS", help="redraws per second (25)"
    )
    parser.add_argument(
        "--plot-save",
        metavar="FILE",
        help="save the live plot's last frame to FILE (.png/.svg/.pdf; works without a display)",
    )
    parser.add_argument(
        "--ack-timeout", type=number(lo=0.0, lo_open=True, hi=60.0), default=0.1,
        help="seconds (0.1)",
    )  # fmt: skip
    parser.add_argument(
        "--retries", type=integer(0, 100), default=3, help="retries per command (3)"
    )
    parser.add_argument("--quiet", action="store_true", help="no live status line")


def main(args: argparse.Namespace) -> int:
    import contextlib

    from serial_protocol.exceptions import CommandError, LinkTimeout
    from serial_protocol.host import BoardClient
    from serial_protocol.messages import (
        PROTOCOL_VERSION,
        BoardHeartbeat,
        FaultReport,
        Malformed,
        Telemetry,
    )
    from serial_protocol.telemetry_csv import TelemetryCsvWriter
    from sim.shell import describe

    # Every command is checked before the port is opened: a bad value is one line, exit 2.
    for after_s, _ in args.interrupt:
        if after_s < 0.0:
            raise CommandError(f"--interrupt {after_s!r}: AFTER_S must be >= 0 seconds")
    live = _live_plot(args)
    # checked before connecting: a bad --gains-from sends nothing
    script = _scripted(args)
    for text in script + [_move_text(args, t) for _, t in args.interrupt]:
        parse_command(None, text)
    with contextlib.ExitStack() as stack:
        if args.url.startswith("can://"):
            link = stack.enter_context(_open_can(args.url, args.capture))
        else:
            capture = None
            if args.capture:
                from sim.capture import TimestampedCapture

                # each chunk with its arrival time, for replay at the recorded pace
                capture = TimestampedCapture(stack.enter_context(_open(args.capture, "wb")))
            if args.url.startswith("sim://"):
                from sim.simlink import SimulatedLink

                # sim://[BENCH.toml]: a simulated board in this process, in real time
                bench = args.url[len("sim://") :] or None
                link = stack.enter_context(SimulatedLink.open(bench, capture=capture))
            else:
                from serial_protocol.transport import SerialLink

                link = stack.enter_context(SerialLink.open(args.url, args.baud, capture=capture))
        writer = None
        if args.csv:
            writer = TelemetryCsvWriter(stack.enter_context(_open(args.csv, "w")))
        # On a terminal the interactive shell shows the status in its toolbar instead.
        status = _StatusLine(enabled=not (args.quiet or args.interactive))

        def on_message(msg: Any) -> None:
            if isinstance(msg, BoardHeartbeat):
                status.bus_voltage_v = msg.bus_voltage_v
            elif isinstance(msg, Telemetry):
                if writer is not None:
                    writer.write(msg)
                if live is not None:
                    live.plot.buffer.append(msg)
                status.show(msg)
            elif isinstance(msg, FaultReport | Malformed):
                status.say(f"<- {describe(msg)}")

        client = BoardClient(link, args.ack_timeout, args.retries, on_message=on_message)
        try:
            hello = client.hello()
        except LinkTimeout as exc:
            raise CommandError(f"no board answers on {args.url}: {exc}") from exc
        if writer is not None and hello.tick_hz > 0:
            writer.tick_hz = float(hello.tick_hz)
        if live is not None and hello.tick_hz > 0:
            live.plot.buffer.tick_hz = float(hello.tick_hz)
        status.say(
            f"connected to {args.url}: protocol {hello.protocol_version}, firmware "
            f"{hello.fw_major}.{hello.fw_minor}.{hello.fw_patch}, {hello.tick_hz} Hz"
        )
        if hello.protocol_version != PROTOCOL_VERSION:
            status.say(
                f"warning: the board speaks protocol {hello.protocol_version}, this tool "
                f"{PROTOCOL_VERSION}"
            )

        def run(label: str, parsed: Any) -> None:
            status.say(f"-> {label}: {describe(parsed(), parsed.fields)}")

        try:
            for text in script:
                run(text, parse_command(client, text))
            idle = live.tick if live is not None else None
            if args.interactive:
                _interactive(client, status, args, idle)
            else:
                _timed(client, args, run, live)
        except LinkTimeout as exc:
            status.say(f"link timeout: {exc}")
            _report(client, link, writer, args)
            return 1
        except KeyboardInterrupt:
            status.say("interrupted")
        _report(client, link, writer, args)
        if live is not None and args.plot_save:
            live.plot.save(args.plot_save)
            print(
                f"wrote {args.plot_save} (live plot: {live.plot.frames} frames drawn, "
                f"{live.plot.buffer.received} telemetry frames plotted)"
            )
    return 0


def _live_plot(args: argparse.Namespace) -> Any:
    """The live plot the options ask for (None without --plot/--plot-save)."""
    import math

    from serial_protocol.exceptions import CommandError

    if not (args.plot or args.plot_save):
        return None
    if not (math.isfinite(args.plot_window) and 0.1 <= args.plot_window <= 3600.0):
        raise CommandError(f"--plot-window {args.plot_window!r}: must be 0.1 to 3600 s")
    if not (math.isfinite(args.plot_fps) and 0.5 <= args.plot_fps <= 120.0):
        raise CommandError(f"--plot-fps {args.plot_fps!r}: must be 0.5 to 120")
    if args.plot_save:
        from pathlib import Path

        save = Path(args.plot_save)
        if save.suffix.lower() not in (".png", ".svg", ".pdf"):
            raise CommandError(f"--plot-save {args.plot_save!r}: must end in .png, .svg or .pdf")
        if save.is_dir() or not save.parent.is_dir():
            raise CommandError(f"--plot-save {args.plot_save!r}: not a file in an existing folder")
    import matplotlib

    from sim.liveplot import LiveBuffer, LiveWindow, has_display

    show = args.plot and has_display()
    if args.plot and not show and not args.plot_save:
        raise CommandError(
            f"--plot: matplotlib's backend {matplotlib.get_backend()!r} opens no window (no "
            "display?); set MPLBACKEND (TkAgg, QtAgg) or use --plot-save FILE"
        )
    # room for the window at up to 1 kHz of telemetry
    buffer = LiveBuffer(max(2, int(args.plot_window * 1000.0) + 1))
    return LiveWindow(buffer, args.plot_window, args.plot_fps, show=show, title=args.url)


def parse_command(client: Any, text: str) -> Any:
    """Check one command line and bind it to ``client`` (``sim.shell.parse_command``)."""
    from sim.shell import parse_command as parse

    return parse(client, text)


def _scripted(args: argparse.Namespace) -> list[str]:
    out = []
    if args.clear_fault:
        out.append("clear")
    if args.enable:
        out.append("enable")
    if args.disable:
        out.append("disable")
    if args.limits:
        if not 4 <= len(args.limits) <= 10:
            from serial_protocol.exceptions import CommandError

            raise CommandError(
                f"--limits {' '.join(repr(v) for v in args.limits)}: takes 4 to 10 numbers "
                "(V_MAX A_MAX CURRENT_A FOLLOW_DEG [TRIP_A BUS_OVER_V BUS_UNDER_V DERATE_C "
                "THERMAL_TRIP_C BRAKE_A])"
            )
        out.append("limits " + " ".join(repr(v) for v in args.limits))
    if args.gains_from:
        out += gains_commands(args.gains_from)
    for loop, kp, ki, kd in args.gains:
        out.append(f"gains {loop} {kp} {ki} {kd}")
    if args.telemetry is not None:
        out.append(f"telemetry {args.telemetry}")
    if args.move is not None:
        out.append(_move_text(args, args.move))
    import shlex

    if args.jog is not None:
        if sum(x is not None for x in (args.move, args.program, args.stream)):
            from serial_protocol.exceptions import CommandError

            raise CommandError(
                f"--jog {args.jog!r}: not with --move, --program or --stream (one motion)"
            )
        a_max = args.a_max if args.jog_accel is None else args.jog_accel
        timeout = JOG_TIMEOUT_MS if args.jog_timeout is None else args.jog_timeout
        out.append(f"jog {args.jog!r} {a_max!r} {timeout}")
    else:
        for name, value in (("--jog-accel", args.jog_accel), ("--jog-timeout", args.jog_timeout)):
            if value is not None:
                from serial_protocol.exceptions import CommandError

                raise CommandError(f"{name} {value!r}: only with --jog VEL_DPS")
    if args.program:
        out.append(f"program {shlex.quote(args.program)}")
    if args.stream:
        period = f" {args.stream_period!r}" if args.stream_period is not None else ""
        out.append(f"stream {shlex.quote(args.stream)}{period}")
    elif args.stream_period is not None:
        from serial_protocol.exceptions import CommandError

        raise CommandError(f"--stream-period {args.stream_period!r}: only with --stream FILE")
    return out


def gains_commands(path: str) -> list[str]:
    """The ``gains`` lines that put the loop gains of bench TOML ``path`` on a board
    (current V/A and V/(A s), velocity A/(°/s) and A/°, position 1/s: the config's units,
    which are the firmware's)."""
    from serial_protocol.exceptions import ConfigError
    from sim.config import load_bench
    from sim.tuning.gains import GainSet

    try:
        g = GainSet.from_bench(load_bench(path))
    except ValueError as exc:  # ConfigError names the file already
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"--gains-from {path!r}: {exc}") from None
    return [
        f"gains current {g.kp_i_v_per_a!r} {g.ki_i_v_per_as!r} 0",
        f"gains velocity {g.kp_v_a_per_dps!r} {g.ki_v_a_per_deg!r} 0",
        f"gains position {g.kp_p_per_s!r} 0 0",
    ]


def _move_text(args: argparse.Namespace, target_deg: float) -> str:
    return f"move {target_deg!r} {args.v_max!r} {args.a_max!r} {args.j_max!r} {args.profile}"


#: With a live plot, no frame is started when a timed command is due within this many
#: seconds plus the slowest frame drawn so far.
DRAW_GUARD_S = 0.05


def _timed(client: Any, args: argparse.Namespace, run: Any, live: Any = None) -> None:
    """Listen for ``--duration`` seconds, sending the timed interrupts and stop."""
    import time

    events = sorted([(after, _move_text(args, target)) for after, target in args.interrupt])
    if args.stop is not None:
        events = sorted([*events, (args.stop, "stop")])
    start_wall_s = time.monotonic()
    end_wall_s = start_wall_s + max(args.duration, max((e[0] for e in events), default=0.0))
    while True:
        now_wall_s = time.monotonic()
        while events and now_wall_s - start_wall_s >= events[0][0]:
            _, text = events.pop(0)
            run(text, parse_command(client, text))
        if now_wall_s >= end_wall_s:
            return
        next_s = min(end_wall_s, start_wall_s + events[0][0] if events else end_wall_s)
        # with a live plot, receive until the next frame is due, then draw it
        turn_s = 0.05 if live is None else min(0.05, max(0.002, live.due_in_s()))
        client.collect(min(turn_s, max(0.0, next_s - now_wall_s)))
        # A frame that renders the whole figure (a rescale) takes tens of ms, more on a
        # loaded machine: none is started when a timed command is due sooner than the
        # slowest frame so far (plus DRAW_GUARD_S), so the plot does not delay an interrupt
        # (it pauses instead).
        if live is not None:
            guard_s = DRAW_GUARD_S + live.slowest_frame_s
            if not events or start_wall_s + events[0][0] - time.monotonic() > guard_s:
                live.tick()


def _interactive(client: Any, status: Any, args: argparse.Namespace, idle: Any = None) -> None:
    """The prompt_toolkit shell on a terminal; plain lines from a pipe or a file."""
    import os

    from sim.shell import MonitorShell

    latest = lambda: status.latest  # noqa: E731
    if sys.stdin.isatty() and sys.stdout.isatty():
        # The toolbar shows the status; a line drawn on stderr would tear the prompt.
        status.enabled = False
        history = os.environ.get("TURNTABLE_SIM_HISTORY", "~/.turntable_sim_history")
        shell = MonitorShell(
            client, latest=latest, history_path=os.path.expanduser(history), on_idle=idle
        )
        shell.run()
    else:
        MonitorShell(client, say=status.say, latest=latest, on_idle=idle).run_lines(sys.stdin)


def _report(client: Any, link: Any, writer: Any, args: argparse.Namespace) -> None:
    print(file=sys.stderr)
    s = client.stats
    print(
        f"commands {s.commands}: acks {s.acks}, nacks {s.nacks}, retries {s.retries}, "
        f"timeouts {s.timeouts}; received telemetry {s.telemetry}, fault reports "
        f"{s.fault_reports}, malformed {s.malformed}, stale answers {s.stale_replies}"
    )
    if hasattr(link, "decoder"):
        d = link.stats()
        print(
            f"link: {link.bytes_in} bytes in, {link.bytes_out} out; frames {d.frames}, "
            f"crc errors {d.crc_errors}, header errors {d.header_errors}, resyncs {d.resyncs}, "
            f"bytes dropped {d.bytes_dropped}, sequence gaps {d.seq_gaps} "
            f"(~{d.frames_missed} frames lost)"
        )
    else:
        c = link.reassembler.stats
        print(
            f"CAN: frames in {c.frames}, out {link.frames_out}; messages {c.messages}, "
            f"malformed {c.malformed}, reassembly errors {c.reassembly_errors}"
        )
    if writer is not None:
        print(f"wrote {writer.rows} telemetry rows to {args.csv}")


class _StatusLine:
    """One live line on stderr (rewritten in place at most 10 times a second, at most 80
    columns); ``latest`` keeps the last telemetry for the interactive shell's toolbar."""

    def __init__(self, enabled: bool) -> None:
        import time

        self.enabled = enabled and sys.stderr.isatty()
        self.latest: Any = None
        self.bus_voltage_v = 0.0  # the latest BoardHeartbeat's (0: none)
        self._clock = time.monotonic
        self._last_wall_s = 0.0

    def show(self, msg: Any) -> None:
        self.latest = msg
        if not self.enabled:
            return
        now_wall_s = self._clock()
        if now_wall_s - self._last_wall_s < 0.1:
            return
        self._last_wall_s = now_wall_s
        from sim.shell import status_text

        sys.stderr.write("\r\x1b[K" + status_text(msg, 79, self.bus_voltage_v))
        sys.stderr.flush()

    def say(self, text: str) -> None:
        if self.enabled:
            sys.stderr.write("\r\x1b[K")
        print(text, file=sys.stderr if self.enabled else sys.stdout)


def _open(path: str, mode: str) -> Any:
    from serial_protocol.exceptions import CommandError

    try:
        return open(path, mode, newline="" if "b" not in mode else None)
    except OSError as exc:
        raise CommandError(f"cannot open {path!r}: {exc.strerror}") from exc


def _open_can(url: str, log_path: str | None) -> Any:
    from serial_protocol.can_link import CanLink
    from serial_protocol.exceptions import CommandError

    interface, _, channel = url[len("can://") :].partition("/")
    if not interface or not channel:
        raise CommandError(f"{url!r}: expected can://INTERFACE/CHANNEL")
    return CanLink.open(interface, channel, log_path=log_path)
