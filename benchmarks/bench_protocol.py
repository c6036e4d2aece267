"""Protocol benchmark: encode and decode cost, decoder throughput, UART cost per tick, and
the share of framing in one simulated servo tick (one ``sim.step()`` per tick, and in the
compiled multi-tick run that ``sim.loop.run`` uses).

    python3 benchmarks/bench_protocol.py [--quick]

Prints a Markdown table (docs/benchmarks.md, section "Protocol"). Wall-clock timing, best of
several repeats (``timeit``); the numbers depend on the machine and its load.
"""

from __future__ import annotations

import argparse
import sys
import time
import timeit
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from serial_protocol.frame import (  # noqa: E402
    TELEMETRY_FRAME_BYTES,
    Decoder,
    encode,
    encode_telemetry_fields,
)
from serial_protocol.messages import Fault, State, Telemetry  # noqa: E402
from serial_protocol.uart import EmulatedUart, FaultInjection  # noqa: E402

TICK_S = 0.002


def best_us(stmt, number: int, repeat: int = 7) -> float:
    """Best time of one call in microseconds."""
    return min(timeit.repeat(stmt, number=number, repeat=repeat)) / number * 1e6


def telemetry(tick: int) -> Telemetry:
    return Telemetry(tick, tick * 0.0123, 990.0, tick * 0.0121, 989.5, 1.234, 0.5678, 2, 0)


