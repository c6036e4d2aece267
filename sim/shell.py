"""The monitor's interactive shell (``turntable-sim monitor URL --interactive``).

Built on prompt_toolkit: a prompt with history (Up/Down, Ctrl-R), completion of commands and
their arguments (Tab), a bottom toolbar with the board's live status that never touches the
line being typed and fits 80 columns, replies in words, ``help`` per command. Telemetry keeps
arriving while the user types: a receiver thread drains the link between commands (the
``BoardClient`` is used by one thread at a time, under a lock).

Nothing typed can end the shell: a bad line is one ``error:`` line, a value the wire cannot
carry is refused before it is sent, a board that stops answering is reported and the prompt
comes back. Ctrl-C clears the line, Ctrl-D or ``quit`` ends the session.

The command words and their parsing are in :data:`COMMANDS` and :func:`parse_command` (shared
with the monitor's scripted options), the rendering of replies in :func:`describe`.
"""

from __future__ import annotations

import asyncio
import math
import shlex
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from serial_protocol.exceptions import CommandError, LinkError, LinkTimeout
from serial_protocol.frame import field_name
from serial_protocol.messages import (
    Ack,
    Fault,
    FaultInfo,
    FaultReport,
    Gains,
    HelloReply,
    Limits,
    Loop,
    Malformed,
    Nack,
    NackCode,
    Profile,
    QueueState,
    QueueStatus,
    State,
    Status,
    StreamState,
    StreamStatus,
    Telemetry,
)

__all__ = [
    "COMMANDS",
    "CommandSpec",
    "MonitorShell",
    "ParsedCommand",
    "describe",
    "help_text",
    "parse_command",
    "status_text",
]

#: Width the toolbar must fit (a classic terminal).
TOOLBAR_COLUMNS = 80

#: Defaults of ``move`` when a rate is not given (the paper's Fig. 8 limits).
MOVE_DEFAULTS = {"v_max_dps": 990.0, "a_max_dps2": 148.0, "j_max_dps3": 0.0}

LOOP_WORDS = tuple(loop.name.lower() for loop in Loop)
#: ``limits``' optional thresholds after the over-current trip (SetLimits' appended fields).
_THRESHOLDS = (
    "bus_over_voltage_v", "bus_under_voltage_v", "thermal_derate_c", "thermal_trip_c",
    "brake_current_limit_a",
)  # fmt: skip
PROFILE_WORDS = tuple(p.name.lower() for p in Profile)


@dataclass(frozen=True)
class CommandSpec:
    """One command of the shell: its usage line and what it does."""

    usage: str
    summary: str
    detail: str = ""


