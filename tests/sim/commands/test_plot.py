"""``turntable-sim plot FILE...``: every kind of recorded run, overlaid, by content (axes,
lines, labels), PNG/SVG/PDF by extension; and the timestamped capture format."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from serial_protocol.exceptions import CommandError
from serial_protocol.frame import encode
from serial_protocol.messages import Fault, State, Telemetry
from serial_protocol.telemetry_csv import TelemetryCsvWriter
from sim import cli
from sim.capture import MAGIC, TimestampedCapture, read_chunks
from sim.runfile import detect_kind, load_trace

BENCH = Path(__file__).resolve().parents[3] / "bench_configs" / "paper_bench.toml"
EXP = f"""bench = "{BENCH}"
duration_s = 0.5
[[command]]
t_s = 0.02
type = "move"
target_deg = 20.0
v_max_dps = 300.0
a_max_dps2 = 2000.0
"""


def frames(n: int = 50, tick0: int = 100):
    """Telemetry of a ramp: velocity 10 t, position 5 t^2, measured = planned + 0.5."""
    out = []
    for k in range(n):
        t = (tick0 + k) / 500.0
        out.append(
            Telemetry(tick0 + k, 5 * t * t, 10 * t, 5 * t * t, 10 * t + 0.5, 1.25, 0.1,
                      State.MOVING, Fault.NONE)
        )  # fmt: skip
    return out


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """One file of every kind the tool reads."""
    d = tmp_path_factory.mktemp("runs")
    tel = frames()
    raw = b"".join(encode(m, k & 0xFF) for k, m in enumerate(tel))
    (d / "raw.bin").write_bytes(b"\x00garbage" + raw)
    clock = iter(np.arange(0.0, 100.0, 0.01))
    with TimestampedCapture(open(d / "stamped.cap", "wb"), clock=lambda: next(clock)) as cap:
        for k in range(0, len(raw), 37):
            cap.write(raw[k : k + 37])
    with open(d / "monitor.csv", "w", newline="") as f:
        writer = TelemetryCsvWriter(f)
        for m in tel:
            writer.write(m)
    cfg = d / "exp.toml"
    cfg.write_text(EXP)
    assert cli.main(["run", str(cfg), "--out", str(d / "run"), "--quiet", "--no-plot"]) == 0
    can_log = d / "bus.asc"
    _write_can_log(can_log, tel)
    return d


def _write_can_log(path: Path, tel) -> None:
    import can

    from serial_protocol.can_link import can_frames

    with can.Logger(str(path)) as logger:
        for k, m in enumerate(tel):
            for arbitration_id, data in can_frames(m, counter=k):
                logger.on_message_received(
                    can.Message(
                        timestamp=k * 0.002, arbitration_id=arbitration_id, data=data,
                        is_extended_id=False,
                    )
                )  # fmt: skip


@pytest.mark.parametrize(
    ("name", "kind"),
    [
        ("raw.bin", "capture"),
        ("stamped.cap", "capture"),
        ("monitor.csv", "telemetry_csv"),
        ("run/log.csv", "log_csv"),
        ("bus.asc", "can"),
    ],
)
def test_every_kind_of_file_reads_to_the_same_columns(files, name, kind):
    path = files / name
    assert detect_kind(path) == kind
    trace = load_trace(path)
    if name == "run/log.csv":
        assert len(trace.t_s) == 250 and trace.pos_deg[-1] > 15.0
        assert len(trace.true_current_a) == 250  # the true current kept apart
        return
    expected = frames()
    assert len(trace.t_s) == len(expected)
    np.testing.assert_allclose(trace.t_s, [m.tick / 500.0 for m in expected])
    np.testing.assert_allclose(trace.vel_dps, [m.vel_dps for m in expected], atol=1e-4)
    np.testing.assert_allclose(trace.current_a, 1.25)  # the measured (IS pin) current
    assert set(trace.state) == {int(State.MOVING)}


def test_timestamped_capture_keeps_chunks_and_times():
    buf = io.BytesIO()
    times = iter([10.0, 10.5, 11.25])
    cap = TimestampedCapture(buf, clock=lambda: next(times))
    cap.write(b"abc")
    cap.write(b"")
    cap.write(b"defg")
    data = buf.getvalue()
    assert data.startswith(MAGIC)
    assert list(read_chunks(io.BytesIO(data))) == [(0.5, b"abc"), (1.25, b"defg")]
    # a plain capture is one chunk at time 0; a truncated chunk gives what is there
    assert list(read_chunks(io.BytesIO(b"xyz"))) == [(0.0, b"xyz")]
    assert list(read_chunks(io.BytesIO(data[:-2]))) == [(0.5, b"abc"), (1.25, b"de")]


def test_plot_overlays_files_and_returns_a_figure_by_content(files, tmp_path, capsys):
    out = tmp_path / "both.svg"
    argv = ["plot", str(files / "run" / "log.csv"), str(files / "monitor.csv"), "-o", str(out)]
    assert cli.main(argv + ["--current-limit", "5"]) == 0
    text = out.read_text()
    assert text.lstrip().startswith("<?xml") and "<svg" in text
    assert "wrote" in capsys.readouterr().out


def test_the_figure_has_the_paper_panels_and_one_curve_per_file(files):
    from sim.reproduce.plots import Curve, paper_figure

    traces = [load_trace(files / "run" / "log.csv"), load_trace(files / "monitor.csv")]
    fig = paper_figure(
        [Curve(t, t.name, c) for t, c in zip(traces, ("tab:blue", "tab:orange"), strict=True)],
        None,
        title="x",
        acceleration=True,
        pos_scale=1.0,
    )
    axes = fig.get_axes()
    labels = [ax.get_ylabel() for ax in axes]
    assert labels[:3] == [
        "output shaft velocity (°/s)",
        "measured − planned\nvelocity (°/s)",
        "planned\nacceleration (°/s$^2$)",
    ]
    assert "planned jerk (°/s$^3$)" in labels
    legend = [t.get_text() for t in axes[0].get_legend().get_texts()]
    assert legend == ["run/log.csv", "monitor.csv", "planned (board setpoint)"]
    # velocity panel: per file the measured (solid) and the planned (dashed) curve
    lines = axes[0].get_lines()
    assert [ln.get_linestyle() for ln in lines] == ["-", "--", "-", "--"]
    np.testing.assert_allclose(lines[3].get_ydata(), traces[1].sp_vel_dps)


@pytest.mark.parametrize("suffix", [".png", ".pdf"])
def test_format_by_extension_and_dpi(files, tmp_path, suffix):
    out = tmp_path / f"fig{suffix}"
    assert cli.main(["plot", str(files / "raw.bin"), "-o", str(out), "--dpi", "50"]) == 0
    head = out.read_bytes()[:8]
    assert head == (b"\x89PNG\r\n\x1a\n" if suffix == ".png" else b"%PDF-1.4"[:8])


def test_png_dpi_sets_the_size(files, tmp_path):
    from matplotlib.image import imread

    small, large = tmp_path / "a.png", tmp_path / "b.png"
    assert cli.main(["plot", str(files / "monitor.csv"), "-o", str(small), "--dpi", "40"]) == 0
    assert cli.main(["plot", str(files / "monitor.csv"), "-o", str(large), "--dpi", "80"]) == 0
    assert imread(large).shape[0] == 2 * imread(small).shape[0]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["README.md"], "no telemetry in it"),
        (["missing.csv"], "cannot read"),
        (["{raw}", "-o", "x.jpg"], "extension must be one of"),
        (["{raw}", "--dpi", "0"], "--dpi"),
        (["{raw}", "-o", "/no/such/dir/x.png"], "no folder"),
    ],
)
def test_bad_input_is_one_line_and_status_2(files, argv, message, capsys, monkeypatch):
    monkeypatch.chdir(Path(__file__).resolve().parents[3])
    argv = [a.replace("{raw}", str(files / "raw.bin")) for a in argv]
    assert cli.main(["plot", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_load_trace_names_the_file_when_empty(tmp_path):
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    with pytest.raises(CommandError, match="empty.bin"):
        load_trace(empty)
