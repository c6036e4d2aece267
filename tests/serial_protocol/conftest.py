"""The link soak (link_soak.py) is shared with benchmarks/soak_link.py: importable by name
from the tests of this folder (pytest runs with --import-mode=importlib)."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
