"""``turntable-sim run``: CSV with the documented header, a PNG, config errors exit 2."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim import cli
from sim.config import load_experiment
from sim.csvlog import CSV_COLUMN, read_csv, write_csv
from sim.loop import LOG_FIELDS, run

BENCH = Path(__file__).resolve().parents[2] / "bench_configs" / "paper_bench.toml"
EXP = f"""bench = "{BENCH}"
duration_s = 0.4
[[command]]
t_s = 0.02
type = "move"
target_deg = 20.0
v_max_dps = 300.0
a_max_dps2 = 2000.0
"""


def test_run_writes_csv_and_png(tmp_path, capsys):
    cfg = tmp_path / "exp.toml"
    cfg.write_text(EXP)
    out = tmp_path / "out"
    assert cli.main(["run", str(cfg), "--out", str(out), "--quiet"]) == 0
    header = (out / "log.csv").read_text().splitlines()[0]
    assert header == ",".join(CSV_COLUMN.get(f, f) for f in LOG_FIELDS)
    # one meaning per name in every CSV: the true current says so, the measured one too
    assert "true_current_a" in header.split(",") and "current_a" not in header.split(",")
    png = (out / "plot.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    log = read_csv(out / "log.csv")
    assert len(log) == 200
    assert log.pos_deg[-1] > 15.0


def test_csv_round_trip_keeps_the_numbers(tmp_path):
    cfg = tmp_path / "exp.toml"
    cfg.write_text(EXP)
    log = run(load_experiment(cfg)).log
    back = read_csv(write_csv(log, tmp_path / "log.csv"))
    for f in LOG_FIELDS:
        np.testing.assert_allclose(getattr(back, f), getattr(log, f), rtol=1e-9, atol=1e-12)


def test_a_log_written_before_the_rename_still_reads(tmp_path):
    cfg = tmp_path / "exp.toml"
    cfg.write_text(EXP)
    log = run(load_experiment(cfg)).log
    path = write_csv(log, tmp_path / "log.csv")
    text = path.read_text()
    path.write_text(text.replace("true_current_a", "current_a", 1))
    np.testing.assert_allclose(read_csv(path).current_a, log.current_a, rtol=1e-9)


def test_config_error_exits_2_naming_the_key(tmp_path, capsys):
    cfg = tmp_path / "exp.toml"
    cfg.write_text(EXP.replace("v_max_dps = 300.0", "v_max_dps = -1"))
    # A negative v_max passes the loader (the firmware NACKs it on the wire); a bad type not:
    cfg.write_text(EXP.replace("v_max_dps = 300.0", 'v_max_dps = "x"'))
    assert cli.main(["run", str(cfg), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "exp.toml" in err and "v_max_dps = 'x'" in err


def test_the_run_figure_has_a_tracking_error_panel_and_returns_the_figure(tmp_path):
    from sim.plot import plot_run

    cfg = tmp_path / "exp.toml"
    cfg.write_text(EXP)
    log = run(load_experiment(cfg)).log
    fig = plot_run(log, tmp_path / "p.svg", title="t")
    assert (tmp_path / "p.svg").read_text().lstrip().startswith("<?xml")
    axes = fig.get_axes()
    labels = [ax.get_ylabel() for ax in axes]
    assert labels[1] == "tracking error\nsetpoint − position (°)"
    err = {ln.get_label(): ln for ln in axes[1].get_lines()}
    np.testing.assert_allclose(err["true"].get_ydata(), log.sp_pos_deg - log.true_pos_deg)
    assert "output shaft" in labels[0] and "°/s" in labels[0]
    assert plot_run(log) is not fig  # no path: nothing saved, a new figure


def test_the_tune_figure_says_the_run_was_time_scaled(tmp_path):
    from sim.tuning.plots import plot_before_after

    cfg = tmp_path / "exp.toml"
    cfg.write_text(EXP)
    log = run(load_experiment(cfg)).log
    plain = plot_before_after({"config": log}, None, "Fig. 8: replanned at 2, 10 and 16 s")
    assert plain.get_suptitle() == "Fig. 8: replanned at 2, 10 and 16 s"
    scaled = plot_before_after({"config": log}, None, "Fig. 8", time_scale=4.0)
    title = scaled.get_suptitle()
    assert "times and velocities / 4, positions / 16" in title
    assert scaled.get_axes()[-1].get_xlabel().startswith("time of the scaled run (s)")
