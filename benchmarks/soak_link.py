"""The link soak of issue #10 §2: 1,000,000 frames through the full fault mix, and the
residual undetected-error rate of the frame check per kind of damage (CRC-32 of protocol
v2 against version 1's CRC-16 on the same damage). Figures go to docs/benchmarks.md.

    python3 benchmarks/soak_link.py                 # 1,000,000 frames, 1,000,000 per kind
    python3 benchmarks/soak_link.py --frames 20000 --residual 20000   # a smoke run

The machinery (fault mix, naive reference receiver, checks) is
``tests/serial_protocol/link_soak.py``, which the test suite runs on 20,000 frames.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "serial_protocol"))

from link_soak import FAULT_KINDS, crc_residual, run_soak  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1_000_000)
    parser.add_argument("--residual", type=int, default=1_000_000, help="frames per kind")
    parser.add_argument("--seed", type=int, default=2026)
    args = parser.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.1f} (2 cores, shared)")
    wall = time.perf_counter()
    r = run_soak(args.frames, seed=args.seed)
    wall = time.perf_counter() - wall
    print(f"soak: {r.frames} frames, {r.stream_bytes} bytes on the line, {wall:.1f} s")
    print(f"  damaged {r.damaged} ({r.damaged / r.frames:.1%}): {r.damaged_by_kind}")
    print(f"  between frames: {r.between_by_kind}")
    print(f"  (faults that left a frame unchanged, counted intact: {r.damaged_delivered_intact})")
    print(f"  delivered {r.delivered}; corrupted frames accepted: {r.accepted_corrupted}")
    print(f"  intact {r.intact}, recovered {r.recovered_intact} ({r.recovery:.6%})")
    before = {}
    for k in r.lost_intact:  # what happened to the frame before each lost intact one
        kind = r.kind_of[k - 1] if k else None
        before[kind] = before.get(kind, 0) + 1
    print(f"  the frame before each lost intact frame was damaged by: {before}")
    print(f"  decoder counters:   {r.counters}")
    same = r.counters == r.reference_counters
    print(f"  reference receiver: {'identical' if same else r.reference_counters}")
    for p in r.problems:
        print(f"  PROBLEM: {p}")
    if args.residual <= 0:
        return 1 if r.problems else 0
    print(f"residual undetected errors, {args.residual} frames damaged per kind:")
    print("  kind        CRC-32: damaged  corrupt  benign    CRC-16: damaged  corrupt  benign")
    for kind in FAULT_KINDS:
        t = time.perf_counter()
        c = crc_residual(args.residual, args.seed + 7, kind)
        dt = time.perf_counter() - t
        print(
            f"  {kind:<10} {c['damaged32']:>15} {c['corrupt32']:>8} {c['benign32']:>7}"
            f" {c['damaged16']:>16} {c['corrupt16']:>8} {c['benign16']:>7}   [{dt:.0f} s]"
        )
    print(f"load average at end: {os.getloadavg()[0]:.1f}")
    return 1 if r.problems else 0


if __name__ == "__main__":
    raise SystemExit(main())