COMMANDS: dict[str, CommandSpec] = {
    "move": CommandSpec(
        "move TARGET_DEG [V_MAX_DPS [A_MAX_DPS2 [J_MAX_DPS3]]] [trapezoid|scurve|step]",
        "move the gearmotor output shaft to TARGET_DEG (axis degrees)",
        "Rates default to v_max 990 deg/s, a_max 148 deg/s^2 (the paper's Fig. 8); an "
        "s-curve needs J_MAX_DPS3 > 0; 'step' jumps the setpoint (no planning, Fig. 6). A "
        "move while moving is the paper's interrupt: the board replans from where it is.",
    ),
    "stop": CommandSpec(
        "stop [A_MAX_DPS2]",
        "decelerate to rest and hold",
        "Without a rate the board uses its configured a_max.",
    ),
    "enable": CommandSpec("enable", "enable the bridge (the servo holds its position)"),
    "disable": CommandSpec("disable", "disable the bridge (the motor coasts)"),
    "clear": CommandSpec("clear", "clear a latched fault"),
    "status": CommandSpec("status", "ask the board for its state, position and velocity"),
    "gains": CommandSpec(
        "gains current|velocity|position KP KI KD",
        "set the gains of one loop",
        "The board refuses gains its stability check rejects; nothing is half-applied.",
    ),
    "getgains": CommandSpec("getgains current|velocity|position", "read the gains of one loop"),
    "limits": CommandSpec(
        "limits V_MAX_DPS A_MAX_DPS2 CURRENT_A FOLLOW_DEG [TRIP_A [BUS_OVER_V [BUS_UNDER_V "
        "[DERATE_C [THERMAL_TRIP_C [BRAKE_A]]]]]]",
        "set the motion limits, the current clamp and the trip thresholds",
        "CURRENT_A clamps the current (never trips); TRIP_A is the over-current trip "
        "threshold, BUS_OVER_V / BUS_UNDER_V the bus voltage trips, DERATE_C / THERMAL_TRIP_C "
        "where the thermal protection starts derating and trips, BRAKE_A the cap on the brake "
        "after a trip (each absent or 0: keep the board's). Out-of-range values are refused, "
        "never clipped.",
    ),
    "fault": CommandSpec(
        "fault BIT", "details of fault flag BIT (0..31): tick, value and threshold"
    ),
    "getlimits": CommandSpec("getlimits", "read the motion limits and trip thresholds"),
    "telemetry": CommandSpec(
        "telemetry DECIMATION", "telemetry every DECIMATION ticks (1 = 500 Hz, 0 = off)"
    ),
    "hello": CommandSpec(
        "hello", "open a new session: the board's protocol, firmware and capabilities"
    ),
    "jog": CommandSpec(
        "jog VEL_DPS [A_MAX_DPS2 [TIMEOUT_MS]]",
        "move at VEL_DPS (signed) until stopped or the travel end",
        "A_MAX_DPS2 defaults to 148 deg/s^2; TIMEOUT_MS (default 0 = none) stops the jog when "
        "nothing is sent for that long (the shell's heartbeats count).",
    ),
    "program": CommandSpec(
        "program FILE",
        "send a motion program file (TOML [[segment]] tables)",
        "The blocks go into the board's queue with flow control; the board plans junction "
        "speeds over what it holds (docs/protocol.md 4.5). See sim/motionfile.py.",
    ),
    "stream": CommandSpec(
        "stream FILE [PERIOD_S]",
        "stream a point file (TOML or CSV) at a fixed period",
        "PERIOD_S overrides the file's period_s (a CSV file needs it). Points with velocities "
        "are interpolated as PVT (cubic), else linearly (docs/protocol.md 4.6).",
    ),
    "queue": CommandSpec("queue", "the program queue: state, free slots, blocks done"),
    "hold": CommandSpec("hold", "feed hold: stop the program on its path, keep the blocks"),
    "resume": CommandSpec("resume", "resume a held program"),
    "abort": CommandSpec("abort", "stop and empty the program queue"),
    "override": CommandSpec("override PCT", "speed override of the program, 10..200 %"),
    "help": CommandSpec("help [COMMAND]", "list the commands, or explain one"),
    "quit": CommandSpec("quit", "end the session (also Ctrl-D)"),
}


# ---------------------------------------------------------------------------- parsing


@dataclass(frozen=True)
class ParsedCommand:
    """A checked command line: ``call()`` sends it through the client and returns the reply.

    ``fields`` are the message fields the line set (name -> value), used to say which value
    a board refused.
    """

    verb: str
    call: Callable[[], Any]
    fields: dict[str, Any] = field(default_factory=dict)

    def __call__(self) -> Any:
        return self.call()


def _number(text: str, word: str, name: str) -> float:
    try:
        value = float(word)
    except ValueError:
        raise CommandError(f"{text!r}: {name} = {word!r} is not a number") from None
    if not math.isfinite(value):
        raise CommandError(f"{text!r}: {name} = {word!r} is not a finite number")
    return value


def _fit(text: str, message: Any) -> None:
    """Refuse a value the wire cannot carry (asked of the codec, ``sim.wire``)."""
    from sim.wire import wire_problem

    problem = wire_problem(message)
    if problem:
        raise CommandError(f"{text!r}: {problem}")


