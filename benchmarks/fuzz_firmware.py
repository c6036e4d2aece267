"""The long runs of the board's fuzzers (issue #11 §1-2; not a test: figures go to
docs/model.md, "Safety"). The test suite runs the same fuzzers with small budgets
(tests/firmware_model/test_safety.py).

* UART command fuzz: ``--frames`` random frames (valid and not: NaN, +-inf, denormals,
  float32 extremes, random bit patterns, every enum byte, every payload length, unknown and
  board-to-PC types, retries) through the emulated UART into the closed loop, in chunks of
  ``--chunk`` frames on a fresh board each (seed = chunk index; every fourth chunk a batch of
  2). Counts exceptions, answers missing or wrong, and NACKed commands that changed anything.
* Travel search: ``--sequences`` random motion sequences aimed at the travel ends; reports
  the worst excursion of the true axis beyond the travel.

    python3 benchmarks/fuzz_firmware.py [--frames 1000000] [--sequences 10000]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "firmware_model"))

from uart_fuzz import fuzz_commands, travel_search  # noqa: E402


def _fuzz(n_frames: int, chunk: int, first_chunk: int = 0) -> None:
    totals: dict[str, int] = {}
    problems: list[str] = []
    exceptions = 0
    wall0 = time.perf_counter()
    k = first_chunk
    sent = 0
    while sent < n_frames:
        n = min(chunk, n_frames - sent)
        batch = 2 if k % 4 == 3 else None
        try:
            report = fuzz_commands(n, seed=k, batch=batch)
        except Exception:  # counted and shown: this is what the fuzz looks for
            exceptions += 1
            problems.append(f"chunk {k}: {traceback.format_exc()}")
            sent += n
            k += 1
            continue
        for key in ("frames_sent", "answers_expected", "answers", "acks", "nacks",
                    "nacks_checked", "half_applied", "fault_reports", "ticks"):  # fmt: skip
            totals[key] = totals.get(key, 0) + getattr(report, key)
        for kind, count in report.kinds.items():
            totals["kind_" + kind] = totals.get("kind_" + kind, 0) + count
        problems += [f"chunk {k}: {p}" for p in report.problems]
        sent += n
        k += 1
        print(f"  {sent:>9,} frames  {time.perf_counter() - wall0:7.1f} s", flush=True)
    wall = time.perf_counter() - wall0
    print(f"UART command fuzz: chunks {first_chunk}..{k - 1}, {wall:.0f} s wall, "
          f"load {os.getloadavg()[0]:.1f}")  # fmt: skip
    for key, value in totals.items():
        print(f"  {key:20s} {value:>12,}")
    print(f"  {'exceptions':20s} {exceptions:>12,}")
    print(f"  {'problems':20s} {len(problems):>12,}")
    for p in problems[:10]:
        print("   ", p)


def _travel(n_sequences: int, seed: int = 12345) -> None:
    wall0 = time.perf_counter()
    report = travel_search(n_sequences, seed=seed)
    wall = time.perf_counter() - wall0
    print(f"Travel search: {report.sequences:,} sequences, {report.commands:,} commands, "
          f"{report.ticks:,} ticks, {wall:.0f} s wall, load {os.getloadavg()[0]:.1f}")  # fmt: skip
    print(f"  acks {report.acks:,}, nacks {report.nacks:,}, faults {report.faults}")
    print(f"  worst excursion of the true axis beyond the travel: "
          f"{report.worst_excess_deg:.4f} deg (sequence {report.worst_sequence})")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1_000_000)
    parser.add_argument("--chunk", type=int, default=50_000)
    parser.add_argument("--first-chunk", type=int, default=0,
                        help="index (and seed) of the first chunk: runs can be split")  # fmt: skip
    parser.add_argument("--sequences", type=int, default=10_000)
    parser.add_argument("--travel-seed", type=int, default=12345)
    args = parser.parse_args()
    if args.frames:
        _fuzz(args.frames, args.chunk, args.first_chunk)
    if args.sequences:
        _travel(args.sequences, args.travel_seed)


if __name__ == "__main__":
    main()
