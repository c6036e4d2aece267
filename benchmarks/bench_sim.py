"""Speed of the simulation (not a test; the numbers go to docs/benchmarks.md, "Simulation").

Paired against reference trees (``--ref``, e.g. a checkout of the commit before issue 12,
and ``--ref NAME=PATH`` again for another, e.g. main before a change), each measurement
alternating between the trees in fresh interpreters, round after round, so that all see
the same machine load; the table gives the medians over the rounds and the median of the
per-round ratios of this tree to each reference, in wall time and again in CPU time (user + sys of
the process, which a loaded machine disturbs far less). All runs use the full firmware model on
``bench_configs/paper_bench.toml`` driven by the paper's Fig. 8 script (``fig8.toml``, cut
to the simulated time given), encoder noise on, telemetry framed every tick and decoded by
the simulated PC (``RunResult.telemetry_arrays``):

1. one 20 s run, N = 1 (real-time factor; median of 5 in a process, after one warm-up run);
2. batch N = 256, 2 s (member-ticks per second; median of 3), float and fixed-point law, and
   the float law with a parameter set per member (a Monte-Carlo study's batch: the motor's
   R from 1.0 to 1.6 ohm);
3. a fresh process: import, loading the compiled kernels, first run (this tree only);
4. whole commands as a user runs them: ``tune bench_configs/paper_bench.toml`` and
   ``reproduce`` (wall time of the process, median of ``--cmd-repeat``);
5. a one-hour simulated ``serve``-style run (``keep_log=False``, stepped in chunks, the PC
   reading every chunk): resident memory along the way;
6. the closed loop with the plant advanced by one ``solve_ivp`` call per tick, against the
   exact-ZOH plant (accuracy and cost of the model, tick by tick).

Usage::

    python3 benchmarks/bench_sim.py --ref /tmp/ref_tree [--rounds 3] [--skip-commands]
    python3 benchmarks/bench_sim.py --ref /tmp/ref_tree --ref main=/tmp/main_tree --paired-only
    python3 benchmarks/bench_sim.py --ref /tmp/ref_tree --paired-only   # 1 and 2 only
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

# "this tree" is the tree this script is in, for [5] and [6] too (run in this process): its
# modules before an installed copy of another checkout's.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim.config import Experiment, ScriptedCommand, load_bench  # noqa: E402
from sim.loop import Simulation  # noqa: E402
from sim.plant import derivative  # noqa: E402

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


def _open_and_move(sim: Simulation, exp: Experiment) -> None:
    """The scripted PC's first frames: a Hello opening session 1, then the first move."""
    from serial_protocol import frame
    from serial_protocol.messages import Hello

    sim.pc_write(frame.encode(Hello(1, session=1), 0))
    sim.pc_write(frame.encode(exp.commands[0].message(2, 1), 1))


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
        self.calls = 0

    def update(self, t_s, x, u):
        self.calls += 1
        sol = solve_ivp(
            lambda t, y: derivative(t, y, _one_input(u), self.params),
            (t_s, t_s + self.h_s),
            np.asarray(x, dtype=float).reshape(5),
            method="DOP853",
            rtol=self.rtol,
            atol=self.atol,
        )
        return sol.y[:, -1].reshape(1, 5)