def parse_command(client: Any, text: str) -> ParsedCommand:
    """Check one command line (see :data:`COMMANDS`) and bind it to ``client``.

    Raises ``CommandError`` naming the bad word or the value that does not fit its wire
    field; nothing is sent (``client`` is not touched) until the result is called.
    """
    from serial_protocol import messages as m

    try:
        words = shlex.split(text)
    except ValueError as exc:  # an unclosed quote
        raise CommandError(f"{text!r}: {exc}") from None
    if not words:
        raise CommandError("empty command")
    verb, rest = words[0].lower(), words[1:]
    spec = COMMANDS.get(verb)
    if spec is None or verb in ("help", "quit"):
        raise CommandError(f"{text!r}: unknown command {words[0]!r} (type 'help')")

    def numbers(names: list[str], required: int) -> dict[str, float]:
        if not required <= len(rest) <= len(names):
            count = str(required) if required == len(names) else f"{required} to {len(names)}"
            raise CommandError(f"{text!r}: {verb} takes {count} numbers: {spec.usage}")
        return {n: _number(text, w, n) for n, w in zip(names, rest, strict=False)}

    def loop(word: str) -> Loop:
        if word.lower() not in LOOP_WORDS:
            raise CommandError(f"{text!r}: loop {word!r} must be current, velocity or position")
        return Loop[word.upper()]

    if verb == "move":
        profile = Profile.TRAPEZOID
        if rest and rest[-1].lower() in PROFILE_WORDS:
            profile = Profile[rest.pop().upper()]
        values = {**MOVE_DEFAULTS, **numbers(["target_deg", *MOVE_DEFAULTS], 1)}
        if profile is Profile.SCURVE and not values["j_max_dps3"] > 0:
            raise CommandError(f"{text!r}: an scurve move needs J_MAX_DPS3 > 0")
        fields = {**values, "profile": profile}
        _fit(text, m.Move(0, **values, profile=profile))
        return ParsedCommand(verb, lambda: client.move(**values, profile=profile), fields)
    if verb == "stop":
        values = numbers(["a_max_dps2"], 0)
        _fit(text, m.Stop(0, *values.values()))
        return ParsedCommand(verb, lambda: client.stop(*values.values()), values)
    if verb == "gains":
        if len(rest) != 4:
            raise CommandError(f"{text!r}: {spec.usage}")
        which = loop(rest[0])
        rest = rest[1:]
        values = numbers(["kp", "ki", "kd"], 3)
        _fit(text, m.SetGains(0, which, **values))
        return ParsedCommand(
            verb, lambda: client.set_gains(which, **values), {"loop": which, **values}
        )
    if verb == "getgains":
        if len(rest) != 1:
            raise CommandError(f"{text!r}: {spec.usage}")
        which = loop(rest[0])
        return ParsedCommand(verb, lambda: client.get_gains(which), {"loop": which})
    if verb == "limits":
        names = ["v_max_dps", "a_max_dps2", "current_limit_a", "following_error_deg"]
        thresholds = ["over_current_trip_a", *_THRESHOLDS]
        values = numbers([*names, *thresholds], 4)
        _fit(text, m.SetLimits(0, **values))
        return ParsedCommand(verb, lambda: client.set_limits(**values), values)
    if verb == "fault":
        bit = numbers(["bit"], 1)["bit"]
        if bit != int(bit) or not 0 <= bit <= 31:
            raise CommandError(f"{text!r}: bit = {rest[0]} must be an integer 0..31")
        return ParsedCommand(verb, lambda: client.get_fault(int(bit)), {"bit": int(bit)})
    if verb == "jog":
        values = {"a_max_dps2": 148.0, "timeout_ms": 0.0,
                  **numbers(["vel_dps", "a_max_dps2", "timeout_ms"], 1)}  # fmt: skip
        timeout = values["timeout_ms"]
        if timeout != int(timeout) or not 0 <= timeout <= 0xFFFF:
            raise CommandError(f"{text!r}: timeout_ms = {timeout:g} must be an integer 0..65535")
        values["timeout_ms"] = int(timeout)
        _fit(text, m.Jog(0, **values))
        return ParsedCommand(verb, lambda: client.jog(**values), values)
    if verb == "override":
        values = numbers(["override_pct"], 1)
        _fit(text, m.QueueControl(0, m.QueueAction.OVERRIDE, values["override_pct"]))
        return ParsedCommand(verb, lambda: client.set_override(values["override_pct"]), values)
    if verb in ("program", "stream"):
        from serial_protocol.exceptions import ConfigError
        from sim.motionfile import load_points, load_program

        if not 1 <= len(rest) <= (2 if verb == "stream" else 1):
            raise CommandError(f"{text!r}: {spec.usage}")
        try:
            if verb == "program":
                prog = load_program(rest[0])
                return ParsedCommand(verb, lambda: client.send_program(list(prog.blocks)))
            period = _number(text, rest[1], "period_s") if len(rest) == 2 else None
            pts = load_points(rest[0], period)
        except ConfigError as exc:
            raise CommandError(f"{text!r}: {exc}") from None
        vel = list(pts.vel_dps) if pts.vel_dps is not None else None
        return ParsedCommand(
            verb,
            lambda: client.stream(
                list(pts.pos_deg), pts.period_s, vel_dps=vel, interp=pts.interp
            ),  # fmt: skip
            {"period_s": pts.period_s},
        )
    if verb == "telemetry":
        value = numbers(["decimation"], 1)["decimation"]
        if value != int(value) or not 0 <= value <= 0xFFFF:
            raise CommandError(f"{text!r}: decimation = {rest[0]} must be an integer 0..65535")
        return ParsedCommand(
            verb, lambda: client.set_telemetry(int(value)), {"decimation": int(value)}
        )
    if rest:
        raise CommandError(f"{text!r}: {verb} takes no arguments")
    simple: dict[str, Callable[[], Any]] = {
        "clear": lambda: client.clear_fault(),
        "status": lambda: client.status(),
        "hello": lambda: client.hello(),
        "getlimits": lambda: client.get_limits(),
        "enable": lambda: client.set_enable(True),
        "disable": lambda: client.set_enable(False),
        "queue": lambda: client.queue_status(),
        "hold": lambda: client.hold(),
        "resume": lambda: client.resume(),
        "abort": lambda: client.abort(),
    }
    return ParsedCommand(verb, simple[verb])


