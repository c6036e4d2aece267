"""The monitor's interactive shell, driven through prompt_toolkit's test harness (a pipe for
the keyboard, a DummyOutput for the screen) against the real firmware behind the emulated
UART (``sim.simlink.SimulatedLink``, stepped a fixed number of ticks per poll)."""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from prompt_toolkit.input import create_pipe_input
from prompt_toolkit.output import DummyOutput

import bench_configs
from serial_protocol.frame import field_index
from serial_protocol.host import BoardClient
from serial_protocol.messages import (
    NO_FIELD,
    Ack,
    Fault,
    Limits,
    Move,
    Nack,
    NackCode,
    SetEnable,
    SetLimits,
    State,
    Status,
    Telemetry,
)
from sim.config import load_bench
from sim.loop import Simulation
from sim.shell import (
    COMMANDS,
    TOOLBAR_COLUMNS,
    MonitorShell,
    completions,
    describe,
    help_text,
    status_text,
)
from sim.simlink import SimulatedLink


@pytest.fixture(scope="module")
def bench():
    return load_bench(bench_configs.path("paper_bench.toml"))


@pytest.fixture
def board(bench):
    sim = Simulation(bench, keep_log=False)
    link = SimulatedLink(sim, ticks_per_poll=5)
    client = BoardClient(link, ack_timeout_s=1.0, retries=0)
    return sim, link, client


def run_shell(client, keys: str):
    """Type ``keys`` into the shell; return (shell, lines it said)."""
    said: list[str] = []
    latest = lambda: client.telemetry[-1] if client.telemetry else None  # noqa: E731
    with create_pipe_input() as inp:
        inp.send_text(keys)
        shell = MonitorShell(
            client, say=said.append, latest=latest, input=inp, output=DummyOutput()
        )
        shell.run()
    return shell, said


def test_a_session_moves_the_real_firmware_and_answers_in_words(board):
    sim, _, client = board
    keys = "enable\rmove 30 100 400\rstatus\rgetgains velocity\rfly\rmove nan\rquit\r"
    shell, said = run_shell(client, keys)
    assert "enable: ok" in said
    assert "move: ok" in said
    status = next(s for s in said if s.startswith("status: "))
    assert "deg" in status and "target 30.000 deg" in status
    assert any(s.startswith("getgains: velocity loop: kp ") for s in said)
    assert any(s.startswith("error: 'fly': unknown command") for s in said)
    assert any("target_deg = 'nan' is not a finite number" in s for s in said)
    assert shell.errors == 2
    # the telemetry kept arriving while the prompt waited
    assert client.stats.telemetry > 0 and sim.tick > 0


def test_history_recalls_the_last_line(board):
    import threading
    import time

    _, _, client = board
    said: list[str] = []
    with create_pipe_input() as inp:
        shell = MonitorShell(client, say=said.append, input=inp, output=DummyOutput())

        def type_up_arrow() -> None:
            # Up is typed once the second prompt runs with the history loaded (prompt_toolkit
            # loads it in the background), as a person would type it.
            end = time.monotonic() + 60.0
            while time.monotonic() < end:
                session = shell.session
                if (
                    session is not None
                    and session.app.is_running
                    and len(session.default_buffer._working_lines) >= 2
                ):
                    break
                time.sleep(0.01)
            inp.send_text("\x1b[A\rquit\r")

        inp.send_text("status\r")
        typist = threading.Thread(target=type_up_arrow, daemon=True)
        typist.start()
        shell.run()
        typist.join(timeout=5)
    assert sum(s.startswith("status: ") for s in said) == 2
    assert client.stats.commands == 3  # the Hello that opened the session, two GetStatus


