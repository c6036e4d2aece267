"""Where the compiled tick spends its time, by kernel (not a test; needs Linux ``perf``).

``run_ticks`` is one machine-code object: the kernels it calls are linked into it (their
own symbols, or inlined into ``run_ticks`` itself), so cProfile sees one function and a
stage timed alone (its arguments captured and called in a loop) runs in another context
(other registers, other aliasing, warm caches) and may cost something else than in the tick.
This samples the real thing: a child process runs the experiment again and again, ``perf
record`` samples it, and each sample in the compiled code is given to the kernel symbol of
``run_ticks``' object that holds it (the object numba compiled, whose layout the loaded code
keeps: addresses are offsets from ``run_ticks``' entry). What is inlined shows under its
caller (``run_ticks`` holds the encoder read's unwrap, the observer, the servo stage, the
log's loops; ``step_members`` holds ``_advance`` and its copy of ``key``).

Usage::

    python3 benchmarks/profile_tick.py [--batch 256] [--duration 2] [--seconds 3]
        [--fixed] [--spread] [--tree .] [--annotate SYMBOL]

``--annotate`` prints the hottest instructions of one kernel (``objdump``).
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

_CHILD = r"""
import dataclasses, os, sys, warnings
warnings.simplefilter("ignore")
tree, batch, duration, out = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[5]
fixed, spread = sys.argv[4] == "1", sys.argv[6] == "1"
sys.path.insert(0, tree)
from pathlib import Path
from sim.config import load_experiment
from sim.loop import run
import sim.tick as st
def _cached_object(dispatcher, symbol):
    import pickle
    def elf(o):
        if isinstance(o, bytes) and o[:4] == b"\x7fELF" and symbol.encode() in o:
            return o
        for x in o.values() if isinstance(o, dict) else o if isinstance(o, (tuple, list)) else ():
            if (r := elf(x)) is not None:
                return r
        return None
    for f in Path(dispatcher._cache._cache_path).glob("tick.run_ticks-*.nbc"):
        if (o := elf(pickle.loads(f.read_bytes()))) is not None:
            return o
    raise SystemExit("run_ticks' object is not in numba's cache")
exp = load_experiment(Path(tree) / "bench_configs" / "fig8.toml")
exp = dataclasses.replace(exp, duration_s=duration)
batch = None if batch == "1" else int(batch)
over = {"servo.arithmetic": "fixed"} if fixed else {}
if spread:  # a Monte-Carlo batch: a parameter set per member (the motor's R, 1.0-1.6 ohm)
    over["motor.r_ohm"] = [1.0 + 0.6 * k / max(1, batch - 1) for k in range(batch)]
run(exp, batch=batch, overrides=over)
for sig, cres in st.run_ticks.overloads.items():
    # the overload of this arithmetic: S (the law's state) of int64 for the fixed law
    s_dtype = str(sig[4].types[2].dtype)
    if (s_dtype == "int64") != fixed:
        continue
    lib = cres.library
    addr = lib.get_pointer_to_function(cres.fndesc.llvm_func_name)
    try:
        lib._get_compiled_object()  # kept when compiled in this process, whose code keeps
        sys.exit(3)  # the callees apart: the caller starts a process that loads the cache
    except RuntimeError:  # loaded from numba's cache: one object, laid out as in its file
        obj = _cached_object(st.run_ticks, cres.fndesc.llvm_func_name)
    Path(out, "run_ticks.o").write_bytes(obj)
    Path(out, "entry").write_text(f"{addr:x} {cres.fndesc.llvm_func_name}")
    with open(f"/tmp/perf-{os.getpid()}.map", "w") as f:
        f.write(f"{addr:x} 1000000 run_ticks\n")
Path(out, "ready").write_text(str(os.getpid()))
while True:
    run(exp, batch=batch, overrides=over)
