"""The BoardHeartbeat framed inside the compiled tick (``firmware_model.tick.frame_heartbeat``)
is the heartbeat ``Firmware._transmit`` frames with ``serial_protocol.frame`` from
``Firmware.link_status``: the same bytes on the wire in every state a session goes through.

Each session runs twice: in the compiled tick (``sim.tick.run_ticks``) and tick by tick
through the firmware's Python API (``record_inputs=True``: ``Firmware.servo_tick`` ->
``_transmit`` frames every heartbeat with the codec). The PC byte streams, the logs and the
firmware counters must be identical, and the compiled run must have framed its heartbeats
itself (counted)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from firmware_model.firmware import Firmware
from serial_protocol import frame
from serial_protocol.messages import (
    BoardHeartbeat,
    ClearFault,
    GetStatus,
    Hello,
    Jog,
    Move,
    QueueAction,
    QueueControl,
    QueueSegment,
    SetEnable,
    SetLimits,
    Stop,
    StreamAction,
    StreamControl,
    StreamPoints,
    StreamState,
)
from sim.config import load_bench
from sim.loop import Simulation

BENCH = Path(__file__).resolve().parents[2] / "bench_configs" / "paper_bench.toml"
S = 7  # the session the scripted PC opens


def _session(compiled: bool, overrides: dict, script: list) -> tuple[bytes, dict, object]:
    sim = Simulation(load_bench(BENCH), seed=3, overrides=overrides, record_inputs=not compiled)
    assert sim._compiled is compiled
    seq = 0
    for ticks, what in script:
        if isinstance(what, bytes):
            sim.pc_write(what)
        elif what is not None:
            sim.pc_write(frame.encode(what, seq))
            seq = (seq + 1) & 0xFF
        sim.step(ticks)
    return sim.pc_read(), sim.fw.counters, sim.log()


def _script_motion() -> list:
    return [
        (40, Hello(1, session=S)),
        (60, SetEnable(2, True, session=S)),
        (300, Move(3, 30.0, 500.0, 1000.0, session=S)),
        (20, b"\xa5\x5a\x10not a frame\x00\x01\xa5"),  # the receiver's counters move
        (230, GetStatus(4, session=S)),
        # a program: its heartbeats are Python's while it runs, compiled again after
        (5, QueueSegment(5, 40.0, 200.0, 0.05, session=S)),
        (5, QueueSegment(6, 35.0, 200.0, 0.0, session=S)),
        (300, QueueSegment(7, 45.0, 200.0, 0.0, session=S)),
        (5, QueueSegment(8, 60.0, 100.0, 0.0, session=S)),
        (60, QueueControl(9, QueueAction.HOLD, session=S)),
        (200, QueueControl(10, QueueAction.RESUME, session=S)),
        (500, QueueControl(11, QueueAction.ABORT, session=S)),
        # a stream that runs dry (an underrun), then one that ends
        (5, StreamControl(12, StreamAction.START, period_s=0.01, prefill=3, session=S)),
        (400, StreamPoints(13, 1, 5, *[60.0 + 0.1 * k for k in range(1, 6)], session=S)),
        (400, Move(14, 70.0, 200.0, 1000.0, session=S)),
        (5, StreamControl(15, StreamAction.START, period_s=0.01, prefill=2, session=S)),
        (5, StreamPoints(16, 1, 4, *[70.0 - 0.1 * k for k in range(1, 5)], session=S)),
        (400, StreamControl(17, StreamAction.END, session=S)),
        # a jog that times out, then a trip latched (following error) and cleared
        (400, Jog(18, 40.0, 400.0, 300, session=S)),
        (10, SetLimits(19, 900.0, 2000.0, 5.0, 0.05, session=S)),
        (300, Move(20, 200.0, 900.0, 2000.0, session=S)),
        (210, ClearFault(21, session=S)),
        (100, Stop(22, session=S)),
        (150, None),
    ]


SESSIONS = {
    "motion": ({}, _script_motion()),
    # every tick a heartbeat on a slow link: it does not fit, it queues (Python's)
    "slow_link": (
        {"telemetry.heartbeat_s": 0.002, "telemetry.baud": 115200},
        _script_motion()[:6],
    ),
    # a noisy line both ways: CRC and header errors, silence discards, NACKs
    "noisy_line": (
        {"uart.bit_flip_rate": 3e-4, "telemetry.heartbeat_s": 0.05},
        _script_motion()[:10],
    ),
    # the bus model with its trips on: the bus voltage moves, a trip latches
    "bus": (
        {"supply.bus_model": True, "safety.bus_voltage_check": True},
        [(40, Hello(1, session=S)), (1500, Move(2, 400.0, 1000.0, 3000.0, session=S))],
    ),
}


@pytest.mark.parametrize("name", sorted(SESSIONS))
def test_the_compiled_heartbeat_is_the_codecs_heartbeat(name, monkeypatch):
    overrides, script = SESSIONS[name]
    python_bytes, python_counters, python_log = _session(False, overrides, script)
    # Count the heartbeats Python frames in the compiled run (link_status: a reply was
    # queued, the program queue or the stream was active, or it did not fit).
    built = []
    link_status = Firmware.link_status

    def counted(self: Firmware) -> BoardHeartbeat:
        built.append(self.tick)
        return link_status(self)

    monkeypatch.setattr(Firmware, "link_status", counted)
    compiled_bytes, compiled_counters, compiled_log = _session(True, overrides, script)
    assert compiled_bytes == python_bytes
    assert compiled_counters == python_counters
    for field, column in python_log.items():
        np.testing.assert_array_equal(getattr(compiled_log, field), column, err_msg=field)
    heartbeats = [m for m in frame.Decoder().feed(compiled_bytes) if isinstance(m, BoardHeartbeat)]
    assert len(heartbeats) >= 10
    if name != "slow_link":  # there the heartbeats queue behind each other: Python's
        assert len(built) < len(heartbeats) // 2  # most were framed in the compiled tick


def test_the_motion_session_goes_through_the_states_the_heartbeat_reports():
    """The session above is not a trivial one: its heartbeats report a session, receiver
    errors, the program queue filling, both stream states, a latched fault and its clear."""
    data, _, _ = _session(True, *SESSIONS["motion"])
    hbs = [m for m in frame.Decoder().feed(data) if isinstance(m, BoardHeartbeat)]
    assert {hb.session for hb in hbs} == {0, S} or {hb.session for hb in hbs} == {S}
    assert any(hb.rx_header_errors or hb.rx_bytes_dropped for hb in hbs)
    assert min(hb.queue_free for hb in hbs) < max(hb.queue_free for hb in hbs)
    assert {StreamState.UNDERRUN, StreamState.IDLE} <= {hb.stream_state for hb in hbs}
    assert any(hb.stream_underruns for hb in hbs)
    assert any(hb.fault_flags for hb in hbs) and hbs[-1].fault_flags == 0
    assert len({hb.bus_voltage_v for hb in hbs}) >= 1 and all(hb.bus_voltage_v > 0 for hb in hbs)
