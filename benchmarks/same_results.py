"""Whether two trees compute the same runs, bit for bit (not a test: the check a pure speed
change of the simulation is made against; docs/benchmarks.md, "Simulation").

Each tree runs the scenarios below in its own fresh interpreter (the tree first on the
path) and hashes every log column (values, shape and dtype) and the bytes the PC received;
the two sets of hashes are then compared scenario by scenario. The scenarios are those
of session 5's batch changes: Fig. 6/7/8, step_demo float / fixed / ADC noise, N = 8
per-member gains and R, N = 8 fixed, N = 16 encoder + ADC noise, N = 256 float and fixed,
sensor / following-error trips N = 1 and 5, over-current trips N = 1 and 4, the bus with
brakes N = 1 and 3, heat N = 3, N = 7 per-member gains with encoder noise; and since
session 8 (the plant step's sweep of batches of 16 or more sharing the plant) N = 32
per-member gains with encoder noise and N = 20 with the bus model braking; and since
session 9 (the sweep of batches with a parameter set per member) N = 24 with R per member
and encoder noise, N = 20 with heat, N = 20 with the bus and a brake resistor per member: 24.

Usage::

    python3 benchmarks/same_results.py TREE_A TREE_B [SCENARIO ...]
    python3 benchmarks/same_results.py --hash TREE OUT.json [SCENARIO ...]

Exit status 0 when every scenario is identical, 1 when one differs or fails.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

_HASH = r"""
import dataclasses, hashlib, json, sys, warnings
import numpy as np
warnings.simplefilter("ignore")
tree, out_path, only = sys.argv[1], sys.argv[2], sys.argv[3:]
sys.path.insert(0, tree)
from pathlib import Path
from sim.config import load_experiment
from sim.loop import LOG_FIELDS, run

B = Path(tree) / "bench_configs"
fig6, fig7, fig8, step = (load_experiment(B / f) for f in
                          ("fig6.toml", "fig7.toml", "fig8.toml", "step_demo.toml"))
f8s = dataclasses.replace(fig8, duration_s=3.0)
f82 = dataclasses.replace(fig8, duration_s=2.0)
lin = np.linspace
S = {
    "fig6": lambda: run(fig6),
    "fig7": lambda: run(fig7),
    "fig8": lambda: run(fig8),
    "step": lambda: run(step),
    "step_fixed": lambda: run(step, overrides={"servo.arithmetic": "fixed"}),
    "step_noisy": lambda: run(step, overrides={"current_sense.noise_rms_lsb": 2.0}),
    "n8_params": lambda: run(f8s, batch=8, overrides={
        "controller.velocity.kp_a_per_dps": list(lin(0.5, 2, 8) * 0.0651274),
        "motor.r_ohm": list(lin(1.0, 1.6, 8))}),
    "n8_fixed": lambda: run(f8s, batch=8, overrides={
        "servo.arithmetic": "fixed", "motor.r_ohm": list(lin(1.0, 1.6, 8))}),
    "n16_noisy": lambda: run(f8s, batch=16, overrides={"current_sense.noise_rms_lsb": 1.5}),
    "n256_fig8": lambda: run(f82, batch=256),
    "n256_fixed": lambda: run(f82, batch=256, overrides={"servo.arithmetic": "fixed"}),
    "n5_fe_trip": lambda: run(f8s, batch=5, overrides={
        "limits.following_error_deg": 2.0, "motor.r_ohm": [1.0, 3.0, 6.0, 10.0, 15.0]}),
    "n1_fe_trip": lambda: run(f8s, overrides={
        "limits.following_error_deg": 2.0, "motor.r_ohm": 10.0}),
    "n4_oc_trip": lambda: run(fig6, batch=4, overrides={
        "safety.over_current_a": 5.05, "motor.r_ohm": [0.5, 1.0, 1.5, 2.0]}),
    "n1_oc_trip": lambda: run(fig6, overrides={"safety.over_current_a": 5.05}),
    "n3_bus_brake": lambda: run(fig6, batch=3, overrides={
        "supply.bus_model": True, "supply.brake_resistor_ohm": [0.0, 4.0, 8.0]}),
    "n1_bus": lambda: run(fig6, overrides={"supply.bus_model": True}),
    "n3_heat": lambda: run(f8s, batch=3, overrides={
        "thermal.model": True, "motor.r_ohm": [1.0, 1.2, 1.4]}),
    "n7_step_params": lambda: run(step, batch=7, overrides={
        "controller.position.kp_per_s": list(lin(8, 30, 7)), "encoder.noise_rms_lsb": 2.0}),
    # batches of 16 members or more that share the plant (the plant step's sweep): the
    # tuner's gains per member, and the bus model's periods and sub-steps while braking
    "n32_gains": lambda: run(f82, batch=32, overrides={
        "controller.position.kp_per_s": list(lin(8, 40, 32)), "encoder.noise_rms_lsb": 2.0}),
    "n20_bus": lambda: run(fig6, batch=20, overrides={"supply.bus_model": True}),
    # batches of 16 or more with a parameter set per member (the sweep from each member's
    # coefficient rows): a Monte-Carlo spread of R, heat moving members between sets, the
    # bus model with a brake resistor per member
    "n24_spread": lambda: run(f82, batch=24, overrides={
        "motor.r_ohm": list(lin(1.0, 1.6, 24)), "encoder.noise_rms_lsb": 2.0}),
    "n20_heat": lambda: run(f8s, batch=20, overrides={
        "thermal.model": True, "motor.r_ohm": list(lin(1.0, 1.4, 20))}),
    "n20_bus_brake": lambda: run(fig6, batch=20, overrides={
        "supply.bus_model": True, "supply.brake_resistor_ohm": list(lin(2.0, 8.0, 20))}),
}