def type_when(shell, inp, steps) -> None:
    """Send each ``(keys, wait_for)``: ``keys`` once the prompt's line reads ``wait_for``
    (completion runs in the background in prompt_toolkit, as the user would wait for it)."""
    import threading
    import time

    def typist() -> None:
        for keys, wait_for in steps:
            end = time.monotonic() + 60.0
            while time.monotonic() < end:
                session = shell.session
                if session is not None and session.default_buffer.text == wait_for:
                    break
                time.sleep(0.01)
            inp.send_text(keys)

    thread = threading.Thread(target=typist, daemon=True)
    thread.start()
    return thread


def test_tab_completes_a_command_and_its_loop_argument(board):
    _, _, client = board
    said: list[str] = []
    with create_pipe_input() as inp:
        shell = MonitorShell(client, say=said.append, input=inp, output=DummyOutput())
        steps = [("getg\t", ""), (" vel\t", "getgains"), ("\rquit\r", "getgains velocity")]
        typist = type_when(shell, inp, steps)
        shell.run()
        typist.join(timeout=5)
    assert any(s.startswith("getgains: velocity loop: kp ") for s in said), said


def test_ctrl_d_ends_and_ctrl_c_only_clears_the_line(board):
    _, _, client = board
    shell, said = run_shell(client, "move 10\x03status\r\x04")
    assert not any(s.startswith("move:") for s in said)
    assert any(s.startswith("status:") for s in said)


def test_refusals_are_said_in_words(board):
    sim, _, client = board
    keys = "disable\rmove 10\rgains velocity -1 0 0\rquit\r"
    shell, said = run_shell(client, keys)
    # with the bridge disabled the move is refused, with the reason
    assert "move: refused: the bridge is disabled (type 'enable' first)" in said
    assert "gains: refused: kp = -1 < limit 0" in said


def test_describe_names_the_field_of_a_v2_nack():
    fields = {"v_max_dps": 2000.0, "a_max_dps2": 148.0}
    v_max = field_index(SetLimits, "v_max_dps")
    refused = Nack(1, SetLimits.MSG_TYPE, NackCode.TOO_HIGH, v_max, 990.0)
    assert describe(refused, fields) == "refused: v_max_dps = 2000 > limit 990"
    a_max = field_index(SetLimits, "a_max_dps2")
    refused = Nack(1, SetLimits.MSG_TYPE, NackCode.NOT_FINITE, a_max)
    assert describe(refused, fields) == "refused: a_max_dps2 = 148: a value is not a finite number"
    plain = Nack(1, Move.MSG_TYPE, NackCode.FAULT_ACTIVE)
    assert describe(plain) == "refused: a fault is latched (type 'clear' first)"
    assert describe(Ack(1, 2)) == "ok"
    limits = describe(Limits(1, 990.0, 148.0, 5.0, 10.0))
    assert limits.startswith("v_max 990 deg/s, a_max 148 deg/s^2")
    assert "brake" not in limits  # no cap: the full short
    capped = describe(Limits(1, 990.0, 148.0, 5.0, 10.0, brake_current_limit_a=5.0))
    assert capped.endswith(", brake after a trip capped at 5 A")
    status = Status(1, 7, State.IDLE, Fault.NONE, 1.0, 0.0, 1.0)
    assert describe(status) == (
        "IDLE: position 1.000 deg, velocity 0.0 deg/s, target 1.000 deg (tick 7)"
    )
    calibrated = dataclasses.replace(status, sense_offset_a=0.4247)
    assert "target 1.000 deg, IS offset 0.425 A (tick 7)" in describe(calibrated)
    both = dataclasses.replace(calibrated, sense_offset_neg_a=0.2123)
    assert "IS offsets 0.425 A (duty > 0) / 0.212 A (duty < 0) (tick 7)" in describe(both)
    refused = Nack(1, SetEnable.MSG_TYPE, NackCode.SENSE_OFFSET, NO_FIELD, 1.7)
    assert "offset" in describe(refused)


