"""Streams and jogs sent by ``BoardClient`` through the emulated UART to the full simulated
bench (paper_bench.toml, compiled tick): seed 002's Tables 1 and 2 measured in the decoded
telemetry, a 2 ms stream longer than the point buffer (flow control), an underrun seen in
the board heartbeat, a jog stopped by its timeout."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from firmware_model.stream import STREAM_CAPACITY
from planner import sample_fixed_period, scurve_from_periods, trapezoid_from_periods
from serial_protocol.host import BoardClient
from serial_protocol.messages import Ack, State, StreamState, StreamStatus
from sim.config import load_bench
from sim.loop import Simulation
from sim.simlink import SimulatedLink

BENCH = Path(__file__).resolve().parents[2] / "bench_configs" / "paper_bench.toml"
H = 0.15
ROW_TICKS = 75


def client() -> tuple[Simulation, BoardClient]:
    sim = Simulation(load_bench(BENCH), seed=1)
    return sim, BoardClient(SimulatedLink(sim, ticks_per_poll=5), ack_timeout_s=30.0)


def _at_rest(c: BoardClient) -> None:
    st = c.wait_status(lambda s: s.state is State.HOLDING, timeout_s=120.0, interval_s=0.0)
    assert st is not None and st.state is State.HOLDING


def _telemetry(c: BoardClient) -> dict[int, tuple[float, float, float]]:
    return {t.tick: (t.sp_pos_deg, t.sp_vel_dps, t.pos_deg) for t in c.telemetry}


@pytest.mark.parametrize("table", [1, 2])
def test_seed002_tables_streamed_over_the_uart_measured_in_the_telemetry(table):
    """PVT points every 150 ms (the table's positions and velocities): the telemetry's
    setpoint every 75 ticks from the stream's start is the table, to the wire's 1e-4 deg;
    the encoder position follows within 0.1 deg (0.08 deg at the start of the acceleration
    here, the servo's lag, as with a ``Move``)."""
    if table == 1:
        prof = trapezoid_from_periods(120.0, 50.0, H, n_acc=4)
    else:
        prof = scurve_from_periods(120.0, 50.0, H, n_jerk=3, n_const=3)
    s = sample_fixed_period(prof, H)
    sim, c = client()
    assert isinstance(c.set_enable(True), Ack)
    last = c.stream(list(s.p[1:]), H, vel_dps=list(s.v[1:]), prefill=len(s.p) - 1)
    assert isinstance(last, StreamStatus) and last.state is StreamState.ENDED, last
    start = last.start_pos_deg
    _at_rest(c)
    t0_tick = round(sim.fw.stream.t0_s / sim.fw.dt_s)  # the tick the stream started
    tel = _telemetry(c)
    rows = [tel[t0_tick + ROW_TICKS * k] for k in range(len(s.p))]
    sp = np.array([r[0] for r in rows]) - start
    v = np.array([r[1] for r in rows])
    pos = np.array([r[2] for r in rows]) - start
    assert np.max(np.abs(sp - s.p)) <= 1.5e-4
    assert np.max(np.abs(v - s.v)) <= 1.5e-4
    assert np.max(np.abs(pos - s.p)) < 0.1
    st = c.stream_status()
    assert isinstance(st, StreamStatus) and (st.state, st.underruns) == (StreamState.IDLE, 0)


def test_a_2ms_stream_longer_than_the_buffer_with_flow_control():
    """600 LINEAR points every 2 ms (1.2 s of a 10 deg, 0.5 Hz-ish sweep), ten times the
    buffer: the client sends as the free slots allow, no underrun, the setpoint passes
    through every point."""
    n = 600
    t = np.arange(1, n + 1) * 0.002
    pos = 10.0 * (1.0 - np.cos(np.pi * t / 1.2)) / 2.0  # rest to rest, 10 deg
    sim, c = client()
    c.set_enable(True)
    last = c.stream(list(pos), 0.002, prefill=32)
    assert isinstance(last, StreamStatus) and last.state is StreamState.ENDED, last
    assert last.underruns == 0
    _at_rest(c)
    t0_tick = round(sim.fw.stream.t0_s / sim.fw.dt_s)
    tel = _telemetry(c)
    sp = np.array([tel[t0_tick + 1 + k][0] for k in range(n)]) - last.start_pos_deg
    assert np.max(np.abs(sp - pos)) <= 1.5e-4
    assert n > STREAM_CAPACITY
    assert c.last_heartbeat is not None and c.last_heartbeat.stream_underruns == 0


def test_an_underrun_shows_in_the_heartbeat_and_the_axis_stops():
    sim, c = client()
    c.set_enable(True)
    # 20 deg/s for 6 points and no END: the stream runs dry
    last = c.stream([0.2 * k for k in range(1, 7)], 0.01, prefill=6, end=False)
    assert isinstance(last, StreamStatus)
    _at_rest(c)
    c.collect(0.0)
    hb = c.wait_for(lambda m: type(m).__name__ == "BoardHeartbeat", timeout_s=60.0)
    assert hb is not None and (hb.stream_state, hb.stream_underruns) == (StreamState.UNDERRUN, 1)
    st = c.status()
    a_max = sim.fw.a_max_dps2
    assert st.target_deg == pytest.approx(1.2 + 20.0**2 / (2 * a_max), abs=2e-4)


def test_a_jog_over_the_uart_stops_when_the_client_falls_silent():
    sim, c = client()
    c.set_enable(True)
    assert isinstance(c.jog(90.0, 900.0, timeout_ms=200), Ack)
    # the client says nothing more: the simulated time runs on without frames from the PC
    sim.step(500)
    assert sim.fw.counters["jog_timeouts"] == 1
    assert sim.fw.sp_vel_dps == 0.0 and sim.fw.fault == 0
    st = c.status()
    assert st.state is State.HOLDING and 15.0 < st.pos_deg < 30.0


def test_the_client_keeps_its_jog_alive_while_it_listens(monkeypatch):
    """A jog with a timeout runs as long as the client waits or collects (its heartbeats
    feed the timeout), and stops once the client falls silent. The client's clock is the
    board's simulated time here, so no wall-clock speed enters the test."""
    import types

    import serial_protocol.host as host

    sim, c = client()
    clock = types.SimpleNamespace(monotonic=lambda: sim.tick * sim.dt_s, sleep=lambda s: None)
    monkeypatch.setattr(host, "time", clock)
    c.set_enable(True)
    assert isinstance(c.jog(40.0, 400.0, timeout_ms=100), Ack)
    c.collect(1.0)  # ten times the timeout
    assert sim.fw.counters["jog_timeouts"] == 0
    assert sim.fw.sp_vel_dps == pytest.approx(40.0)
    assert c.stats.heartbeats_sent >= 30  # one at least every 25 ms of the second
    sim.step(200)  # silent: the jog times out and brakes at its a_max
    assert sim.fw.counters["jog_timeouts"] == 1
    assert sim.fw.sp_vel_dps == 0.0 and sim.fw.fault == 0


def test_monitor_jogs_a_simulated_board_and_stops_it(tmp_path, capsys):
    """``monitor --jog``: the jog at its acceleration in the recorded telemetry, ended by
    ``--stop``; bad values are one line and status 2 before anything is sent."""
    import csv

    from sim import cli

    out = tmp_path / "jog.csv"
    argv = ["monitor", "sim://", "--jog", "-30", "--jog-accel", "1000", "--stop", "0.4",
            "--duration", "0.8", "--quiet", "--ack-timeout", "2", "--csv", str(out)]  # fmt: skip
    assert cli.main(argv) == 0
    said = capsys.readouterr().out
    assert "-> jog -30.0 1000.0 500: ok" in said and "-> stop: ok" in said
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    sp_v = np.array([float(r["sp_vel_dps"]) for r in rows])
    assert sp_v.min() == -30.0 and sp_v.max() <= 0.0  # reached, never beyond
    ticks = np.array([int(r["tick"]) for r in rows])  # a loaded host may miss a frame
    ramp = np.abs(np.diff(sp_v)) / np.diff(ticks)
    reached = int(np.argmax(sp_v == -30.0))
    assert np.max(ramp[:reached]) == pytest.approx(1000.0 * 0.002)  # the jog's a_max
    assert np.max(ramp) <= 2000.0 * 0.002 + 1e-4  # the Stop brakes at the board's a_max
    assert sp_v[-1] == 0.0 and rows[-1]["state"] == "HOLDING"
    for bad, message in [
        (["--jog", "nan"], "argument --jog: 'nan': must be a finite number"),
        (["--jog", "5", "--jog-timeout", "70000"], "'70000': does not fit the wire"),
        (["--jog-timeout", "100"], "--jog-timeout 100: only with --jog VEL_DPS"),
        (["--jog", "5", "--move", "10"], "--jog 5.0: not with --move, --program or --stream"),
    ]:
        assert cli.main(["monitor", "socket://127.0.0.1:9", *bad]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err


def test_a_program_a_stream_and_a_jog_through_a_real_serve_tcp():
    """The same through ``turntable-sim serve --tcp`` (a real socket, the server's own
    pacing, 4x real time): a program, seed 002's Table 1 streamed (all points held before
    it moves, so the machine's load cannot make it run dry), a jog stopped by Stop."""
    import signal
    import subprocess
    import sys

    from serial_protocol.messages import QueueStatus
    from serial_protocol.transport import SerialLink

    root = Path(__file__).resolve().parents[2]
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "serve", "--tcp", "0", "--speed", "4"],
        cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("socket://"), proc.stderr.read()
        with SerialLink.open(url) as link:
            c = BoardClient(link, ack_timeout_s=2.0, retries=5)
            assert isinstance(c.set_enable(True), Ack)
            last = c.send_program([(30.0, 200.0, 0.0), (60.0, 50.0, 0.0), (0.0, 200.0, 0.0)])
            assert isinstance(last, QueueStatus) and last.queued >= 1
            st = c.wait_status(lambda s: s.state is State.HOLDING, 60.0)
            assert st is not None and st.target_deg == 0.0 and abs(st.pos_deg) < 0.5
            s = sample_fixed_period(trapezoid_from_periods(120.0, 50.0, H, n_acc=4), H)
            c.telemetry.clear()
            last = c.stream(list(s.p[1:]), H, vel_dps=list(s.v[1:]), prefill=len(s.p) - 1)
            assert isinstance(last, StreamStatus) and last.state is StreamState.ENDED, last
            st = c.wait_status(lambda s: s.state is State.HOLDING, 60.0)
            assert st is not None and abs(st.target_deg - 120.0) < 1e-3
            assert abs(st.pos_deg - 120.0) < 0.5
            done = c.stream_status()
            assert (done.state, done.underruns) == (StreamState.IDLE, 0)
            # the rows the telemetry holds (a loaded machine may drop some frames)
            tel = {t.tick: t for t in c.telemetry}
            moving = sorted(k for k, t in tel.items() if t.state is State.MOVING)
            t0 = moving[0]  # the stream's t0: its first tick is MOVING, at point 0
            rows = [(k, tel.get(t0 + ROW_TICKS * k)) for k in range(len(s.p))]
            seen = [(k, t) for k, t in rows if t is not None]
            assert len(seen) >= len(rows) // 2
            for k, t in seen:
                assert abs(t.sp_pos_deg - s.p[k]) <= 1.5e-4
            assert isinstance(c.jog(-40.0, 400.0, timeout_ms=500), Ack)
            c.collect(0.2)
            assert isinstance(c.stop(), Ack)
            st = c.wait_status(lambda s: s.state is State.HOLDING, 60.0)
            assert st is not None and st.pos_deg < 120.0
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)
    assert proc.returncode == 0