def digest(a):
    a = np.ascontiguousarray(a)
    blob = a.tobytes() + str(a.shape).encode() + str(a.dtype).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


out = {}
for name in only or list(S):
    try:
        res = S[name]()
        out[name] = {f: digest(getattr(res.log, f)) for f in LOG_FIELDS}
        out[name]["pc"] = hashlib.sha256(res.pc_bytes).hexdigest()[:16]
        out[name]["faults"] = str(np.unique(res.log.fault))
    except Exception as exc:  # a scenario the tree cannot run: reported, not hashed
        out[name] = {"error": repr(exc)[:200]}
    print(f"  {name}: {'hashed' if 'error' not in out[name] else out[name]['error']}",
          file=sys.stderr)
json.dump(out, open(out_path, "w"), indent=1)
"""


def hash_tree(tree: str, out: str, only: list[str]) -> dict[str, dict[str, str]]:
    """Run the scenarios in ``tree`` (a fresh interpreter) and return their hashes."""
    subprocess.run([sys.executable, "-c", _HASH, tree, out, *only], check=True)
    return json.loads(Path(out).read_text())


def compare(a: dict[str, dict[str, str]], b: dict[str, dict[str, str]]) -> int:
    """Print scenario by scenario what differs; return the number of scenarios differing."""
    bad = 0
    for name in b:
        if "error" in b[name] or "error" in a.get(name, {"error": "missing"}):
            print(f"{name}: FAILED ({a.get(name, {}).get('error')} / {b[name].get('error')})")
            bad += 1
            continue
        diff = [f for f in b[name] if a[name].get(f) != b[name][f]]
        print(f"{name}: {'identical' if not diff else 'DIFFERENT ' + ', '.join(diff)}")
        bad += bool(diff)
    print(f"{bad} of {len(b)} scenarios differ")
    return bad


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--hash", action="store_true", help="only hash TREE into OUT.json")
    ap.add_argument("first", help="TREE_A (or TREE with --hash)")
    ap.add_argument("second", help="TREE_B (or OUT.json with --hash)")
    ap.add_argument("scenarios", nargs="*", help="a subset of the scenarios (default: all)")
    args = ap.parse_args()
    if args.hash:
        hash_tree(args.first, args.second, args.scenarios)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        print(f"hashing {args.first}", file=sys.stderr)
        a = hash_tree(args.first, f"{tmp}/a.json", args.scenarios)
        print(f"hashing {args.second}", file=sys.stderr)
        b = hash_tree(args.second, f"{tmp}/b.json", args.scenarios)
    return 1 if compare(a, b) else 0


if __name__ == "__main__":
    sys.exit(main())
