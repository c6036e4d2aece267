"""``turntable-sim tune CONFIG [--scenario NAME ...] [--out DIR] [--seed N]``: tune the
current, velocity and position loops of a bench config on simulated closed-loop runs, write
a tuned copy of the config, before/after and Bode plots, and a report (docs/tuning.md)."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from sim.commands._common import integer, number, output_dir

HELP = "tune the current, velocity and position loop gains offline (writes a tuned TOML)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", type=Path, help="bench TOML whose gains are tuned (not changed)")
    parser.add_argument(
        "--scenario",
        action="append",
        default=None,
        help="experiment (built-in name or TOML file) the cost is measured on; repeatable "
        "(default: fig8)",
    )
    parser.add_argument("--out", type=Path, default=Path("tune_out"), help="output directory")
    parser.add_argument(
        "--seed", type=integer(0, 2**32 - 1), default=0, help="optimiser and noise seed"
    )
    parser.add_argument(
        "--joint", action="store_true", help="tune all five gains at once (default: staged)"
    )
    parser.add_argument(
        "--time-scale",
        type=number(lo=1.0, hi=100.0),
        default=4.0,
        help="run the scenarios with times / K, velocities / K, accelerations kept "
        "(default 4; 1 = as written; 1 to 100)",
    )
    parser.add_argument(
        "--popsize", type=integer(2, 1000), default=10, help="population per gain (scipy, >= 2)"
    )
    parser.add_argument(
        "--maxiter", type=integer(0, 1000), default=4, help="generations per stage (>= 0)"
    )
    parser.add_argument(
        "--bound-factor",
        type=number(lo=1.0, lo_open=True, hi=1e6),
        default=4.0,
        help="search each gain within [config / F, config * F] (default 4)",
    )
    parser.add_argument(
        "--weight", action="append", default=[], metavar="NAME=VALUE", help="cost weight"
    )
    parser.add_argument("--no-robust", action="store_true", help="skip the plant-spread check")
    parser.add_argument("--no-relay", action="store_true", help="skip the relay auto-tune")
    parser.add_argument("--quiet", action="store_true", help="no progress or summary")


def main(args: argparse.Namespace) -> int:
    # The folder is checked first (a bad --out fails in a moment, not after the tuning) and
    # removed again if the command stops before writing anything.
    with output_dir(args.out, ("*_tuned.toml", "*.png", "report.md")):
        return _tune(args)


def _tune(args: argparse.Namespace) -> int:
    from firmware_model.units import AXIS_DEG_PER_COUNT
    from serial_protocol.exceptions import CommandError
    from sim.config import load_bench
    from sim.progress import Progress
    from sim.tuning import baselines, linear, plots, report
    from sim.tuning.cost import CostWeights
    from sim.tuning.evaluate import BOOT_OFFSET_COUNTS, evaluate
    from sim.tuning.gains import GainSet
    from sim.tuning.optimise import TuneSettings, generations, tune
    from sim.tuning.scenarios import DEFAULT_SCENARIO, scenario

    wall0 = time.perf_counter()
    bench = load_bench(args.config)
    try:
        weights = CostWeights().with_updates(args.weight)
        settings = TuneSettings(
            seed=args.seed,
            mode="joint" if args.joint else "staged",
            popsize=args.popsize,
            maxiter=args.maxiter,
            bound_factor=args.bound_factor,
            weights=weights,
        )
        start = GainSet.from_bench(bench)
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    linear.check_gains(bench, start, str(args.config))
    names = args.scenario or [DEFAULT_SCENARIO]
    scenarios = [scenario(n, bench, time_scale=args.time_scale, tail_s=1.0) for n in names]
    log = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr))

    sets: dict[str, GainSet] = {"config": start}
    sets["classic"] = baselines.classic(bench, start)
    if not args.no_relay:
        from sim.tuning.relay import relay_tune

        try:
            relay = relay_tune(bench, start, seed=args.seed)
        except ValueError as exc:  # no sustained oscillation on this bench
            log(f"relay: skipped ({exc})")
        else:
            log(
                f"relay: Ku = {relay.ku_a_per_dps:.4g} A/(deg/s), "
                f"Tu = {relay.tu_s * 1e3:.1f} ms ({relay.cycles} cycles)"
            )
            sets["relay"] = relay.gains

    with Progress("tune", generations(settings), enabled=not args.quiet) as bar:
        baselines_found = [g for k, g in sets.items() if k != "config"]
        result = tune(
            scenarios, start, settings, on_generation=bar.advance, extra_starts=baselines_found
        )
    sets["tuned"] = result.gains

    # The comparison: every gain set in one batch, logs kept for the plots.
    labels = list(sets)
    final = evaluate(
        scenarios, [sets[k] for k in labels], weights=weights, keep_logs=True, seed=args.seed
    )
    terms = {k: final.member_terms(j) for j, k in enumerate(labels)}
    costs = {k: float(final.cost[j]) for j, k in enumerate(labels)}
    loops = {
        k: {n: linear.loop_transfer(bench, g, n) for n in linear.LOOPS} for k, g in sets.items()
    }
    margins = {k: {n: linear.margins(lt) for n, lt in per.items()} for k, per in loops.items()}
    spec = settings.margins or linear.MarginSpec()
    refused = {k: linear.rejection_reasons(bench, g, settings.margins) for k, g in sets.items()}

    note = (
        f"tuned by turntable-sim tune (seed {args.seed}, cost {costs['config']:.4g} -> "
        f"{costs['tuned']:.4g})"
    )
    toml_out = args.out / f"{args.config.stem}_tuned.toml"
    report.write_tuned_toml(args.config, toml_out, result.gains, note)
    offset = BOOT_OFFSET_COUNTS * AXIS_DEG_PER_COUNT
    ba = args.out / "before_after.png"
    plots.plot_before_after(
        {k: final.logs[0].member(j) for j, k in enumerate(labels) if k in ("config", "tuned")},
        ba,
        scenarios[0].title,
        pos_offset_deg=offset,
        time_scale=args.time_scale,
    )
    bode = args.out / "bode.png"
    plots.plot_bode(loops, bode, "loop gains L(z)")

    robust_md = ""
    if not args.no_robust:
        from sim.tuning.robust import robust_table, spread_evaluate

        with Progress("robust", 1, enabled=not args.quiet) as bar:
            worst = spread_evaluate(
                scenarios, sets, weights=weights, seed=args.seed, progress=bar.callback
            )
        robust_md = "\n## Robustness: worst case over the plant spread\n\n" + robust_table(worst)

    stage_lines = [
        f"- {'+'.join(s.loops)}: cost {s.start_cost:.4g} -> {s.cost:.4g} "
        f"({s.generations} generations, {s.simulated} simulated, {s.refused} refused by "
        f"the linear gate)"
        for s in result.stages
    ]
    edge = [
        name
        for name, value in result.gains.as_dict().items()
        if value > 0
        and getattr(start, name) > 0
        and abs(math.log(value / getattr(start, name))) > 0.98 * math.log(args.bound_factor)
    ]
    if edge:
        stage_lines.append(
            f"- at the edge of the search box (x{args.bound_factor:g} of the config): "
            f"{', '.join(edge)}; a larger --bound-factor may find more"
        )
    wall_s = time.perf_counter() - wall0
    md = "\n".join(
        [
            f"# Tuning report: {args.config}",
            "",
            f"Scenarios: {', '.join(names)} (time scale 1/{args.time_scale:g}, 1 s tail); "
            f"seed {args.seed}; mode {settings.mode}; wall time {wall_s:.1f} s.",
            "",
            "## Gains",
            "",
            report.gains_table(sets),
            "",
            "## Cost terms (lower is better)",
            "",
            report.terms_table(terms, costs),
            "",
            f"Weights: {weights}",
            "",
            "## Margins (linear model, docs/tuning.md)",
            "",
            report.margins_table(margins),
            "",
            f"Below the margin spec (GM >= {spec.gain_margin}, PM >= {spec.phase_margin_deg} deg):",
            *[f"- {k}: {'; '.join(v) if v else 'none'}" for k, v in refused.items()],
            "",
            "## Search",
            "",
            *stage_lines,
            robust_md,
            "",
            f"Files: {toml_out.name}, {ba.name}, {bode.name}",
            "",
        ]
    )
    (args.out / "report.md").write_text(md)
    if not args.quiet:
        print(report.terms_table(terms, costs))
        print()
        print(report.margins_table({k: margins[k] for k in ("config", "tuned")}))
        print(f"\ntuned gains written to {toml_out} ({wall_s:.1f} s wall)")
        for p in (ba, bode, args.out / "report.md"):
            print(f"wrote {p}")
    return 0
