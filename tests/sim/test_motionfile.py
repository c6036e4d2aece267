"""Program files and point files (sim/motionfile.py) through the monitor, its shell and run
experiment files: bad files are one line with exit status 2, good ones reach the board."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from serial_protocol.exceptions import ConfigError
from serial_protocol.messages import Interp
from sim import cli
from sim.config import load_experiment
from sim.loop import run
from sim.motionfile import load_points, load_program

ROOT = Path(__file__).resolve().parents[2]
SCAN = ROOT / "bench_configs" / "inspection_scan.toml"
STREAM = ROOT / "bench_configs" / "seed002_stream.toml"


def test_the_bench_configs_files_load():
    prog = load_program(SCAN)
    assert len(prog.blocks) == 9 and prog.blocks[1] == (60.0, 20.0, 0.0)
    assert prog.blocks[-1] == (0.0, 300.0, 0.5)
    pts = load_points(STREAM)
    assert pts.interp is Interp.CUBIC and pts.period_s == 0.02
    assert len(pts.pos_deg) == len(pts.vel_dps) > 100


@pytest.mark.parametrize(
    ("text", "said"),
    [
        ("[[segment]]\nv_max_dps = 10.0\n", "[segment #1] target_deg = <missing>"),
        ("[[segment]]\ntarget_deg = 10.0\n", "[segment #1] v_max_dps = <missing>"),
        ("[[segment]]\ntarget_deg = 'x'\nv_max_dps = 1\n", "target_deg = 'x': must be a number"),
        ("v_max_dps = 5\n[[segment]]\ntarget_deg = 1e9\n", "target_deg = 1000000000.0: must"),
        ("v_max_dps = 5\n[[segment]]\ntarget_deg = 1\ndwell_s = -1\n", "dwell_s = -1"),
        ("v_max_dps = 5\n[[segment]]\ntarget_deg = 1\nspeed = 3\n", "speed = 3: unknown key"),
        ("title = 'x'\n", "segment = None: give the blocks as [[segment]] tables"),
        ("[[segment\n", "not valid TOML"),
    ],
)
def test_a_bad_program_file_is_one_line_naming_the_key(tmp_path, text, said):
    path = tmp_path / "prog.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match="prog.toml") as err:
        load_program(path)
    assert said in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("name", "text", "said"),
    [
        ("p.toml", "pos_deg = [1, 2]\n", "period_s = <missing>"),
        ("p.toml", "period_s = 0.1\npos_deg = []\n", "pos_deg = []: must be a non-empty"),
        ("p.toml", "period_s = 0.1\npos_deg = [1, 'a']\n", "pos_deg[1] = 'a'"),
        ("p.toml", "period_s = 0.1\npos_deg = [1]\nvel_dps = [1, 2]\n", "2 values for 1"),
        ("p.toml", "period_s = 0.1\ninterp = 'cubic'\npos_deg = [1]\n", "needs vel_dps"),
        ("p.toml", "period_s = 0.1\ninterp = 'spline'\npos_deg = [1]\n", "interp = 'spline'"),
        ("p.toml", "period_s = -1\npos_deg = [1]\n", "period_s = -1"),
        ("p.csv", "pos\n1\n", "line 1 = ['pos']: the header must be"),
        ("p.csv", "pos_deg,vel_dps\n1,2\n3\n", "line 3 = ['3']: 2 values expected"),
        ("p.csv", "pos_deg\nx\n", "line 2 = ['x']: not a number"),
    ],
)
def test_a_bad_point_file_is_one_line(tmp_path, name, text, said):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_points(path, 0.1 if name.endswith(".csv") else None)
    assert said in str(err.value) and "\n" not in str(err.value)


def test_a_csv_point_file_needs_a_period(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("pos_deg,vel_dps\n1,10\n2,10\n")
    with pytest.raises(ConfigError, match="period_s = <missing>"):
        load_points(path)
    pts = load_points(path, 0.1)
    assert (pts.pos_deg, pts.vel_dps, pts.interp) == ((1.0, 2.0), (10.0, 10.0), Interp.CUBIC)


def test_monitor_refuses_a_bad_program_file_before_connecting(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[[segment]]\ntarget_deg = 'x'\n")
    status = cli.main(["monitor", "socket://127.0.0.1:9", "--program", str(bad)])
    err = capsys.readouterr().err
    assert status == 2 and "bad.toml" in err and "target_deg = 'x'" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    status = cli.main(["monitor", "socket://127.0.0.1:9", "--stream-period", "0.1"])
    err = capsys.readouterr().err
    assert status == 2 and "--stream-period 0.1: only with --stream FILE" in err


def test_monitor_sends_a_program_and_a_stream_to_a_simulated_board(tmp_path, capsys):
    pts = tmp_path / "pts.csv"
    pts.write_text("pos_deg\n" + "".join(f"{0.05 * k:.4f}\n" for k in range(1, 41)))
    prog = tmp_path / "prog.toml"
    prog.write_text("v_max_dps = 50\n[[segment]]\ntarget_deg = 5\n[[segment]]\ntarget_deg = 0\n")
    argv = ["monitor", "sim://", "--program", str(prog), "--duration", "0.5", "--quiet",
            "--ack-timeout", "2"]  # fmt: skip
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert "program" in out and "2 block(s) queued" in out
    argv = ["monitor", "sim://", "--stream", str(pts), "--stream-period", "0.01",
            "--duration", "0.2", "--quiet", "--ack-timeout", "2"]  # fmt: skip
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert "stream ENDED: next point 41" in out


def test_the_shell_sends_a_program_and_refuses_a_missing_file(tmp_path, monkeypatch, capsys):
    prog = tmp_path / "prog.toml"
    prog.write_text("v_max_dps = 50\n[[segment]]\ntarget_deg = 5\ndwell_s = 0.1\n")
    monkeypatch.setattr("sys.stdin", io.StringIO(
        f"program {prog}\nprogram {tmp_path / 'none.toml'}\nqueue\njog 10 100 50\nstop\nquit\n"
    ))  # fmt: skip
    assert cli.main(["monitor", "sim://", "--interactive", "--ack-timeout", "2"]) == 0
    out = capsys.readouterr().out
    assert "1 block(s) queued" in out
    assert "none.toml: file not found" in out
    assert "jog: ok" in out, out


def test_a_run_file_with_a_program_and_a_stream(tmp_path):
    """Both reach the board through the emulated UART in order: the program's blocks, then
    the stream's frames paced ahead of the axis (a 2 ms stream longer than the buffer)."""
    n = 300
    t = np.arange(1, n + 1) * 0.002
    pos = 5.0 + 4.0 * (1.0 - np.cos(np.pi * t / 0.6)) / 2.0
    (tmp_path / "pts.toml").write_text(
        "period_s = 0.002\npos_deg = [" + ", ".join(f"{p:.4f}" for p in pos) + "]\n"
    )
    (tmp_path / "prog.toml").write_text(
        "v_max_dps = 60\n[[segment]]\ntarget_deg = 10\n[[segment]]\ntarget_deg = 5\n"
    )
    exp_file = tmp_path / "exp.toml"
    exp_file.write_text(
        f'bench = "{ROOT / "bench_configs" / "paper_bench.toml"}"\nduration_s = 3.0\n'
        '[[command]]\nt_s = 0.0\ntype = "program"\nfile = "prog.toml"\n'
        '[[command]]\nt_s = 1.0\ntype = "stream"\nfile = "pts.toml"\n'
    )
    exp = load_experiment(exp_file)
    kinds = [c.type for c in exp.commands]
    assert kinds[:2] == ["queue_segment", "queue_segment"]
    assert kinds[2] == "stream_control" and kinds[-1] == "stream_control"
    assert kinds.count("stream_points") == n // 5
    result = run(exp)
    nacks = [r for r in result.replies if type(r).__name__ == "Nack"]
    assert not nacks
    streams = [r for r in result.replies if type(r).__name__ == "StreamStatus"]
    assert len(streams) == 2 + n // 5 and streams[-1].underruns == 0
    assert result.firmware_counters["faults"] == 0
    sp = np.asarray(result.log.sp_pos_deg)
    assert abs(sp[-1] - pos[-1]) < 1e-3 and sp.max() <= 10.0 + 1e-6


def test_a_run_file_program_longer_than_the_queue_is_refused(tmp_path):
    (tmp_path / "prog.toml").write_text(
        "v_max_dps = 60\n" + "".join(f"[[segment]]\ntarget_deg = {k}\n" for k in range(40))
    )
    exp_file = tmp_path / "exp.toml"
    exp_file.write_text(
        f'bench = "{ROOT / "bench_configs" / "paper_bench.toml"}"\nduration_s = 3.0\n'
        '[[command]]\nt_s = 0.0\ntype = "program"\nfile = "prog.toml"\n'
    )
    with pytest.raises(ConfigError, match=r"40 blocks; a run file sends a program at once"):
        load_experiment(exp_file)
    status = cli.main(["run", str(exp_file), "--out", str(tmp_path / "out"), "--quiet"])
    assert status == 2
