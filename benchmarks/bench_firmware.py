"""Cost of the firmware model per servo tick (not a test; numbers go to docs/benchmarks.md).

Drives ``Firmware`` open loop with an encoder stream (0 -> 3000 axis degrees and back in
10 s from rest, up to 940 deg/s, 14-bit wrapped) and a constant ADC reading, telemetry every
tick and a Move interrupted twice, so that every part of the tick runs: unwrap and
observer, planner sample, the three loops, the trip checks, framing the telemetry. One call
sequence per tick: ``servo_tick`` + ``current_tick`` + ``signals`` (what ``sim/loop.py``
calls). The plant is not included (see the loop's own benchmark).

The machine is shared, so the ticks are timed in chunks of 50 and both the quietest chunk
(the cost) and the median chunk (what a loaded machine gives) are reported.

    python3 benchmarks/bench_firmware.py [--ticks 10000] [--batch 256]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from firmware_model.firmware import Firmware
from firmware_model.params import FirmwareParams, LimitsParams, ServoParams
from serial_protocol import frame
from serial_protocol.messages import Hello, Move

CHUNK_TICKS = 50


def _encoder_stream(n_ticks: int) -> list[int]:
    # 0..3000 axis degrees and back in 10 s, from rest: up to 940 deg/s, ~7000 counts/tick.
    t = np.arange(n_ticks) * 0.002
    axis_deg = 1500.0 * (1.0 - np.cos(2 * math.pi * t / 10.0))
    counts = np.floor(axis_deg * 80.0 / 360.0 * 16384).astype(np.int64) % 16384
    return [int(c) for c in counts]


def bench(arithmetic: str, batch: int | None, n_ticks: int) -> tuple[float, float]:
    """``(quietest, median)`` microseconds per servo tick over chunks of 50 ticks."""
    # The stream is not the plant's answer to the duty: the following-error trip is set out
    # of reach (every check still runs); the other trips stay at their defaults.
    params = FirmwareParams(
        servo=ServoParams(arithmetic=arithmetic),
        limits=LimitsParams(following_error_deg=1e6),
    )
    fw = Firmware(params, batch=batch)
    stream = _encoder_stream(n_ticks)
    targets = {5: 3000.0, n_ticks // 5: -8000.0, n_ticks // 2: -1000.0}
    script = {
        k: frame.encode(
            Move(cmd_id=i + 1, target_deg=t, v_max_dps=990.0, a_max_dps2=148.0, session=1), i + 1
        )
        for i, (k, t) in enumerate(targets.items())
    }
    script[5] = frame.encode(Hello(0, session=1), 0) + script[5]  # open the session first
    if batch is None:
        enc: list = stream
        adc: object = 300
    else:
        enc = [np.full(batch, c, dtype=np.int64) for c in stream]
        adc = np.full(batch, 300, dtype=np.int64)
    servo_tick, current_tick, signals = fw.servo_tick, fw.current_tick, fw.signals
    empty = b""
    per_tick_us = []
    clock = time.perf_counter
    for start in range(0, n_ticks - CHUNK_TICKS + 1, CHUNK_TICKS):
        t0 = clock()
        for k in range(start, start + CHUNK_TICKS):
            servo_tick(enc[k], script.get(k, empty), 4096)
            current_tick(adc)
            signals()
        per_tick_us.append((clock() - t0) / CHUNK_TICKS * 1e6)
    assert fw.counters["commands_applied"] == len(script)
    assert fw.counters["faults"] == 0
    return min(per_tick_us), statistics.median(per_tick_us)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=10_000, help="ticks per case (20 s)")
    parser.add_argument("--batch", type=int, default=256, help="N of the batch cases")
    args = parser.parse_args()
    n = args.ticks
    print(f"firmware model, {n} ticks per case ({n * 0.002:.0f} s simulated)")
    head = f"{'case':<24}{'us/tick':>9}{'(median)':>10}{'x real time':>13}{'member-ticks/s':>16}"
    print(head)
    for arithmetic in ("float", "fixed"):
        for batch in (None, args.batch):
            best, median = bench(arithmetic, batch, n if batch is None else n // 4)
            members = batch or 1
            name = f"{arithmetic}, " + ("N = 1 (scalar)" if batch is None else f"N = {batch}")
            print(
                f"{name:<24}{best:>9.2f}{median:>10.2f}{2000.0 / best:>13.0f}"
                f"{members / best * 1e6:>16,.0f}"
            )


if __name__ == "__main__":
    main()
