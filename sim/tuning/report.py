"""What ``turntable-sim tune`` writes: the tuned TOML (a copy of the input with the five
gains replaced, comments kept) and the report (Markdown: cost terms before and after,
margins, the stages of the search, the robustness worst cases)."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from pathlib import Path

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
    """``source_text`` with the gains of ``gains`` written into their tables.

    A key already present keeps its line (value replaced, comment replaced by ``note``); a
    missing key is added under its table header; a missing table is appended.
    """
    lines = source_text.splitlines()
    for name, dotted in GAIN_FIELDS.items():
        table, _, key = dotted.rpartition(".")
        value = f"{getattr(gains, name):.6g}"
        header = re.compile(rf"^\s*\[\s*{re.escape(table)}\s*\]\s*(#.*)?$")
        start = next((k for k, line in enumerate(lines) if header.match(line)), None)
        if start is None:
            lines += ["", f"[{table}]", f"{key} = {value}  # {note}"]
            continue
        end = next(
            (k for k in range(start + 1, len(lines)) if re.match(r"^\s*\[", lines[k])),
            len(lines),
        )
        key_re = re.compile(rf"^(\s*{re.escape(key)}\s*=\s*)([^#]*?)(\s*#.*)?$")
        for k in range(start + 1, end):
            if key_re.match(lines[k]):
                m = key_re.match(lines[k])
                lines[k] = f"{m.group(1)}{value}  # {note}"
                break
        else:
            lines.insert(start + 1, f"{key} = {value}  # {note}")
    return "\n".join(lines) + "\n"


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
