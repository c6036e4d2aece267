"""The ``turntable-sim`` command line: --version, ports, completion, and every bad input of
issue #15 §4 as one line with exit status 2 (in-process through ``sim.cli.main``; a few
checks in a fresh process where the process itself is what is tested)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from sim import cli

ROOT = Path(__file__).resolve().parents[1]
FIG8 = ROOT / "bench_configs" / "fig8.toml"


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}


def _main(capsys, *argv: str) -> tuple[int, str, str]:
    status = cli.main(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


def test_help_lists_every_registered_command(capsys):
    parser = cli.build_parser()
    help_text = parser.format_help()
    for name in cli.COMMANDS:
        assert name in help_text


def test_no_command_prints_help_and_fails():
    assert cli.main([]) == 2


def test_console_entry_point_runs():
    out = subprocess.run(
        [sys.executable, "-m", "sim.cli", "--help"],
        capture_output=True,
        text=True,
        check=True,
        env=_env(),
    )
    assert "turntable-sim" in out.stdout


def test_version(capsys):
    from importlib import metadata

    from serial_protocol.messages import PROTOCOL_VERSION

    status, out, _ = _main(capsys, "--version")
    assert status == 0
    assert out.startswith(f"turntable-sim {metadata.version('turntable-sim')} ")
    assert f"protocol {PROTOCOL_VERSION}" in out
    fresh = subprocess.run(
        [sys.executable, "-m", "sim.cli", "--version"], capture_output=True, text=True, env=_env()
    )
    assert fresh.returncode == 0 and fresh.stdout == out


class _Port(SimpleNamespace):
    pass


def test_ports_lists_filters_and_says_when_none(capsys, monkeypatch):
    from serial.tools import list_ports

    ports = [
        _Port(
            device="/dev/ttyUSB0", description="CP2102 USB to UART", hwid="USB VID:PID=10C4:EA60"
        ),
        _Port(device="/dev/ttyACM0", description="STM32 Virtual COM", hwid="USB VID:PID=0483:5740"),
    ]
    monkeypatch.setattr(list_ports, "comports", lambda: ports)
    status, out, err = _main(capsys, "ports")
    assert status == 0
    assert out.splitlines() == [
        "/dev/ttyACM0  STM32 Virtual COM",
        "/dev/ttyUSB0  CP2102 USB to UART",
    ]
    assert "2 ports" in err
    status, out, _ = _main(capsys, "ports", "cp21", "-v")
    assert out.splitlines() == ["/dev/ttyUSB0  CP2102 USB to UART  [USB VID:PID=10C4:EA60]"]
    status, out, err = _main(capsys, "ports", "ftdi")
    assert status == 0 and out == "" and "no serial ports found matching 'ftdi'" in err
    monkeypatch.setattr(list_ports, "comports", lambda: [])
    status, out, err = _main(capsys, "ports")
    assert status == 0 and "no serial ports found" in err


def test_ports_runs_against_this_machine(capsys):
    status, out, err = _main(capsys, "ports", "-v")
    assert status == 0
    assert out or "no serial ports found" in err


def _complete(line: str, tmp_path: Path) -> list[str]:
    """Ask ``turntable-sim`` for completions the way bash's argcomplete hook does: a fresh
    process with the request in the environment, the answer on file descriptor 8."""
    pytest.importorskip("argcomplete")
    read_fd, write_fd = os.pipe()
    env = {
        **_env(),
        "_ARGCOMPLETE": "1",
        "_ARGCOMPLETE_IFS": "\v",
        "COMP_LINE": line,
        "COMP_POINT": str(len(line)),
        "COMP_TYPE": "9",
    }
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli"],
        env=env,
        cwd=tmp_path,
        pass_fds=(write_fd, 8),
        preexec_fn=lambda: os.dup2(write_fd, 8),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    os.close(write_fd)
    with os.fdopen(read_fd, "rb") as fh:
        answer = fh.read().decode()
    proc.wait(timeout=60)
    return answer.split("\v") if answer else []


def test_shell_completion_of_commands_options_and_files(tmp_path):
    (tmp_path / "my_bench.toml").write_text("")
    (tmp_path / "notes.txt").write_text("")
    assert set(_complete("turntable-sim ", tmp_path)) >= set(cli.COMMANDS)
    assert _complete("turntable-sim repr", tmp_path) == ["reproduce "]
    assert "--tick-hz" in _complete("turntable-sim decode --ti", tmp_path)[0]
    files = _complete("turntable-sim tune my", tmp_path)
    assert files == ["my_bench.toml "]
    assert _complete("turntable-sim tune not", tmp_path) == []  # only TOML files
    assert _complete("turntable-sim monitor lo", tmp_path) == ["loop://"]


# ------------------------------------------------------------- bad input: exit 2, one line

BAD_ARGUMENTS = [
    (["monitor", "loop://", "--move", "3e6"], "--move: '3e6': does not fit the wire"),
    (["monitor", "loop://", "--move", "1e9"], "Move.target_deg holds -214748.3649 .. 214748.3647"),
    (["monitor", "loop://", "--move", "nan"], "must be a finite number"),
    (["monitor", "loop://", "--telemetry", "-1"], "SetTelemetry.decimation holds 0 .. 65535"),
    (["monitor", "loop://", "--gains", "velocity", "1e40", "0", "0"], "kp = 1e+40: does not fit"),
    (
        ["monitor", "loop://", "--gains", "speed", "1", "0", "0"],
        "must be current, velocity or position",
    ),
    (["monitor", "loop://", "--limits", "1", "1", "inf", "1"], "must be a finite number"),
    (["monitor", "loop://", "--interrupt", "-2", "5"], "AFTER_S must be >= 0"),
    (["monitor", "loop://", "--baud", "0"], "--baud: '0': must be in 1 .. 100000000"),
    (["monitor", "loop://", "--duration", "-1"], "--duration: '-1': must be >= 0"),
    (["serve", "--tcp", "99999"], "--tcp: '99999': must be in 0 .. 65535"),
    (["serve", "--pty", "--speed", "0"], "--speed: '0': must be > 0"),
    (["serve", "--pty", "--set", "encoder.bits=12"], "written for the AS5048's 14 bits"),
    (["serve", "--pty", "--set", "nonsense"], "expected TABLE.KEY=VALUE"),
    (["decode", "--tick-hz", "0", "x.bin"], "--tick-hz: '0': must be > 0"),
    (["decode", "--can-base-id", "0x800", "x.asc"], "must be in 0 .. 2047"),
    (["run", "bench_configs", "--out", "o"], "bench_configs: is a folder, not a TOML file"),
    (["run", "missing.toml", "--out", "o"], "missing.toml: file not found"),
    (["run", "bench_configs/fig8.toml", "--out", "README.md"], "is a file, not a folder"),
    (["run", "bench_configs/fig8.toml", "--out", "README.md/x"], "cannot create the folder"),
    (["run", "bench_configs/fig8.toml", "--out", "/proc/no/x"], "cannot create the folder"),
    (["run", "bench_configs/fig8.toml", "--out", "o", "--seed", "-1"], "--seed: '-1'"),
    (["tune", "bench_configs/paper_bench.toml", "--out", "README.md"], "is a file, not a folder"),
    (["tune", "bench_configs/paper_bench.toml", "--time-scale", "0"], "must be >= 1"),
    (["tune", "bench_configs/paper_bench.toml", "--popsize", "1"], "must be in 2 .. 1000"),
    (["tune", "README.md"], "README.md: not valid TOML"),
    (["reproduce", "--out", "README.md"], "is a file, not a folder"),
    (["reproduce", "--out", "o", "--noise-copies", "1"], "--noise-copies: '1': must be in 2 .. 64"),
    (["reproduce", "--out", "o", "--noise-copies", "x"], "--noise-copies: 'x'"),
    (["reproduce", "--out", "o", "--retune", "pid"], "--retune: invalid choice: 'pid'"),
    (["reproduce", "--out", "o", "--sensitivity=yes"], "--sensitivity: ignored explicit argument"),
    (["ports", "("], "is not a regular expression"),
    (["nonsense"], "invalid choice: 'nonsense'"),
]


@pytest.mark.parametrize(("argv", "expected"), BAD_ARGUMENTS)
def test_bad_input_is_one_line_and_exit_status_2(argv, expected, capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    status, out, err = _main(capsys, *argv)
    assert status == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert expected in lines[0]
    assert lines[0].startswith("turntable-sim")
    assert "Traceback" not in out + err
    assert not (ROOT / "o").exists()  # nothing created on the way


def test_decode_of_a_file_that_is_not_a_capture_is_an_error(tmp_path, capsys):
    out_csv = tmp_path / "r.csv"
    status, _, err = _main(capsys, "decode", str(ROOT / "README.md"), "-o", str(out_csv))
    assert status == 2
    assert "no frame of the protocol found" in err and "nothing written" in err
    assert not out_csv.exists()
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    assert _main(capsys, "decode", str(empty))[0] == 2
    assert not Path(f"{empty}.csv").exists()


def test_an_unexpected_exception_is_one_line_with_status_70(capsys, monkeypatch):
    from sim.commands import ports

    def broken(args):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(ports, "main", broken)
    monkeypatch.delenv("TURNTABLE_SIM_TRACEBACK", raising=False)
    status, _, err = _main(capsys, "ports")
    assert status == cli.EXIT_INTERNAL
    assert err.count("\n") == 1 and "internal error: ZeroDivisionError: a bug" in err
    monkeypatch.setenv("TURNTABLE_SIM_TRACEBACK", "1")
    with pytest.raises(ZeroDivisionError):
        cli.main(["ports"])


# ------------------------------------------------------------------- Ctrl-C: what is kept


def _interrupt(*_a, **_k):
    raise KeyboardInterrupt


def test_ctrl_c_in_run_removes_the_empty_folder_it_made(tmp_path, capsys, monkeypatch):
    import sim.loop

    monkeypatch.setattr(sim.loop, "run", _interrupt)
    out = tmp_path / "new" / "run_out"
    status, _, err = _main(capsys, "run", str(FIG8), "--out", str(out))
    assert status == 130
    assert not (tmp_path / "new").exists()
    assert f"nothing was written; removed the empty folder {out}" in err
    assert err.strip().endswith("turntable-sim run: interrupted")


def test_ctrl_c_in_run_keeps_and_names_what_was_written(tmp_path, capsys, monkeypatch):
    import sim.plot

    monkeypatch.setattr(sim.plot, "plot_run", _interrupt)  # after log.csv
    out = tmp_path / "run_out"
    status, _, err = _main(capsys, "run", str(FIG8), "--out", str(out), "--quiet")
    assert status == 130
    assert (out / "log.csv").stat().st_size > 0
    assert f"kept in {out}: log.csv (written before the interrupt)" in err


def test_ctrl_c_in_an_existing_folder_leaves_it_and_its_files(tmp_path, capsys, monkeypatch):
    import sim.loop

    monkeypatch.setattr(sim.loop, "run", _interrupt)
    (tmp_path / "mine.txt").write_text("keep me")
    status, _, err = _main(capsys, "run", str(FIG8), "--out", str(tmp_path))
    assert status == 130
    assert (tmp_path / "mine.txt").read_text() == "keep me"
    assert f"nothing was written to {tmp_path}" in err


def test_ctrl_c_in_reproduce_and_tune(tmp_path, capsys, monkeypatch):
    import sim.reproduce
    import sim.tuning.optimise

    def half_reproduce(out_dir, **_):
        (Path(out_dir) / "telemetry").mkdir()
        (Path(out_dir) / "fig6.png").write_bytes(b"png")
        raise KeyboardInterrupt

    monkeypatch.setattr(sim.reproduce, "reproduce", half_reproduce)
    out = tmp_path / "rep"
    status, _, err = _main(capsys, "reproduce", "--out", str(out))
    assert status == 130
    assert f"kept in {out}: fig6.png" in err
    assert not (out / "telemetry").exists()  # the empty sub-folder it made is gone

    monkeypatch.setattr(sim.tuning.optimise, "tune", _interrupt)
    out = tmp_path / "tune_out"
    bench = ROOT / "bench_configs" / "paper_bench.toml"
    status, _, err = _main(capsys, "tune", str(bench), "--out", str(out), "--quiet", "--no-relay")
    assert status == 130
    assert not out.exists() and "removed the empty folder" in err


def test_ctrl_c_in_a_real_process(tmp_path):
    """SIGINT to a fresh ``turntable-sim run`` of a long experiment while it simulates (its
    progress display has started), as the terminal sends it: status 130, the folder it made
    is gone, one line says so."""
    import threading

    exp = tmp_path / "long.toml"
    exp.write_text('bench = "paper_bench.toml"\nduration_s = 2000.0\n')
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "run", str(exp), "--out", str(out)],
        env=_env(),
        stderr=subprocess.PIPE,
        text=True,
    )
    err: list[str] = []
    reader = threading.Thread(target=lambda: err.extend(iter(lambda: proc.stderr.read(1), "")))
    reader.start()
    deadline = time.monotonic() + 120
    # the progress display's first line ("long.toml: 0% ...") comes once the run starts
    while "long.toml: " not in "".join(err) and proc.poll() is None:
        assert time.monotonic() < deadline, "".join(err)
        time.sleep(0.05)
    time.sleep(0.5)
    assert proc.poll() is None, "".join(err)
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=120)
    reader.join(timeout=60)
    text = "".join(err)
    assert proc.returncode == 130, text
    assert "Traceback" not in text
    assert not out.exists(), text
    assert f"nothing was written; removed the empty folder {out}" in text
    assert text.rstrip().endswith("turntable-sim run: interrupted")
