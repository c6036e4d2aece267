"""Speed of the simulation loop (not a test; the numbers go to docs/benchmarks.md, "Simulation").

Three measurements, all with the full firmware model (``firmware_model.firmware.Firmware``)
on ``bench_configs/paper_bench.toml``, driven by the paper's Fig. 8 script (3000 deg, then
interrupts to -8000, -6000 and -1000 deg at 2, 10 and 16 s; v_max 990 deg/s, a_max 148
deg/s^2), encoder noise on, telemetry every tick:

1. real-time factor of one 20 s run (``sim.loop.run``), N = 1;
2. batch throughput at N = 256 (controller ticks per second = N x ticks / wall time);
3. the same closed loop with the plant advanced by one ``solve_ivp`` call per tick (what a
   user would write by hand), at equal accuracy (rtol 1e-10; the motor angles of the two
   runs are compared and printed), against the exact-ZOH loop, in the same run.

Repeats give a median and a minimum (the machine is shared: the minimum is the closest to an
idle machine). Usage::

    python3 benchmarks/bench_sim.py [--repeat 3] [--batch 256] [--batch-s 2] [--ivp-s 1]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from sim.config import Experiment, ScriptedCommand, load_bench
from sim.loop import Simulation, run
from sim.plant import derivative

BENCH = Path(__file__).resolve().parents[1] / "bench_configs" / "paper_bench.toml"


def fig8_experiment(duration_s: float) -> Experiment:
    bench = load_bench(BENCH)
    moves = [(0.0, 3e6), (2.0, -8e6), (10.0, -6e6), (16.0, -1e6)]
    cmds = tuple(
        ScriptedCommand(
            t,
            "move",
            (("target_mdeg", target), ("v_max_dps", 990.0), ("a_max_dps2", 148.0)),
        )
        for t, target in moves
        if t < duration_s
    )
    return Experiment(bench=bench, duration_s=duration_s, commands=cmds)


def _one_input(u):
    """``(duty, enable)`` of member 0 as a float and a bool."""
    duty, enable = u
    return float(np.asarray(duty).reshape(-1)[0]), bool(np.asarray(enable).reshape(-1)[0])


class SolveIvpPlant:
    """A plant that calls ``solve_ivp`` once per step, with ``Plant``'s interface (N = 1)."""

    def __init__(self, params, h_s: float, rtol: float = 1e-10, atol: float = 1e-12) -> None:
        self.params = params
        self.h_s = h_s
        self.rtol, self.atol = rtol, atol

    def update(self, t_s, x, u):
        sol = solve_ivp(
            lambda t, y: derivative(t, y, _one_input(u), self.params),
            (t_s, t_s + self.h_s),
            np.asarray(x, dtype=float).reshape(5),
            method="DOP853",
            rtol=self.rtol,
            atol=self.atol,
        )
        return sol.y[:, -1].reshape(1, 5)


def time_run(exp: Experiment, batch: int | None, repeat: int) -> list[float]:
    walls = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = run(exp, batch=batch)
        walls.append(time.perf_counter() - t0)
        # What the PC decodes is part of the experiment: decode it into the columns the
        # figures are drawn from, as sim.reproduce does (lazy in RunResult).
        t1 = time.perf_counter()
        n_tel = len(res.telemetry_arrays()["tick"])
        walls[-1] += time.perf_counter() - t1
    assert n_tel > 0
    return walls


def cold_process(duration_s: float) -> dict[str, float]:
    """One run in a fresh interpreter, as the CLI does it: wall s of importing the
    simulator, of loading the compiled kernels (numba's start-up) and of the run (with the
    first use of every mode's matrices) plus the PC decode."""
    code = f"""
import json, sys, time
t0 = time.perf_counter()
sys.path.insert(0, {str(Path(__file__).resolve().parent)!r})
from bench_sim import fig8_experiment
from sim import plant_kernel
from sim.loop import run
t1 = time.perf_counter()
plant_kernel.warm_up()
t2 = time.perf_counter()
res = run(fig8_experiment({duration_s!r}))
res.telemetry_arrays()
t3 = time.perf_counter()
print(json.dumps({{"import_s": t1 - t0, "kernels_s": t2 - t1, "run_s": t3 - t2}}))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.splitlines()[-1])


def quietest_chunks(
    exp: Experiment, chunk: int = 100, batch: int | None = None
) -> tuple[float, float]:
    """Step the experiment in chunks of ``chunk`` ticks: (quietest, median) us/tick.
    On a shared machine the quietest chunk is the closest to the code's own cost."""
    from serial_protocol import frame

    sim = Simulation(exp.bench, seed=0, batch=batch)
    sim.reserve(round(exp.duration_s / exp.bench.dt_s))
    n = round(exp.duration_s / exp.bench.dt_s)
    at = {round(c.t_s / exp.bench.dt_s): c for c in exp.commands}
    per = []
    seq = 0
    for start in range(0, n, chunk):
        for k in range(start, start + chunk):
            if k in at:
                sim.pc_write(frame.encode(at[k].message(seq + 1), seq))
                seq += 1
        t0 = time.perf_counter()
        sim.step(chunk)
        per.append((time.perf_counter() - t0) / chunk * 1e6)
    return min(per), statistics.median(per)


