"""Importing any module of the project never changes matplotlib's backend (issue #15 §5):
a notebook or a GUI program that imports ``sim.reproduce`` keeps the backend it chose."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("planner", "firmware_model", "serial_protocol", "sim", "bench_configs")

# In a fresh interpreter: choose a backend the project would never pick itself, import every
# module of every package one by one, and name each import after which the backend differs.
CHECK = """
import importlib, pkgutil, sys
import matplotlib
matplotlib.use("template")
import matplotlib.pyplot  # the backend a user's pyplot session has resolved
changed, failed, count = [], [], 0
for package in sys.argv[1:]:
    pkg = importlib.import_module(package)
    names = [package] + [m.name for m in pkgutil.walk_packages(pkg.__path__, package + ".")]
    for name in names:
        try:
            importlib.import_module(name)
        except Exception as exc:
            failed.append(f"{name}: {type(exc).__name__}: {exc}")
            continue
        count += 1
        if matplotlib.get_backend() != "template":
            changed.append(f"{name} -> {matplotlib.get_backend()}")
            matplotlib.use("template")
print(count)
print("CHANGED", changed)
print("FAILED", failed)
"""


def test_importing_any_module_keeps_the_backend():
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    env["PYTHONPATH"] = str(ROOT)
    done = subprocess.run(
        [sys.executable, "-c", CHECK, *PACKAGES],
        env=env,
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    count, changed, failed = done.stdout.strip().splitlines()[-3:]
    assert int(count) > 40  # every module was imported
    assert changed == "CHANGED []"
    assert failed == "FAILED []"


def test_the_check_sees_a_module_that_switches(tmp_path):
    """The check above can fail: a module calling ``matplotlib.use("Agg")`` is named."""
    pkg = tmp_path / "switcher"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "plots.py").write_text('import matplotlib\nmatplotlib.use("Agg")\n')
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    env["PYTHONPATH"] = str(tmp_path)
    done = subprocess.run(
        [sys.executable, "-c", CHECK, "switcher"], env=env, capture_output=True, text=True
    )
    assert "changed ['switcher.plots -> agg']" in done.stdout.lower(), done.stdout + done.stderr