def loop_ivp_vs_zoh(exp: Experiment, seconds: float) -> dict[str, float]:
    """Same closed loop, ZOH plant vs solve_ivp plant, same seed: wall per tick and the
    largest motor-angle difference."""
    n = round(seconds / exp.bench.dt_s)
    out = {}
    logs = {}
    # The tick-by-tick path's kernels loaded (compiled, the first time on a machine) before
    # the clock starts: else the first chunk of the ZOH loop times the compiler.
    warm = Simulation(exp.bench, seed=0, record_inputs=True)
    _open_and_move(warm, exp)
    warm.step(50)
    for name in ("zoh", "ivp"):
        # record_inputs: the tick-by-tick path, where the plant object can be swapped.
        sim = Simulation(exp.bench, seed=0, record_inputs=True)
        if name == "ivp":
            sim.plant = SolveIvpPlant(exp.bench.plant, sim.h_s)

        _open_and_move(sim, exp)
        chunks = []
        for _ in range(n // 50):
            t0 = time.perf_counter()
            sim.step(50)
            chunks.append((time.perf_counter() - t0) / 50 * 1e6)
        out[f"{name}_us_per_tick"] = sum(chunks) / len(chunks)
        out[f"{name}_quietest_us"] = min(chunks)
        out[f"{name}_median_us"] = statistics.median(chunks)
        logs[name] = sim.log()
        if name == "ivp":
            out["ivp_calls"] = sim.plant.calls
    # What the difference is of: the travel of each run (a run that never moved would
    # differ by 0.0) and the solve_ivp steps taken.
    out["travel_rev"] = min(np.ptp(log.motor_pos_rad) for log in logs.values()) / (2 * math.pi)
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

    _open_and_move(sim, exp)
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


_MEASURE = r"""
import dataclasses, json, resource, statistics, sys, time, warnings
warnings.simplefilter("ignore")
sys.path.insert(0, {tree!r})
from pathlib import Path
from sim.config import load_experiment
from sim.loop import run
fig8 = load_experiment(Path({tree!r}) / "bench_configs" / "fig8.toml")
CPU = {cpu!r}
def clock():
    if CPU:  # user + sys of this process: what the machine's load disturbs least
        r = resource.getrusage(resource.RUSAGE_SELF)
        return r.ru_utime + r.ru_stime
    return time.perf_counter()
def timed(exp, batch=None, overrides=None, repeat=3):
    walls = []
    for _ in range(repeat):
        t0 = clock()
        res = run(exp, batch=batch, overrides=overrides)
        res.telemetry_arrays()
        walls.append(clock() - t0)
        del res
    return statistics.median(walls)
one = dataclasses.replace(fig8, duration_s=20.0)
short = dataclasses.replace(fig8, duration_s={batch_s!r})
run(dataclasses.replace(fig8, duration_s=0.1))  # load the kernels
run(dataclasses.replace(fig8, duration_s=0.1), batch=2)
run(dataclasses.replace(fig8, duration_s=0.1), batch=2, overrides={{"servo.arithmetic": "fixed"}})
out = {{"n1_s": timed(one, repeat=5)}}
out["float_s"] = timed(short, batch={batch!r})
out["fixed_s"] = timed(short, batch={batch!r}, overrides={{"servo.arithmetic": "fixed"}})
spread = {{"motor.r_ohm": [1.0 + 0.6 * k / max(1, {batch!r} - 1) for k in range({batch!r})]}}
run(short, batch={batch!r}, overrides=spread)  # its modes' matrices, met once per process
out["spread_s"] = timed(short, batch={batch!r}, overrides=spread)
print(json.dumps(out))
"""

_FRESH = r"""
import json, sys, time, warnings
warnings.simplefilter("ignore")
t0 = time.perf_counter()
sys.path.insert(0, {tree!r})
from pathlib import Path
from sim.config import load_experiment
from sim.loop import run, warm_up
t1 = time.perf_counter()
exp = load_experiment(Path({tree!r}) / "bench_configs" / "fig8.toml")
warm_up(exp.bench)
t2 = time.perf_counter()
run(exp).telemetry_arrays()
t3 = time.perf_counter()
print(json.dumps({{"import_s": t1 - t0, "kernels_s": t2 - t1, "run_s": t3 - t2}}))
"""


def _user_env(**extra: str) -> dict[str, str]:
    """The environment of a user's process: this one's without ``PYTHONDONTWRITEBYTECODE``
    (a development shell may set it; a user's Python writes each module's bytecode on the
    first import and loads it afterwards, which is what a fresh process's import costs)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env.update(extra)
    return env


def _python(code: str, env: dict[str, str] | None = None) -> dict[str, float]:
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True,
        env=_user_env() if env is None else env,
    )  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def _load() -> str:
    return "load average " + " ".join(f"{v:.1f}" for v in os.getloadavg())


def paired(
    trees: dict[str, str], rounds: int, batch: int, batch_s: float, cpu: bool = False
) -> None:
    """Measurements 1 and 2, alternating between the trees round after round; ``cpu``:
    times are the process's user + sys CPU time instead of wall time."""
    results: dict[str, list[dict[str, float]]] = {name: [] for name in trees}
    for r in range(rounds):
        for name, tree in trees.items():
            code = _MEASURE.format(tree=tree, batch=batch, batch_s=batch_s, cpu=cpu)
            results[name].append(_python(code))
        print(f"    round {r + 1}/{rounds} done ({_load()})", flush=True)
    ticks = batch * round(batch_s / 0.002)

    def row(m: dict[str, float]) -> tuple[float, float, float, float, float]:
        return (
            20.0 / m["n1_s"],
            ticks / m["float_s"],
            ticks / m["fixed_s"],
            ticks / m["spread_s"],
            m["fixed_s"] / m["float_s"],
        )

    print(
        f"| tree | 20 s run N = 1 (x real time) | N = {batch} float (member-ticks/s) | "
        f"N = {batch} fixed (member-ticks/s) | N = {batch}, parameters per member "
        "(member-ticks/s) | fixed / float time |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for name in trees:
        rows = [row(m) for m in results[name]]
        med = [statistics.median(c) for c in zip(*rows, strict=True)]
        print(
            f"| {name} | {med[0]:,.0f} | {med[1]:,.0f} | {med[2]:,.0f} | {med[3]:,.0f} | "
            f"{med[4]:.2f} |"
        )
    b = list(trees)[-1]  # this tree, against each reference
    for a in list(trees)[:-1]:
        ratios = [
            [nb / na for na, nb in zip(row(x), row(y), strict=True)][:4]
            for x, y in zip(results[a], results[b], strict=True)
        ]
        med = [statistics.median(c) for c in zip(*ratios, strict=True)]
        print(
            f"| {b} / {a} (median of per-round ratios) | {med[0]:.2f}x | {med[1]:.2f}x | "
            f"{med[2]:.2f}x | {med[3]:.2f}x | |"
        )


def fresh_process(tree: str, repeat: int) -> None:
    with tempfile.TemporaryDirectory() as cache:
        # An empty numba cache: what the first run after an install does.
        cold = _python(_FRESH.format(tree=tree), env=_user_env(NUMBA_CACHE_DIR=cache))
    print(
        f"    first run after an install (empty numba cache): import {cold['import_s']:.2f} s, "
        f"compiling and caching the kernels {cold['kernels_s']:.1f} s, run + decode "
        f"{cold['run_s']:.3f} s ({_load()})"
    )
    runs = [_python(_FRESH.format(tree=tree)) for _ in range(repeat)]
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    print(
        f"    fresh process (median of {repeat}): import {med['import_s']:.2f} s, loading the "
        f"compiled kernels {med['kernels_s']:.2f} s, first 30 s Fig. 8 run + decode "
        f"{med['run_s']:.3f} s ({30 / med['run_s']:.0f}x real time) ({_load()})"
    )


def commands(trees: dict[str, str], repeat: int) -> None:
    """Whole commands, wall time of the process, alternating between the trees."""
    cmds = {
        "tune": ["tune", "bench_configs/paper_bench.toml"],
        "reproduce": ["reproduce"],
    }
    for label, argv in cmds.items():
        walls: dict[str, list[float]] = {name: [] for name in trees}
        for _ in range(repeat):
            for name, tree in trees.items():
                with tempfile.TemporaryDirectory() as tmp:
                    extra = ["--out", tmp]
                    env = _user_env(PYTHONPATH=tree, MPLBACKEND="Agg")
                    t0 = time.perf_counter()
                    subprocess.run(
                        [sys.executable, "-m", "sim.cli", *argv, *extra], cwd=tree, env=env,
                        check=True, capture_output=True,
                    )  # fmt: skip
                    walls[name].append(time.perf_counter() - t0)
        text = ", ".join(f"{n} {statistics.median(w):.1f} s" for n, w in walls.items())
        print(f"    {label} (whole command, median of {repeat}): {text} ({_load()})")


def serve_hour(hours: float, chunk: int) -> None:
    """A serve-style run (no per-tick log, the PC reading every chunk): RSS as it goes."""
    import resource

    from sim.config import load_bench
    from sim.loop import Simulation

    def rss_mb() -> float:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6

    sim = Simulation(load_bench(BENCH), keep_log=False)
    n = round(hours * 3600 / sim.dt_s)
    marks = []
    t0 = time.perf_counter()
    received = 0
    while sim.tick < n:
        sim.step(min(chunk, n - sim.tick))
        received += len(sim.pc_read())
        if sim.tick % (n // 6) < chunk:
            marks.append((sim.tick * sim.dt_s / 60, rss_mb()))
    wall = time.perf_counter() - t0
    text = ", ".join(f"{m:.0f} min {r:.1f} MB" for m, r in marks)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3
    print(
        f"    {hours:g} h simulated in {wall:.1f} s ({hours * 3600 / wall:.0f}x real time), "
        f"{received / 1e6:.1f} MB to the PC; RSS: {text}; peak {peak:.1f} MB ({_load()})"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--ref", action="append", default=[],
        help="a reference tree, PATH or NAME=PATH (e.g. a checkout of the previous commit); "
        "again for another",
    )  # fmt: skip
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--batch-s", type=float, default=2.0, help="simulated s of the batch run")
    ap.add_argument("--cmd-repeat", type=int, default=3)
    ap.add_argument("--skip-commands", action="store_true")
    ap.add_argument("--paired-only", action="store_true", help="measurements 1 and 2 only")
    ap.add_argument("--serve-hours", type=float, default=1.0)
    ap.add_argument("--ivp-s", type=float, default=1.0, help="simulated s of the ivp loop")
    args = ap.parse_args()
    here = str(Path(__file__).resolve().parents[1])
    trees = {}
    for k, ref in enumerate(args.ref):
        name, _, path = ref.rpartition("=")
        trees[name or ("reference" if k == 0 else f"reference {k + 1}")] = path
    trees["this tree"] = here
    print(f"[1, 2] paired runs, {args.rounds} rounds, wall clock ({_load()} at the start)")
    paired(trees, args.rounds, args.batch, args.batch_s)
    print(f"[1, 2] the same in CPU time (user + sys) ({_load()} at the start)")
    paired(trees, args.rounds, args.batch, args.batch_s, cpu=True)
    if args.paired_only:
        return
    print("[3]")
    fresh_process(here, 3)
    if not args.skip_commands:
        print("[4]")
        commands(trees, args.cmd_repeat)
    print("[5]")
    serve_hour(args.serve_hours, 5000)
    exp20 = fig8_experiment(20.0)
    r = loop_ivp_vs_zoh(exp20, args.ivp_s)
    print(f"[6] closed loop, {args.ivp_s:g} s, same seed: ZOH {r['zoh_us_per_tick']:.1f} us/tick,")
    print(f"    solve_ivp per tick (DOP853, rtol 1e-10) {r['ivp_us_per_tick']:.1f} us/tick")
    print(
        f"    ratio {r['ratio']:.0f}x overall, {r['ratio_median']:.0f}x median 50-tick chunk; "
        f"closed-loop motor-angle difference {r['max_diff_rev']:.2e} rev"
        f" (travel {r['travel_rev']:.1f} rev, {r['ivp_calls']} solve_ivp steps)"
    )
    p = plant_only(exp20, args.ivp_s)
    print(
        f"    plant alone (replayed duty): ZOH {p['plant_zoh_us_per_step']:.2f} us/step, "
        f"solve_ivp {p['plant_ivp_us_per_step']:.0f} us/step, ratio {p['plant_ratio']:.0f}x, "
        f"max motor-angle difference {p['plant_diff_rev']:.2e} rev"
    )


if __name__ == "__main__":
    main()
