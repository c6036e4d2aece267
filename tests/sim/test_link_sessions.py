"""Issue #10's headline defect, end to end: one simulated board, one PC program after another
(each a fresh ``BoardClient``, as each ``turntable-sim monitor`` run is), every one of whose
first commands must be carried out. Also: a false header left by a killed tool, then the
documented silence, then a new program's first command answered at its first attempt."""

from __future__ import annotations

from pathlib import Path

import pytest

from serial_protocol import frame
from serial_protocol.host import BoardClient
from serial_protocol.messages import Ack, MsgType, State, Status
from sim.config import load_bench
from sim.loop import Simulation
from sim.simlink import SimulatedLink

BENCH = Path(__file__).resolve().parents[2] / "bench_configs" / "paper_bench.toml"


@pytest.fixture
def sim():
    return Simulation(load_bench(BENCH), seed=3)


def program(sim: Simulation) -> BoardClient:
    """A new PC program on the board's line (its own decoder, sequence and session)."""
    # A generous wall-clock timeout: time here is the simulation's, advanced by each poll.
    return BoardClient(SimulatedLink(sim, ticks_per_poll=5), ack_timeout_s=30.0)


def test_monitor_enable_then_disable(sim):
    first = program(sim)
    assert isinstance(first.set_enable(True), Ack)
    second = program(sim)
    assert isinstance(second.set_enable(False), Ack)
    assert first.last_command.cmd_id == second.last_command.cmd_id == 1
    assert second.status().state is State.DISABLED
    assert sim.fw.counters["duplicates"] == 0 and sim.fw.counters["sessions"] == 2


def test_monitor_move_30_then_move_minus_30(sim):
    start = float(sim.fw.signals()["pos_deg"])
    first = program(sim)
    # Both programs' first command is a Move with cmd_id 1 (what v1 took for a repeat).
    assert first.move(start + 30.0, 200.0, 1000.0) == Ack(1, MsgType.MOVE)
    first.wait_status(lambda s: s.state is State.HOLDING, 30.0, interval_s=0.0)
    second = program(sim)
    assert second.move(start - 30.0, 200.0, 1000.0) == Ack(1, MsgType.MOVE)
    status = second.wait_status(
        lambda s: s.state is State.HOLDING and abs(s.pos_deg - (start - 30.0)) < 0.5,
        30.0,
        interval_s=0.0,
    )
    assert isinstance(status, Status) and status.target_deg == pytest.approx(start - 30.0)
    # The first program's session is over: its next command is refused, not applied.
    late = first.stop()
    assert late.code.name == "STALE_SESSION"


def test_a_killed_tools_false_header_does_not_delay_the_next_program(sim):
    head = bytes((frame.MAX_PAYLOAD_BYTES, 0x03, 0))
    sim.pc_write(frame.SYNC + head + bytes((frame.crc8(head),)))  # then the tool dies
    sim.step(round(frame.RX_SILENCE_S / sim.dt_s))  # the documented silence
    client = program(sim)
    client.link.ticks_per_poll = 1
    sent_tick = sim.tick
    client.hello()
    # Answered at the first attempt, within the ticks the bytes take on the line (a 16-byte
    # Hello at 460800 baud is 0.35 ms) plus the board's tick: not held back.
    assert client.stats.retries == 0 and sim.tick - sent_tick <= 3
    assert sim.fw.decoder.partial_discards == 1