@given(
    state=st.sampled_from(State),
    fault=st.sampled_from(Fault),
    value=st.floats(-2.1e5, 2.1e5),
    vel=st.floats(-1e5, 1e5),
    current=st.floats(-100.0, 100.0),
)
@settings(max_examples=200, deadline=None)
def test_the_toolbar_fits_80_columns(state, fault, value, vel, current):
    msg = Telemetry(1, value, vel, value, vel, current, 0.0, state, fault)
    assert len(status_text(msg)) <= TOOLBAR_COLUMNS
    assert status_text(msg).startswith(state.name)
    assert len(status_text(None)) <= TOOLBAR_COLUMNS


def test_completion_words():
    assert completions("") == list(COMMANDS)
    assert completions("mo") == ["move"]
    assert completions("gains v") == ["velocity"]
    assert completions("getgains ") == ["current", "velocity", "position"]
    assert completions("move 10 s") == ["scurve", "step"]
    assert completions("move 10 scurve ") == []
    assert completions("help te") == ["telemetry"]


def test_help_per_command():
    assert help_text("move").startswith("usage: move TARGET_DEG")
    assert "no command 'fly'" in help_text("fly")
    every = help_text()
    assert all(name in every for name in COMMANDS)
    assert max(map(len, every.splitlines())) <= 80


# Anything typed: the shell says something and goes on, never raises, never half-sends.
words = st.sampled_from(
    [*COMMANDS, "nan", "inf", "-inf", "1e400", "1e30", "-1", "0", "3e6", "velocity",
     "scurve", "'", '"', "\\", "#", "x", "1", "2.5", "\x00", "é"]
)  # fmt: skip


@given(st.lists(st.lists(words, max_size=7).map(" ".join), max_size=6) | st.lists(st.text()))
@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
def test_no_typed_line_can_crash_the_shell(board, lines):
    _, _, client = board
    said: list[str] = []
    shell = MonitorShell(client, say=said.append)
    for line in lines:
        assert shell.execute(line) in (True, False)


def test_values_the_wire_cannot_carry_are_not_sent(board):
    _, link, client = board
    said: list[str] = []
    shell = MonitorShell(client, say=said.append)
    before = link.frames_out
    shell.execute("move 1e30")
    # refused when parsed, with the wire field's range (sim.wire), before anything is sent
    assert said[-1].startswith("error: 'move 1e30': target_deg = 1e+30: does not fit the wire")
    assert link.frames_out == before


def test_a_scurve_without_jerk_is_refused_before_sending(board):
    _, link, client = board
    said: list[str] = []
    MonitorShell(client, say=said.append).execute("move 10 100 100 0 scurve")
    assert "needs J_MAX_DPS3 > 0" in said[-1]
    assert link.frames_out == 0


def test_the_toolbar_shows_the_bus_voltage_of_the_last_heartbeat(board):
    # The board measures its bus and sends it in BoardHeartbeat (every 0.2 s): the status
    # line shows it beside the current (the firmware's reading, 24.007 V on the paper bench).
    _, _, client = board
    client.hello()
    client.set_telemetry(10)
    client.collect(0.5)
    assert client.last_heartbeat is not None
    assert client.last_heartbeat.bus_voltage_v == pytest.approx(24.0, abs=0.01)
    shell = MonitorShell(client, latest=lambda: client.telemetry[-1], say=lambda s: None)
    assert " A 24.0V" in shell.toolbar()
    msg = client.telemetry[-1]
    # every telemetry frame carries it too (appended): shown without a heartbeat
    assert msg.bus_voltage_v == pytest.approx(24.0, abs=0.01) == client.bus_voltage_v
    assert status_text(msg).endswith(" A 24.0V")
    old = dataclasses.replace(msg, bus_voltage_v=0.0)  # an older board's telemetry
    assert "V" not in status_text(old).split(" A")[-1]  # no heartbeat yet: no bus shown
    assert status_text(old, bus_voltage_v=27.93).endswith("A 27.9V")