def bench_codec(n: int) -> list[tuple[str, float, str]]:
    msg = telemetry(1234)
    rows = [
        ("Telemetry(...) construction", best_us(lambda: telemetry(1234), n), "us"),
        (
            f"encode(Telemetry) -> {TELEMETRY_FRAME_BYTES} bytes",
            best_us(lambda: encode(msg, 7), n),
            "us",
        ),
        (
            "encode_telemetry_fields(...)",
            best_us(
                lambda: encode_telemetry_fields(
                    7, 1234, 15.18, 990.0, 14.93, 989.5, 1.234, 0.5678, State.MOVING, Fault.NONE
                ),
                n,
            ),
            "us",
        ),
    ]
    frames = b"".join(encode(telemetry(k), k) for k in range(1000))

    def per_tick() -> None:
        decoder = Decoder()
        for k in range(0, len(frames), TELEMETRY_FRAME_BYTES):
            decoder.feed(frames[k : k + TELEMETRY_FRAME_BYTES])

    def bulk() -> None:
        Decoder().feed(frames)

    def bulk_columns() -> None:
        Decoder().feed_columns(frames)

    reps = max(1, n // 2000)
    kb = len(frames) // 1000
    per_tick_us = best_us(per_tick, reps) / 1000
    bulk_us = best_us(bulk, reps) / 1000
    columns_us = best_us(bulk_columns, reps) / 1000
    rows += [
        ("decode, one frame per feed()", per_tick_us, "us/frame"),
        ("decode throughput, one frame per feed()", 1e6 / per_tick_us, "frames/s"),
        (f"decode throughput, {kb} kB per feed()", 1e6 / bulk_us, "frames/s"),
        (f"decode throughput, {kb} kB per feed_columns()", 1e6 / columns_us, "frames/s"),
    ]
    faults = FaultInjection(bit_flip_rate=1e-3, drop_rate=1e-3, insert_rate=1e-3, burst_rate=1e-3)
    uart = EmulatedUart(460800, 1 << 22, faults, seed=1)
    uart.write(frames * 4)
    noisy = uart.advance(1e3)

    def noisy_bulk() -> None:
        Decoder().feed(noisy)

    noisy_us = best_us(noisy_bulk, reps) / 4000
    rows.append(("decode throughput, 0.4 % faulty bytes", 1e6 / noisy_us, "frames/s"))
    return rows


def bench_uart(n: int) -> list[tuple[str, float, str]]:
    frame = encode(telemetry(1), 0)
    out = []
    for label, faults in (
        ("clean", None),
        ("faults 1e-4/byte", FaultInjection(bit_flip_rate=1e-4)),
    ):
        uart = EmulatedUart(460800, 256, faults, seed=0)

        def tick(uart=uart) -> None:
            uart.write(frame)
            uart.advance(TICK_S)

        out.append((f"UART write({len(frame)} B) + advance(2 ms), {label}", best_us(tick, n),
                    "us/tick"))  # fmt: skip
    return out


def bench_simulation(ticks: int, repeats: int) -> tuple[float, float, float] | None:
    """Wall time of one simulated tick without and with the PC-side decode, and the
    telemetry frames per tick of that run."""
    try:
        from serial_protocol.messages import Hello, Move, SetEnable
        from sim.config import load_bench
        from sim.loop import Simulation
    except ImportError as exc:
        print(f"(simulation not available: {exc})", file=sys.stderr)
        return None
    bench = load_bench(Path(__file__).resolve().parents[1] / "bench_configs" / "paper_bench.toml")
    start = (
        encode(Hello(1, session=1), 0)
        + encode(SetEnable(2, True, session=1), 1)
        + encode(Move(3, 3000.0, 990.0, 148.0, session=1), 2)
    )

    def one_run(decode: bool) -> tuple[float, int]:
        sim = Simulation(bench, seed=0)
        sim.pc_write(start)
        decoder = Decoder()
        begin_wall_s = time.perf_counter()
        if decode:
            for _ in range(ticks):
                sim.step()
                decoder.feed(sim.pc_read())
        else:
            for _ in range(ticks):
                sim.step()
                sim.pc_read()
        return (time.perf_counter() - begin_wall_s) / ticks * 1e6, decoder.frames

    # alternate the two kinds so that a burst of machine load hits both alike
    bare, with_decode, frames = [], [], 0
    for _ in range(repeats):
        bare.append(one_run(False)[0])
        us, frames = one_run(True)
        with_decode.append(us)
    bare_us, with_us = min(bare), min(with_decode)
    return bare_us, with_us, frames / ticks


def bench_compiled_run(repeats: int, duration_s: float) -> dict[str, float] | None:
    """CPU time of the Fig. 8 run (N = 1, as ``sim.loop.run`` does it: many ticks per compiled
    call) with a telemetry frame every tick and with telemetry off (``telemetry.decimation =
    0``), paired: the difference is the board's framing and the UART in compiled code; the
    PC's decode (``telemetry_arrays``) is timed on its own. Medians, us per tick."""
    try:
        import dataclasses
        import resource
        import statistics

        from sim.config import load_experiment
        from sim.loop import run
    except ImportError as exc:
        print(f"(simulation not available: {exc})", file=sys.stderr)
        return None
    root = Path(__file__).resolve().parents[1]
    fig8 = load_experiment(root / "bench_configs" / "fig8.toml")
    exp = dataclasses.replace(fig8, duration_s=duration_s)
    off = {"telemetry.decimation": 0}

    def cpu_s() -> float:
        r = resource.getrusage(resource.RUSAGE_SELF)
        return r.ru_utime + r.ru_stime

    def timed(overrides: dict | None) -> tuple[float, float]:
        t0 = cpu_s()
        res = run(exp, overrides=overrides)
        t1 = cpu_s()
        res.telemetry_arrays()
        return t1 - t0, cpu_s() - t1

    short = dataclasses.replace(fig8, duration_s=0.1)
    run(short).telemetry_arrays()  # load the kernels
    run(short, overrides=off)
    on, off_runs = [], []
    for _ in range(repeats):
        on.append(timed(None))
        off_runs.append(timed(off)[0])
    us = 1e6 / round(duration_s * 500)
    return {
        "run_on": statistics.median(r for r, _ in on) * us,
        "run_off": statistics.median(off_runs) * us,
        "ratio": statistics.median(r / o for (r, _), o in zip(on, off_runs, strict=True)),
        "decode": statistics.median(d for _, d in on) * us,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats (a smoke run)")
    args = parser.parse_args()
    n = 2_000 if args.quick else 50_000
    rows = bench_codec(n) + bench_uart(n)
    sim = bench_simulation(500 if args.quick else 5_000, 2 if args.quick else 5)
    compiled = bench_compiled_run(2 if args.quick else 7, 2.0 if args.quick else 20.0)
    print("| measurement | value | unit |\n|---|---|---|")
    for label, value, unit in rows:
        print(f"| {label} | {value:,.2f} | {unit} |" if value < 1000 else
              f"| {label} | {value:,.0f} | {unit} |")  # fmt: skip
    if sim is not None:
        bare_us, with_us, frames_per_tick = sim
        build_us, encode_us, fields_us, decode_us = (rows[k][1] for k in range(4))
        board_us = (build_us + encode_us) * frames_per_tick
        print(f"| simulated tick: firmware + plant + UART (sim.step) | {bare_us:.2f} | us |")
        print(f"| simulated tick + PC-side decode of what arrived | {with_us:.2f} | us |")
        print(f"| telemetry frames per tick in that run | {frames_per_tick:.2f} | |")
        print(
            f"| board framing: Telemetry(...) + encode, per tick | {board_us:.2f} | us "
            f"({100 * board_us / bare_us:.1f} % of sim.step) |"
        )
        print(
            f"| board framing with encode_telemetry_fields | {fields_us * frames_per_tick:.2f} "
            f"| us ({100 * fields_us * frames_per_tick / bare_us:.1f} % of sim.step) |"
        )
        print(
            f"| PC decode, per tick | {with_us - bare_us:.2f} | us "
            f"({100 * (with_us - bare_us) / with_us:.1f} % of the tick with decode) |"
        )
        print(f"| real-time factor with decode | {2000 / with_us:.0f} | x |")
    if compiled is not None:
        c = compiled
        framing = c["run_on"] - c["run_off"]
        label = "Fig. 8 run (compiled, N = 1), a frame every tick, CPU"
        print(f"| {label} | {c['run_on']:.2f} | us/tick |")
        print(f"| the same run, telemetry off, CPU | {c['run_off']:.2f} | us/tick |")
        print(
            f"| board framing + UART in that run | {framing:.2f} | us/tick "
            f"({100 * framing / c['run_on']:.1f} % of the run; paired ratio {c['ratio']:.3f}) |"
        )
        print(
            f"| PC decode of that run (telemetry_arrays), CPU | {c['decode']:.2f} | us/tick "
            f"({100 * c['decode'] / (c['run_on'] + c['decode']):.1f} % of run + decode) |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
