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


def test_the_largest_board_frame_quoted_for_the_tx_fifo_is_the_codec_s():
    """The `uart.fifo_bytes` row quotes the largest frame the board sends; it went stale
    (57 bytes) when fields were appended to `BoardHeartbeat`."""
    from serial_protocol import frame

    size, name = max(
        (frame.frame_bytes(cls), cls.__name__) for cls in frame._BY_CLASS if cls.MSG_TYPE >= 0x80
    )
    assert f"asked of the codec: {size} bytes, `{name}`" in DOC.read_text(encoding="utf-8")