# ---------------------------------------------------------------------------- words

_NACK_WORDS = {
    NackCode.UNKNOWN_TYPE: "the board does not know this command",
    NackCode.BAD_LENGTH: "the board expected another length (a protocol version mismatch?)",
    NackCode.NOT_FINITE: "a value is not a finite number",
    NackCode.OUT_OF_RANGE: "a value is out of range",
    NackCode.UNSTABLE_GAINS: "the board's stability check rejects these gains",
    NackCode.FAULT_ACTIVE: "a fault is latched (type 'clear' first)",
    NackCode.DISABLED: "the bridge is disabled (type 'enable' first)",
    NackCode.NOT_A_COMMAND: "a board-to-PC message was sent to the board",
    NackCode.NO_SESSION: "no session is open (type 'hello')",
    NackCode.STALE_SESSION: "another program has opened a session since (type 'hello')",
    NackCode.UNSUPPORTED_VERSION: "the board speaks another protocol version",
    NackCode.TOO_HIGH: "a value is above its limit",
    NackCode.TOO_LOW: "a value is below its limit",
    NackCode.BUSY: "not while moving",
    NackCode.TRAVEL: "the trajectory would leave the travel",
    NackCode.QUEUE_FULL: "the program or point queue is full",
    NackCode.NO_STREAM: "no stream is open to take points",
    NackCode.SENSE_OFFSET: "the current-sense offset calibrated at enable is implausible",
}


