"""recording.py (runs that keep the plant's inputs) is shared by the tests of this folder:
importable by name (pytest runs with --import-mode=importlib)."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
