"""What ``turntable-sim tune`` writes: the tuned TOML (a copy of the input with the five
gains replaced, written with tomlkit so that comments and layout are kept) and the report
(Markdown: cost terms before and after, margins, the stages of the search, the robustness
worst cases)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sim.tuning.cost import TERMS
from sim.tuning.gains import GAIN_FIELDS, GainSet
from sim.tuning.linear import Margins

__all__ = [
    "gains_table",
    "margins_table",
    "terms_table",
    "tuned_toml_text",
    "write_tuned_toml",
]


def tuned_toml_text(source_text: str, gains: GainSet, note: str) -> str:
    """``source_text`` with the gains of ``gains`` written into their tables (tomlkit: every
    other line, comment and blank of the input is kept as it was).

    A key already present keeps its place and its comment's column; its comment becomes
    ``note``. A missing key is added at the end of its table, a missing table at the end.
    Values are written with 6 significant digits.
    """
    import tomlkit

    try:
        doc = tomlkit.parse(source_text)
    except tomlkit.exceptions.ParseError as exc:
        raise ValueError(f"the config is not valid TOML: {exc}") from None
    for name, dotted in GAIN_FIELDS.items():
        table_path, _, key = dotted.rpartition(".")
        table: Any = doc
        for part in table_path.split("."):
            if part not in table:
                table[part] = tomlkit.table(is_super_table=part != table_path.split(".")[-1])
            table = table[part]
        new = tomlkit.item(float(f"{getattr(gains, name):.6g}"))
        new.comment(note)
        if key in table:
            old = table.item(key)
            # keep the comment where it was (the config aligns its comments in a column)
            width = len(old.as_string()) + len(old.trivia.comment_ws)
            new.trivia.comment_ws = " " * max(2, width - len(new.as_string()))
        else:
            new.trivia.comment_ws = "  "
        table[key] = new
    return tomlkit.dumps(doc)


def write_tuned_toml(source: Path, out: Path, gains: GainSet, note: str) -> Path:
    """Write the tuned copy of ``source`` to ``out`` (refuses to overwrite ``source``)."""
    if out.resolve() == source.resolve():
        raise ValueError(f"{out}: would overwrite the input config")
    out.write_text(tuned_toml_text(source.read_text(), gains, note))
    return out


def _fmt(x: float) -> str:
    if isinstance(x, float) and (math.isinf(x) or math.isnan(x)):
        return "inf" if x == math.inf else "-"
    return f"{x:.4g}"


def terms_table(rows: Mapping[str, Mapping[str, float]], costs: Mapping[str, float]) -> str:
    """Markdown table: one row per gain set, one column per cost term, then the cost."""
    head = "| gains | " + " | ".join(TERMS) + " | cost |"
    sep = "|---" * (len(TERMS) + 2) + "|"
    body = [
        f"| {name} | " + " | ".join(_fmt(terms[t]) for t in TERMS) + f" | {_fmt(costs[name])} |"
        for name, terms in rows.items()
    ]
    return "\n".join([head, sep, *body])


def margins_table(margins: Mapping[str, Mapping[str, Margins]]) -> str:
    """Markdown table of margins: rows ``(gain set, loop)``."""
    head = (
        "| gains | loop | spectral radius | gain margin | GM (dB) | phase margin (deg) "
        "| crossover (Hz) | bandwidth (Hz) |"
    )
    rows = [head, "|---" * 8 + "|"]
    for name, per_loop in margins.items():
        for loop, m in per_loop.items():
            rows.append(
                f"| {name} | {loop} | {m.spectral_radius:.4f} | {_fmt(m.gain_margin)} | "
                f"{_fmt(m.gain_margin_db)} | {_fmt(m.phase_margin_deg)} | "
                f"{_fmt(m.crossover_hz)} | {_fmt(m.bandwidth_hz)} |"
            )
    return "\n".join(rows)


def gains_table(sets: Mapping[str, GainSet]) -> str:
    names = list(GAIN_FIELDS)
    rows = ["| gains | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for label, g in sets.items():
        rows.append(f"| {label} | " + " | ".join(f"{getattr(g, n):.5g}" for n in names) + " |")
    return "\n".join(rows)