def _g(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _refused(reply: Nack, fields: dict[str, Any]) -> str:
    code = NackCode(reply.code) if reply.code in NackCode._value2member_map_ else reply.code
    reason = _NACK_WORDS.get(code, f"code {reply.code}")
    # The NACK names the refused field by its index on the wire (and the bound it broke).
    name = field_name(reply.msg_type, reply.field)
    if code is NackCode.TRAVEL:
        return f"refused: {reason} (it would cross {_g(reply.limit)} deg)"
    if name is None:
        return f"refused: {reason}"
    what = f"{name} = {_g(fields[name])}" if name in fields else name
    if code is NackCode.TOO_HIGH:
        return f"refused: {what} > limit {_g(reply.limit)}"
    if code is NackCode.TOO_LOW:
        return f"refused: {what} < limit {_g(reply.limit)}"
    return f"refused: {what}: {reason}"


def describe(reply: Any, fields: dict[str, Any] | None = None) -> str:
    """One line in words for a board's answer (``fields``: what the command sent)."""
    fields = fields or {}
    if isinstance(reply, Ack):
        return "ok"
    if isinstance(reply, Nack):
        return _refused(reply, fields)
    if isinstance(reply, Status):
        fault = "" if reply.fault == Fault.NONE else f", fault {_name(Fault, reply.fault)}"
        # the IS offsets the board subtracts (calibrated at enable), when it has them: one
        # per pin, shown once when alike (or from an older board, which sends one)
        pos_a, neg_a = reply.sense_offset_a, reply.sense_offset_neg_a
        offset = ""
        if neg_a not in (0.0, pos_a):
            offset = f", IS offsets {pos_a:.3f} A (duty > 0) / {neg_a:.3f} A (duty < 0)"
        elif pos_a:
            offset = f", IS offset {pos_a:.3f} A"
        return (
            f"{_name(State, reply.state)}{fault}: position {reply.pos_deg:.3f} deg, velocity "
            f"{reply.vel_dps:.1f} deg/s, target {reply.target_deg:.3f} deg{offset} "
            f"(tick {reply.tick})"
        )
    if isinstance(reply, Gains):
        return (
            f"{_name(Loop, reply.loop).lower()} loop: kp {reply.kp:g}, ki {reply.ki:g}, "
            f"kd {reply.kd:g}"
        )
    if isinstance(reply, Limits):
        text = (
            f"v_max {reply.v_max_dps:g} deg/s, a_max {reply.a_max_dps2:g} deg/s^2, current "
            f"limit {reply.current_limit_a:g} A, following error {reply.following_error_deg:g} "
            f"deg, over-current trip {reply.over_current_trip_a:g} A"
        )
        if reply.bus_over_voltage_v or reply.bus_under_voltage_v:
            text += f", bus trips {reply.bus_under_voltage_v:g}..{reply.bus_over_voltage_v:g} V"
        if reply.thermal_trip_c:
            text += (
                f", thermal derate {reply.thermal_derate_c:g} degC, trip "
                f"{reply.thermal_trip_c:g} degC (winding {reply.winding_estimate_c:.1f} degC)"
            )
        if reply.brake_current_limit_a:
            text += f", brake after a trip capped at {reply.brake_current_limit_a:g} A"
        return text
    if isinstance(reply, HelloReply):
        return (
            f"protocol {reply.protocol_version}, firmware {reply.fw_major}.{reply.fw_minor}."
            f"{reply.fw_patch}, {reply.tick_hz} Hz servo, {reply.counts_per_rev} counts/rev"
        )
    if isinstance(reply, FaultReport):
        return f"FAULT {_name(Fault, reply.fault)} at tick {reply.tick} (value {reply.value:g})"
    if isinstance(reply, FaultInfo):
        if not reply.latched:
            return f"fault bit {reply.bit}: not latched"
        return (
            f"fault bit {reply.bit}: tripped at tick {reply.tick}, value {reply.value:g}, "
            f"threshold {reply.threshold:g}"
        )
    if isinstance(reply, QueueStatus):
        return (
            f"program {_name(QueueState, reply.state)}: {reply.queued} block(s) queued, "
            f"{reply.free_slots} free, {reply.done} done, override {reply.override_pct:g} %"
        )
    if isinstance(reply, StreamStatus):
        return (
            f"stream {_name(StreamState, reply.state)}: next point {reply.next_index}, "
            f"{reply.free_slots} free, {reply.underruns} underrun(s) since boot"
        )
    if isinstance(reply, Malformed):
        return f"malformed frame from the board: {reply}"
    return str(reply)


def _name(enum: Any, value: int) -> str:
    try:
        return enum(value).name
    except ValueError:
        return f"{enum.__name__.lower()} {value}"


def status_text(
    msg: Telemetry | None, width: int = TOOLBAR_COLUMNS, bus_voltage_v: float = 0.0
) -> str:
    """The toolbar line for the latest telemetry (at most ``width`` characters), with the
    bus voltage it carries, or else (an older board's telemetry) that of the latest
    ``BoardHeartbeat`` (``bus_voltage_v``; 0: none reported)."""
    if msg is None:
        return "no telemetry yet ('telemetry 1' asks for it)"[:width]
    fault = "" if msg.fault == Fault.NONE else f" {_name(Fault, msg.fault)}"
    bus_voltage_v = getattr(msg, "bus_voltage_v", 0.0) or bus_voltage_v
    bus = f" {bus_voltage_v:4.1f}V" if bus_voltage_v > 0.0 else ""
    text = (
        f"{_name(State, msg.state):<8} pos {msg.pos_deg:>10.2f}° sp {msg.sp_pos_deg:>10.2f}° "
        f"v {msg.vel_dps:>7.1f}°/s I {msg.current_a:>5.2f} A{bus}{fault}"
    )
    return text if len(text) <= width else text[: width - 1] + "…"


def _bus_voltage_v(client: Any) -> float:
    """The bus voltage of the client's latest ``BoardHeartbeat`` (0: none yet)."""
    heartbeat = getattr(client, "last_heartbeat", None)
    return float(getattr(heartbeat, "bus_voltage_v", 0.0) or 0.0)


def help_text(word: str | None = None) -> str:
    """``help`` (every command, one line each) or ``help WORD``."""
    if word:
        spec = COMMANDS.get(word.lower())
        if spec is None:
            return f"no command {word!r}; commands: {', '.join(COMMANDS)}"
        lines = [f"usage: {spec.usage}", f"  {spec.summary}"]
        if spec.detail:
            import textwrap

            lines += textwrap.wrap(spec.detail, 76, initial_indent="  ", subsequent_indent="  ")
        return "\n".join(lines)
    width = max(map(len, COMMANDS))
    rows = [f"  {name:<{width}}  {spec.summary}" for name, spec in COMMANDS.items()]
    return "\n".join(
        ["commands (angles in degrees of the gearmotor output shaft):", *rows, "Tab completes."]
    )


# ---------------------------------------------------------------------------- completion


def completions(text_before_cursor: str) -> list[str]:
    """Words that may complete the word under the cursor (pure; the Completer wraps it)."""
    words = text_before_cursor.split()
    if text_before_cursor and not text_before_cursor[-1].isspace():
        current = words.pop() if words else ""
    else:
        current = ""
    if not words:
        options: Iterable[str] = COMMANDS
    else:
        verb = words[0].lower()
        if verb in ("gains", "getgains") and len(words) == 1:
            options = LOOP_WORDS
        elif verb == "help" and len(words) == 1:
            options = COMMANDS
        elif verb == "move" and len(words) >= 2 and not any(w in PROFILE_WORDS for w in words):
            options = PROFILE_WORDS
        else:
            options = ()
    return [o for o in options if o.startswith(current.lower())]


def _completer() -> Any:
    from prompt_toolkit.completion import Completer, Completion

    class MonitorCompleter(Completer):
        def get_completions(self, document: Any, complete_event: Any) -> Any:
            before = document.text_before_cursor
            current = "" if not before or before[-1].isspace() else before.split()[-1]
            for word in completions(before):
                spec = COMMANDS.get(word)
                yield Completion(
                    word, -len(current), display_meta=spec.summary if spec is not None else ""
                )

    return MonitorCompleter()


# ---------------------------------------------------------------------------- the shell


class MonitorShell:
    """The interactive session over a ``BoardClient``.

    Args:
        client: a ``serial_protocol.host.BoardClient`` (any object with its methods).
        say: where lines for the user go (default: printed above the prompt).
        latest: returns the latest telemetry (or None), shown in the toolbar.
        history_path: a file for the history across sessions (None: this session only).
        input, output: prompt_toolkit ``Input``/``Output`` (tests pass a pipe and a
            ``DummyOutput``); default the terminal.
        poll_s: how long the receiver thread holds the link per turn (wall seconds).
        on_idle: called every ``idle_s`` in the main thread while the prompt waits (the live
            plot's redraw: a GUI must be driven from the main thread).
    """

    def __init__(
        self,
        client: Any,
        *,
        say: Callable[[str], None] | None = None,
        latest: Callable[[], Telemetry | None] | None = None,
        history_path: str | None = None,
        input: Any = None,  # noqa: A002 - prompt_toolkit's name
        output: Any = None,
        poll_s: float = 0.02,
        on_idle: Callable[[], None] | None = None,
        idle_s: float = 0.02,
    ) -> None:
        self.client = client
        self._say = say
        self._latest = latest or (lambda: None)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._poll_s = poll_s
        self.errors = 0
        self.link_error: str | None = None
        self._history_path = history_path
        self._input = input
        self._output = output
        self.session: Any = None  # the PromptSession while run() runs
        self._on_idle = on_idle
        self._idle_s = idle_s

    def say(self, text: str) -> None:
        if self._say is not None:
            self._say(text)
        else:
            from prompt_toolkit import print_formatted_text

            print_formatted_text(text)

    def toolbar(self) -> str:
        """The bottom toolbar's text: the live status, or a broken link."""
        if self.link_error is not None:
            return f"link lost: {self.link_error}"[:TOOLBAR_COLUMNS]
        return status_text(self._latest(), bus_voltage_v=_bus_voltage_v(self.client))

    def execute(self, line: str) -> bool:
        """Run one typed line; False when the session should end. Never raises for any
        text (errors are said, counted in ``errors``)."""
        line = line.strip()
        if not line or line.startswith("#"):
            return True
        word, _, rest = line.partition(" ")
        word = word.lower()
        if word in ("quit", "exit"):
            return False
        if word in ("help", "?"):
            self.say(help_text(rest.strip() or None))
            return True
        try:
            parsed = parse_command(self.client, line)
            with self._lock:
                reply = parsed()
        except CommandError as exc:
            self.errors += 1
            self.say(f"error: {exc}")
        except LinkTimeout as exc:
            self.errors += 1
            self.say(f"no answer from the board: {exc}")
        except LinkError as exc:
            self.errors += 1
            self.link_error = str(exc)
            self.say(f"link error: {exc}")
        except ValueError as exc:  # the codec refuses a value the wire cannot carry
            self.errors += 1
            self.say(f"not sent: {exc}")
        else:
            self.say(f"{parsed.verb}: {describe(reply, parsed.fields)}")
        return True

    # -------------------------------------------------------------- receiving thread

    def _receive(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                try:
                    self.client.collect(self._poll_s)
                except LinkError as exc:
                    self.link_error = str(exc)
                    self._stop.wait(0.5)
            # Let a command waiting for the lock have it before the next turn.
            time.sleep(0.001)

    def run(self) -> None:
        """Prompt until ``quit``, Ctrl-D or the end of the input."""
        from prompt_toolkit import PromptSession
        from prompt_toolkit.auto_suggest import AutoSuggestFromHistory
        from prompt_toolkit.history import FileHistory, InMemoryHistory
        from prompt_toolkit.patch_stdout import patch_stdout

        history: Any = InMemoryHistory()
        if self._history_path is not None:
            try:
                with open(self._history_path, "ab"):  # readable and writable, or say so
                    pass
                history = FileHistory(self._history_path)
            except OSError as exc:
                self.say(f"history not kept ({self._history_path}: {exc.strerror})")
                history = InMemoryHistory()
        self.session = session = PromptSession(
            history=history,
            completer=_completer(),
            complete_while_typing=False,
            auto_suggest=AutoSuggestFromHistory(),
            bottom_toolbar=self.toolbar,
            refresh_interval=0.1,
            input=self._input,
            output=self._output,
        )
        receiver = threading.Thread(target=self._receive, name="monitor-rx", daemon=True)
        receiver.start()
        try:
            with patch_stdout(raw=True):
                self.say("type 'help' for the commands, Tab to complete, 'quit' to end")
                asyncio.run(self._prompt_loop(session))
        finally:
            self._stop.set()
            receiver.join(timeout=2.0)

    async def _prompt_loop(self, session: Any) -> None:
        idler = asyncio.create_task(self._idle()) if self._on_idle is not None else None
        try:
            while True:
                try:
                    line = await session.prompt_async("turntable> ")
                except KeyboardInterrupt:
                    continue  # Ctrl-C clears the line, as in a shell
                except EOFError:
                    return
                if not self.execute(line):
                    return
        finally:
            if idler is not None:
                idler.cancel()

    async def _idle(self) -> None:
        while True:
            try:
                self._on_idle()  # type: ignore[misc]
            except Exception as exc:  # a broken plot window must not end the session
                self.say(f"live plot stopped: {exc}")
                return
            await asyncio.sleep(self._idle_s)

    def run_lines(self, stream: Any) -> None:
        """Read commands from a pipe or file (no terminal): one per line, receiving
        telemetry while none is waiting, until ``quit`` or the end of the input."""
        import select

        self.say("reading commands from the input ('help' lists them)")
        fileno = getattr(stream, "fileno", None)
        try:
            fd = fileno() if fileno is not None else None
        except (OSError, ValueError):  # io.StringIO and friends
            fd = None
        while True:
            if fd is not None:
                ready, _, _ = select.select([fd], [], [], 0.0)
                if not ready:
                    try:
                        self.client.collect(0.05 if self._on_idle is None else 0.01)
                    except LinkError as exc:
                        self.link_error = str(exc)
                        self.say(f"link error: {exc}")
                        return
                    continue
            if self._on_idle is not None:
                self._on_idle()
            raw = stream.readline()
            if not raw:
                return  # end of input
            if not self.execute(raw):
                return
