"""``turntable-sim tune``: the files it writes, the input untouched, unstable configs
refused with the file named."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from serial_protocol.exceptions import ConfigError
from sim.commands import tune as tune_cmd
from sim.config import load_bench
from sim.tuning.gains import GainSet

BENCH = Path(__file__).resolve().parents[3] / "bench_configs" / "paper_bench.toml"
MOVE = f"""
bench = "{BENCH.as_posix()}"
duration_s = 0.7

[[command]]
t_s = 0.0
type = "move"
target_deg = 30.0
v_max_dps = 300.0
a_max_dps2 = 3000.0
"""


@pytest.fixture
def short_move_path(tmp_path) -> Path:
    path = tmp_path / "short_move.toml"
    path.write_text(MOVE)
    return path


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    tune_cmd.add_arguments(parser)
    return parser.parse_args(list(argv))


def test_tune_writes_toml_plots_and_report(tmp_path, short_move_path, capsys):
    config = tmp_path / "bench.toml"
    config.write_text(BENCH.read_text())
    before = config.read_text()
    out = tmp_path / "out"
    argv = [str(config), "--scenario", str(short_move_path), "--out", str(out), "--seed", "2"]
    argv += ["--time-scale", "1", "--popsize", "2", "--maxiter", "0", "--quiet"]
    assert tune_cmd.main(_args(*argv)) == 0
    assert config.read_text() == before
    tuned = load_bench(out / "bench_tuned.toml")
    assert GainSet.from_bench(tuned) != GainSet.from_bench(load_bench(config))
    for name in ("before_after.png", "bode.png", "report.md"):
        assert (out / name).stat().st_size > 1000
    text = (out / "report.md").read_text()
    for heading in ("## Cost terms", "## Margins", "## Robustness", "| relay |", "| classic |"):
        assert heading in text
    assert capsys.readouterr().out == ""


def test_unstable_config_is_refused_with_its_file(tmp_path, short_move_path):
    config = tmp_path / "unstable.toml"
    config.write_text(BENCH.read_text().replace("kp_per_s = 13.3929", "kp_per_s = 400.0"))
    with pytest.raises(ConfigError, match=r"unstable.toml: gains refused \(.*position loop"):
        tune_cmd.main(
            _args(
                str(config),
                "--scenario",
                str(short_move_path),
                "--quiet",
                "--out",
                str(tmp_path / "o"),
            )
        )
    assert not (tmp_path / "o").exists()
