"""docs/config.md states every key of every bench table (the config reference of #11 §5)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from sim.config import TABLES

DOC = Path(__file__).resolve().parents[1] / "docs" / "config.md"


def test_every_key_of_every_table_is_in_the_config_reference():
    rows = DOC.read_text(encoding="utf-8").splitlines()
    missing = []
    for table, cls in TABLES.items():
        # a row starts with `table.key`, or `table.key1`, `key2`, ... for keys sharing a range
        mine = [r for r in rows if r.startswith(f"| `{table}.")]
        for f in dataclasses.fields(cls):
            if not any(f"`{table}.{f.name}`" in r or f"`{f.name}`" in r for r in mine):
                missing.append(f"{table}.{f.name}")
    assert not missing, f"add these keys and their ranges to docs/config.md: {missing}"