def time_split(exp: Experiment, chunk: int, batch: int | None = None) -> dict[str, float]:
    """Where a tick's time goes: the firmware's calls (``servo_tick``, ``current_tick``,
    ``signals``), the plant's ``update``, and the rest of the loop (encoder, ADC, duty
    rounding, log rows, UART), in us per tick: medians over the quietest quarter of the
    ``chunk``-tick chunks. Each timed call carries ~0.1-0.3 us of timer overhead."""
    from serial_protocol import frame

    sim = Simulation(exp.bench, seed=0, batch=batch)
    n = round(exp.duration_s / exp.bench.dt_s)
    sim.reserve(n)
    spent = {"firmware": 0.0, "plant": 0.0}

    def timed(obj: object, name: str, part: str) -> None:
        call = getattr(obj, name)

        def wrapper(*args):
            t0 = time.perf_counter()
            out = call(*args)
            spent[part] += time.perf_counter() - t0
            return out

        setattr(obj, name, wrapper)

    for name in ("servo_tick", "current_tick", "signals"):
        timed(sim.fw, name, "firmware")
    timed(sim.plant, "update", "plant")
    at = {round(c.t_s / exp.bench.dt_s): c for c in exp.commands}
    rows = []
    seq = 0
    for start in range(0, n, chunk):
        for k in range(start, start + chunk):
            if k in at:
                sim.pc_write(frame.encode(at[k].message(seq + 1), seq))
                seq += 1
        before = dict(spent)
        t0 = time.perf_counter()
        sim.step(chunk)
        wall = time.perf_counter() - t0
        rows.append((wall, {part: spent[part] - before[part] for part in spent}))
    rows.sort(key=lambda r: r[0])
    quiet = rows[: max(1, len(rows) // 4)]
    out = {"tick": statistics.median(r[0] for r in quiet) / chunk * 1e6}
    for part in spent:
        out[part] = statistics.median(r[1][part] for r in quiet) / chunk * 1e6
    out["rest"] = out["tick"] - out["firmware"] - out["plant"]
    return out


def print_split(split: dict[str, float]) -> None:
    tick = split["tick"]
    parts = ", ".join(
        f"{part} {split[part]:.1f} us ({100 * split[part] / tick:.0f} %)"
        for part in ("firmware", "plant", "rest")
    )
    print(f"    where a tick goes (quietest quarter of chunks, timed): {tick:.1f} us = {parts}")


def loop_ivp_vs_zoh(exp: Experiment, seconds: float) -> dict[str, float]:
    """Same closed loop, ZOH plant vs solve_ivp plant, same seed: wall per tick and the
    largest motor-angle difference."""
    n = round(seconds / exp.bench.dt_s)
    out = {}
    logs = {}
    for name in ("zoh", "ivp"):
        sim = Simulation(exp.bench, seed=0)
        if name == "ivp":
            sim.plant = SolveIvpPlant(exp.bench.plant, sim.h_s)
        from serial_protocol import frame

        sim.pc_write(frame.encode(exp.commands[0].message(1), 0))
        chunks = []
        for _ in range(n // 50):
            t0 = time.perf_counter()
            sim.step(50)
            chunks.append((time.perf_counter() - t0) / 50 * 1e6)
        out[f"{name}_us_per_tick"] = sum(chunks) / len(chunks)
        out[f"{name}_quietest_us"] = min(chunks)
        out[f"{name}_median_us"] = statistics.median(chunks)
        logs[name] = sim.log()
    diff = np.max(np.abs(logs["zoh"].motor_pos_rad - logs["ivp"].motor_pos_rad))
    out["max_diff_rev"] = diff / (2 * math.pi)
    out["ratio"] = out["ivp_us_per_tick"] / out["zoh_us_per_tick"]
    out["ratio_quietest"] = out["ivp_quietest_us"] / out["zoh_quietest_us"]
    out["ratio_median"] = out["ivp_median_us"] / out["zoh_median_us"]
    return out


def plant_only(exp: Experiment, seconds: float) -> dict[str, float]:
    """Plant alone: replay a recorded duty sequence through Plant (N = 1) and solve_ivp."""
    n = round(seconds / exp.bench.dt_s)
    sim = Simulation(exp.bench, record_inputs=True)
    from serial_protocol import frame

    sim.pc_write(frame.encode(exp.commands[0].message(1), 0))
    sim.step(n)
    duty, enable = sim.inputs()
    from sim.plant import Plant

    zoh = Plant(exp.bench.plant, 1, sim.h_s)
    ivp = SolveIvpPlant(exp.bench.plant, sim.h_s)
    res = {}
    traj = {}
    for name, plant in (("zoh", zoh), ("ivp", ivp)):
        x = np.zeros((1, 5))
        pos = []
        t0 = time.perf_counter()
        for k in range(n):
            x = plant.update(k * sim.h_s, x, (duty[k : k + 1], enable[k : k + 1]))
            pos.append(x[0, 1])
        res[f"plant_{name}_us_per_step"] = (time.perf_counter() - t0) / n * 1e6
        traj[name] = np.array(pos)
    res["plant_ratio"] = res["plant_ivp_us_per_step"] / res["plant_zoh_us_per_step"]
    res["plant_diff_rev"] = float(np.max(np.abs(traj["zoh"] - traj["ivp"]))) / (2 * math.pi)
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--batch-s", type=float, default=2.0, help="simulated s of the batch run")
    ap.add_argument("--ivp-s", type=float, default=1.0, help="simulated s of the ivp loop")
    args = ap.parse_args()

    exp20 = fig8_experiment(20.0)
    walls = time_run(exp20, None, args.repeat)
    med, best = statistics.median(walls), min(walls)
    print(f"[1] 20 s run, N = 1, full firmware: wall median {med:.3f} s (min {best:.3f} s)")
    print(f"    real-time factor median {20 / med:.0f}x (best {20 / best:.0f}x), target 200x;")
    print(f"    {med / 10_000 * 1e6:.1f} us per tick median ({best / 10_000 * 1e6:.1f} best)")

    cold = [cold_process(20.0) for _ in range(3)]
    med = {k: statistics.median(c[k] for c in cold) for k in cold[0]}
    print(
        f"    in a fresh process (median of 3): import {med['import_s']:.2f} s, compiled kernels "
        f"{med['kernels_s']:.2f} s, first run + decode {med['run_s']:.3f} s "
        f"({20 / med['run_s']:.0f}x real time)"
    )

    q, m = quietest_chunks(exp20)
    print(
        f"    stepped in chunks of 100 ticks (no PC decode): quietest chunk {q:.1f} us/tick "
        f"({1e6 / q / 500:.0f}x real time), median chunk {m:.1f} us/tick"
    )

    print_split(time_split(exp20, 100))

    expb = fig8_experiment(args.batch_s)
    walls = time_run(expb, args.batch, args.repeat)
    ticks = args.batch * round(args.batch_s / expb.bench.dt_s)
    med, best = statistics.median(walls), min(walls)
    print(
        f"[2] batch N = {args.batch}, {args.batch_s:g} s: wall median {med:.3f} s (min {best:.3f})"
    )
    print(
        f"    {ticks / med:,.0f} controller ticks/s median ({ticks / best:,.0f} best), "
        "target 2,000,000"
    )

    q, m = quietest_chunks(expb, chunk=20, batch=args.batch)
    print(
        f"    stepped in chunks of 20 ticks: quietest chunk {args.batch / q * 1e6:,.0f} "
        f"ticks/s, median chunk {args.batch / m * 1e6:,.0f} ticks/s"
    )

    print_split(time_split(expb, 20, batch=args.batch))

    r = loop_ivp_vs_zoh(exp20, args.ivp_s)
    print(f"[3] closed loop, {args.ivp_s:g} s, same seed: ZOH {r['zoh_us_per_tick']:.1f} us/tick,")
    print(f"    solve_ivp per tick (DOP853, rtol 1e-10) {r['ivp_us_per_tick']:.1f} us/tick")
    print(
        f"    ratio {r['ratio']:.0f}x overall, {r['ratio_median']:.0f}x median 50-tick chunk, "
        f"{r['ratio_quietest']:.0f}x quietest chunks (target 50x); closed-loop motor-angle "
        f"difference {r['max_diff_rev']:.2e} rev"
    )
    p = plant_only(exp20, args.ivp_s)
    print(
        f"    plant alone (replayed duty): ZOH {p['plant_zoh_us_per_step']:.2f} us/step, "
        f"solve_ivp {p['plant_ivp_us_per_step']:.0f} us/step, ratio {p['plant_ratio']:.0f}x, "
        f"max motor-angle difference {p['plant_diff_rev']:.2e} rev"
    )
    print(
        "    (the closed loops drift apart once a tiny difference flips an encoder count;"
        " the replay compares the two integrators on identical inputs)"
    )


if __name__ == "__main__":
    main()
