"""sim.progress: terminal bar, plain-line fallback, ETA, quiet mode."""

from __future__ import annotations

import io

import pytest

from sim.progress import Progress, format_duration


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_format_duration():
    assert format_duration(3.25) == "3.2 s"
    assert format_duration(42.0) == "42 s"
    assert format_duration(185.0) == "3:05"
    assert format_duration(3723.0) == "1:02:03"
    assert format_duration(float("nan")) == "?"


def test_tty_bar_redraws_in_place_with_percent_and_eta():
    out = io.StringIO()
    clock = FakeClock()
    bar = Progress("fig8", 200, stream=out, tty=True, width=10, min_interval_s=0.0, clock=clock)
    clock.now += 2.0
    bar.update(50)
    text = out.getvalue()
    assert text.startswith("\rfig8 [##........]  25% ETA 6.0 s")
    assert "\n" not in text
    clock.now += 6.0
    bar.update(200)
    text = out.getvalue()
    assert text.endswith("done in 8.0 s\n")
    assert text.count("\n") == 1
    assert text.count("done in") == 1  # the final state is drawn once


def test_tty_bar_is_rate_limited():
    out = io.StringIO()
    clock = FakeClock()
    bar = Progress("x", 1000, stream=out, tty=True, min_interval_s=0.5, clock=clock)
    for k in range(1, 100):
        bar.update(k)  # the clock does not move: only the first update draws
    assert out.getvalue().count("\r") == 1
    clock.now += 1.0
    bar.update(100)
    assert out.getvalue().count("\r") == 2


def test_plain_lines_when_not_a_tty():
    out = io.StringIO()  # StringIO.isatty() is False
    clock = FakeClock()
    with Progress("fig7 S_1", 100, stream=out, clock=clock) as bar:
        for k in range(1, 101):
            clock.now += 0.25
            bar.update(k)
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue()
    # start, 25 %, 50 %, 75 %, done
    assert len(lines) == 5
    assert lines[0].startswith("fig7 S_1:   0% (0/100)")
    assert lines[1].startswith("fig7 S_1:  25% (25/100) ETA")
    assert lines[-1] == "fig7 S_1: 100% (100/100) done in 25 s"


def test_callback_matches_sim_loop_signature_and_total_may_change():
    out = io.StringIO()
    bar = Progress("run", 1, stream=out, tty=False, line_step=0.5)
    bar.callback(10, 40)
    assert bar.total == 40 and bar.done == 10
    bar.callback(40, 40)
    assert out.getvalue().splitlines()[-1].startswith("run: 100% (40/40) done")


def test_disabled_writes_nothing():
    out = io.StringIO()
    with Progress("q", 10, stream=out, enabled=False) as bar:
        bar.advance(10)
    assert out.getvalue() == ""


def test_bad_arguments():
    with pytest.raises(ValueError, match="total = 0"):
        Progress("x", 0)
    with pytest.raises(ValueError, match="line_step"):
        Progress("x", 5, line_step=0.0)
