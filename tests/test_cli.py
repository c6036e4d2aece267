import subprocess
import sys

from sim import cli


def test_help_lists_every_registered_command(capsys):
    parser = cli.build_parser()
    help_text = parser.format_help()
    for name in cli.COMMANDS:
        assert name in help_text


def test_no_command_prints_help_and_fails():
    assert cli.main([]) == 2


def test_console_entry_point_runs():
    out = subprocess.run(
        [sys.executable, "-m", "sim.cli", "--help"], capture_output=True, text=True, check=True
    )
    assert "turntable-sim" in out.stdout