"""


def _demangle(name: str) -> str:
    """``_ZN3sim12plant_kernel10_excursionB2v8...`` -> ``sim.plant_kernel._excursion``."""
    i = 3 if name.startswith("_ZN") else 0
    parts = []
    while i < len(name) and name[i].isdigit():
        j = i
        while name[j].isdigit():
            j += 1
        n = int(name[i:j])
        parts.append(name[j : j + n])
        i = j + n
    return ".".join(parts) or name[:60]


def _symbols(obj: Path) -> list[tuple[int, int, str, str]]:
    out = subprocess.run(["nm", "-S", "-n", str(obj)], capture_output=True, text=True).stdout
    syms = []
    for line in out.splitlines():
        p = line.split()
        if len(p) == 4 and p[2] in "TtWw":
            syms.append((int(p[0], 16), int(p[1], 16), _demangle(p[3]), p[3]))
    return syms


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--duration", type=float, default=2.0, help="simulated s of each run")
    ap.add_argument("--seconds", type=float, default=3.0, help="how long perf samples")
    ap.add_argument("--fixed", action="store_true", help="the fixed-point law")
    ap.add_argument(
        "--spread", action="store_true",
        help="a parameter set per member (motor R 1.0-1.6 ohm): the Monte-Carlo path",
    )  # fmt: skip
    ap.add_argument("--tree", default=str(Path(__file__).resolve().parents[1]))
    ap.add_argument("--annotate", metavar="SYMBOL", help="e.g. sim.plant_kernel._excursion")
    a = ap.parse_args()
    for tool in ("perf", "nm", "objdump"):
        if not shutil.which(tool):
            print(f"profile_tick: {tool} not found (Debian: linux-perf, binutils)", file=sys.stderr)
            return 2
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        args = [sys.executable, "-c", _CHILD, a.tree, str(a.batch), str(a.duration),
                "1" if a.fixed else "0", tmp, "1" if a.spread else "0"]  # fmt: skip
        child = subprocess.Popen(args)
        try:
            for _ in range(1200):  # a first run after a change compiles (~20 s)
                if (t / "ready").exists():
                    break
                if child.poll() == 3:  # it compiled the tick: again, from the cache
                    child = subprocess.Popen(args)
                elif child.poll() is not None:
                    break
                time.sleep(0.1)
            if not (t / "ready").exists():
                print("profile_tick: the child did not start", file=sys.stderr)
                return 1
            data = t / "perf.data"
            subprocess.run(
                ["perf", "record", "-q", "-F", "4999", "-p", str(child.pid), "-o", str(data),
                 "--", "sleep", str(a.seconds)],
                check=True, capture_output=True,
            )  # fmt: skip
            # perf script reads the child's map (/tmp/perf-PID.map) for the compiled code
            script = subprocess.run(
                ["perf", "script", "-i", str(data), "-F", "ip,sym"], capture_output=True,
                text=True,
            ).stdout  # fmt: skip
        finally:
            child.kill()
            child.wait()
            Path(f"/tmp/perf-{child.pid}.map").unlink(missing_ok=True)
        entry = int((t / "entry").read_text().split()[0], 16)
        syms = _symbols(t / "run_ticks.o")
        start = next(s for s in syms if s[3] == (t / "entry").read_text().split()[1])[0]
        total = 0
        outside: collections.Counter[str] = collections.Counter()
        inside: collections.Counter[str] = collections.Counter()
        offsets: collections.Counter[int] = collections.Counter()
        for line in script.splitlines():
            p = line.split(None, 1)
            if not p:
                continue
            total += 1
            sym = p[1].strip() if len(p) > 1 else "?"
            if sym != "run_ticks":
                outside[re.sub(r"\+0x.*", "", sym)] += 1
                continue
            off = int(p[0], 16) - entry + start
            offsets[off] += 1
            name = next((s[2] for s in syms if s[0] <= off < s[0] + s[1]), "(outside the object)")
            inside[name] += 1
        n_in = sum(inside.values())
        print(
            f"{total} samples ({a.seconds:g} s at 4999 Hz), N = {a.batch}, "
            f"{'fixed' if a.fixed else 'float'} law; the compiled tick: "
            f"{100 * n_in / max(total, 1):.1f} %"
        )
        print("\n| kernel (its own code and what is inlined into it) | share of the tick |")
        print("|---|---:|")
        for name, k in inside.most_common():
            print(f"| `{name}` | {100 * k / n_in:.1f} % |")
        print("\nOutside the compiled tick (share of all samples):")
        for name, k in outside.most_common(8):
            print(f"  {100 * k / total:5.1f} %  {name}")
        if a.annotate:
            found = [s for s in syms if s[2] == a.annotate]
            if not found:
                names = ", ".join(sorted({s[2] for s in syms}))
                print(f"profile_tick: --annotate {a.annotate!r}: not a kernel of the tick "
                      f"({names})", file=sys.stderr)  # fmt: skip
                return 2
            s0, size, _, _ = found[0]
            dis = subprocess.run(
                ["objdump", "-d", "--no-show-raw-insn", f"--start-address={s0}",
                 f"--stop-address={s0 + size}", str(t / "run_ticks.o")],
                capture_output=True, text=True,
            ).stdout  # fmt: skip
            here = sum(k for o, k in offsets.items() if s0 <= o < s0 + size)
            print(f"\n{a.annotate}: {here} samples; instructions with 1 % or more of them:")
            for line in dis.splitlines():
                m = re.match(r"\s*([0-9a-f]+):\s*(.*)", line)
                if m and offsets.get(int(m.group(1), 16), 0) >= max(here / 100, 1):
                    k = offsets[int(m.group(1), 16)]
                    print(f"  {100 * k / here:5.1f} %  {m.group(1)}: {m.group(2)[:90]}")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONWARNINGS", "ignore")
    sys.exit(main())
