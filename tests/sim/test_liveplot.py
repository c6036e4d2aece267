"""The live plot's data path (no timing asserted): every frame reaches the buffer, the window
is the latest one in order, the lines show it, the monitor draws and saves it."""

from __future__ import annotations

import argparse
import re

import numpy as np
import pytest

from serial_protocol.messages import Fault, State, Telemetry
from sim.commands import monitor
from sim.liveplot import MAX_POINTS, LiveBuffer, LivePlot, _reduce


def tel(tick: int, v: float = 0.0) -> Telemetry:
    return Telemetry(tick, tick * 0.1, v, tick * 0.1 + 0.01, v + 0.5, 0.25, 0.0,
                     State.MOVING, Fault.NONE)  # fmt: skip


def test_the_buffer_keeps_every_frame_in_order_across_the_ring():
    buf = LiveBuffer(capacity=100, tick_hz=500.0)
    for k in range(250):
        buf.append(tel(k, float(k)))
    assert buf.received == 250
    w = buf.window()
    np.testing.assert_array_equal(w["t_s"], np.arange(150, 250) / 500.0)
    np.testing.assert_array_equal(w["sp_vel_dps"], np.arange(150, 250))
    np.testing.assert_array_equal(w["vel_dps"], np.arange(150, 250) + 0.5)
    # the last 0.05 s only
    assert len(buf.window(0.05)["t_s"]) == 26


def test_the_tick_counter_wrapping_keeps_time_increasing():
    buf = LiveBuffer(capacity=10)
    for tick in (2**32 - 2, 2**32 - 1, 0, 1):
        buf.append(tel(tick))
    t = buf.window()["t_s"]
    np.testing.assert_allclose(np.diff(t), 1 / 500.0, rtol=1e-6)


def test_other_messages_are_ignored_by_the_callback():
    buf = LiveBuffer(capacity=10)
    buf("not telemetry")
    buf(tel(1))
    assert buf.received == 1


def test_reduce_keeps_the_peaks():
    t = np.arange(10_000.0)
    y = np.zeros_like(t)
    y[4321], y[8765] = 7.0, -3.0
    tt, yy = _reduce(t, y, 1000)
    assert len(tt) <= 1000 and yy.max() == 7.0 and yy.min() == -3.0


def test_the_lines_show_the_latest_window():
    buf = LiveBuffer(capacity=5000)
    for k in range(3000):
        buf.append(tel(k, 100.0 * np.sin(k / 300.0)))
    plot = LivePlot(buf, window_s=2.0)
    plot.draw()
    assert plot.frames == 1 and plot.full_redraws == 1
    w = buf.window(2.0)
    lines = {ln.get_label(): ln for ln in plot.axes[0].get_lines()}
    x, y = lines["measured"].get_data()
    assert len(w["t_s"]) == 1001 <= MAX_POINTS
    np.testing.assert_allclose(x, w["t_s"] - w["t_s"][-1])
    np.testing.assert_allclose(y, w["vel_dps"])
    lo, hi = plot.axes[0].get_ylim()
    assert lo <= w["vel_dps"].min() and hi >= w["vel_dps"].max()
    # more data inside the ranges: lines only, no full render
    for k in range(3000, 3010):
        buf.append(tel(k, 0.0))
    plot.draw()
    assert plot.frames == 2 and plot.full_redraws == 1
    assert [ax.get_ylabel() for ax in plot.axes] == [
        "output shaft\nvelocity (°/s)",
        "output shaft\nposition (°)",
        "motor current (A)",
        "bus voltage (V)\n(0: not sent)",
    ]


def test_monitor_plot_save_draws_every_frame_it_received(tmp_path, capsys):
    out = tmp_path / "live.png"
    parser = argparse.ArgumentParser()
    monitor.add_arguments(parser)
    args = parser.parse_args(
        ["sim://", "--enable", "--move", "20", "--duration", "0.5", "--quiet",
         "--ack-timeout", "2", "--plot-save", str(out)]
    )  # fmt: skip
    assert monitor.main(args) == 0
    text = capsys.readouterr().out
    received = int(re.search(r"received telemetry (\d+)", text).group(1))
    plotted = int(re.search(r"(\d+) telemetry frames plotted", text).group(1))
    assert received > 0 and plotted == received
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--plot"], "opens no window"),  # the tests run on Agg
        (["--plot-save", "x.jpg"], "must end in .png"),
        (["--plot-save", "a.png", "--plot-window", "0"], "--plot-window"),
        (["--plot-save", "a.png", "--plot-fps", "nan"], "--plot-fps"),
    ],
)
def test_bad_plot_options_are_command_errors(argv, message, tmp_path, monkeypatch):
    from serial_protocol.exceptions import CommandError

    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.chdir(tmp_path)
    parser = argparse.ArgumentParser()
    monitor.add_arguments(parser)
    with pytest.raises(CommandError, match=message):
        monitor.main(parser.parse_args(["sim://", *argv]))


def test_a_slow_frame_never_delays_a_timed_interrupt(monkeypatch):
    """monitor --plot --interrupt: a frame that renders the whole figure can take longer
    than the time left before an interrupt is due (0.3 s here, on a fake clock, so nothing
    depends on this machine's speed); the monitor starts no frame closer to a timed command
    than its slowest frame so far, so the interrupt goes out when due (before: up to a
    frame late; measured at load ~10, an interrupt due at 0.25 s went out after ~1 s)."""
    import time

    clock = [0.0]
    monkeypatch.setattr(time, "monotonic", lambda: clock[0])

    class Client:
        def collect(self, duration_s):
            clock[0] += max(duration_s, 0.001)
            return []

    class SlowLive:  # LiveWindow's interface to the monitor's loop
        frames = 0
        slowest_frame_s = 0.0

        def due_in_s(self):
            return 0.0

        def tick(self):
            self.frames += 1
            clock[0] += 0.3  # a full render on a loaded machine
            self.slowest_frame_s = 0.3

    sent = []
    args = argparse.Namespace(
        interrupt=[(0.5, -120.0)], stop=None, duration=1.0, v_max=600.0, a_max=1500.0,
        j_max=None, profile="trapezoid",
    )  # fmt: skip
    live = SlowLive()
    monkeypatch.setattr(monitor, "parse_command", lambda client, text: text)
    monitor._timed(Client(), args, lambda text, parsed: sent.append((clock[0], text)), live)
    assert len(sent) == 1 and sent[0][1].startswith("move -120")
    assert 0.5 <= sent[0][0] < 0.5 + 0.01  # when due, to the loop's resolution
    assert live.frames >= 2  # frames were drawn before and after it
