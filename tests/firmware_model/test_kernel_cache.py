"""The kernel cache's list of sources covers every module the compiled tick is built from.

Numba keys a cached kernel on its own file only, so ``kernel_cache.KERNEL_SOURCES`` must name
every project module whose code or constants can end up in ``sim/tick.py``'s compiled run: a
module left out would, once changed, be served from stale machine code. The set is derived
here from the import statements (``ast``), not kept by hand.
"""

import ast
from pathlib import Path

from firmware_model import kernel_cache

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = {"firmware_model", "sim", "serial_protocol", "planner"}
# Modules that hold no kernel code and no constant a kernel could freeze.
NOT_KERNEL: set[str] = set()


def _module_file(name: str) -> Path | None:
    for path in (
        ROOT / (name.replace(".", "/") + ".py"),
        ROOT / name.replace(".", "/") / "__init__.py",
    ):
        if path.exists():
            return path
    return None


def _project_imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return {n for n in names if n.split(".")[0] in PACKAGES}


def reachable_from(module: str) -> set[str]:
    """Repo-relative files of every project module ``module`` imports, transitively."""
    seen: set[Path] = set()
    todo = [module]
    while todo:
        path = _module_file(todo.pop())
        if path is None or path in seen:
            continue
        seen.add(path)
        todo.extend(_project_imports(path))
    return {p.relative_to(ROOT).as_posix() for p in seen if p.name != "__init__.py"}


def test_every_module_of_the_compiled_tick_is_a_kernel_source():
    needed = reachable_from("sim.tick") - NOT_KERNEL
    missing = sorted(needed - set(kernel_cache.KERNEL_SOURCES))
    assert not missing, f"add to firmware_model/kernel_cache.py KERNEL_SOURCES: {missing}"


def test_every_kernel_source_exists():
    for name in kernel_cache.KERNEL_SOURCES:
        assert (ROOT / name).is_file(), name


def test_the_walk_sees_through_imports():
    # the tick reaches the frame layout only through firmware_model/tick.py
    assert "serial_protocol/frame.py" in reachable_from("sim.tick")
    assert "serial_protocol/frame.py" not in reachable_from("sim.plant_kernel")


_LOAD = """
import sys
from pathlib import Path
from sim.config import load_experiment
from sim.loop import run, warm_up
exp = load_experiment(Path({root!r}) / "bench_configs" / "fig8.toml")
warm_up(exp.bench)
loaded = sorted(m for m in ("numba.np.linalg", "numba.np.arraymath", "numba.typed.typeddict")
                if m in sys.modules)
print("registries:", ",".join(loaded) or "none")
"""


def test_the_ticks_kernels_load_from_the_cache_without_numbas_registries():
    """A cached kernel is linked, not compiled: ``_KernelCache`` skips numba's refresh, which
    imports every implementation numba has (half of a fresh process's kernel load). The first
    process may compile (an empty cache refreshes inside numba's compiler); the second loads
    the same kernels from the cache and must not have imported numba's implementation modules.
    """
    import subprocess
    import sys

    code = _LOAD.format(root=str(ROOT))
    env = {**__import__("os").environ, "PYTHONPATH": str(ROOT)}
    first = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert first.returncode == 0, first.stderr
    second = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert second.returncode == 0, second.stderr
    assert second.stdout.strip().splitlines()[-1] == "registries: none", second.stdout


_ASIDE = """
import sys
from pathlib import Path
from sim import loop
from sim.config import load_bench
from sim.supply import step_period
sim = loop.Simulation(load_bench(Path({root!r}) / "bench_configs" / "paper_bench.toml"))
loop._compile_plant_aside(sim)
proc = loop._ASIDE[0]
assert proc is not None, "no second process with an empty cache"
assert proc.wait() == 0, proc.returncode
loop._ASIDE[0] = None
sim.step(3)  # compiles run_ticks: the plant's step must come from the second process's cache
hits, misses = step_period.stats.cache_hits, step_period.stats.cache_misses
print("hits", sum(hits.values()), "misses", sum(misses.values()))
"""


def test_a_cold_start_compiles_the_plant_step_in_a_second_process(tmp_path):
    """With an empty numba cache, ``sim.loop._compile_plant_aside`` compiles the plant's step
    in a second process with exactly the argument types ``run_ticks`` passes: the tick then
    loads it from the cache instead of compiling it (here the second process is waited for,
    so the check does not depend on which finishes first). ~20 s: a whole cold compile."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run(
        [sys.executable, "-c", _ASIDE.format(root=str(ROOT))],
        capture_output=True, text=True, env=env,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "hits 1 misses 0", out.stdout


def _divide(a, b, m, k):
    return a / b, m % k, m // k


def test_a_kernels_division_by_zero_gives_numpys_values_and_never_raises():
    # The board never raises: compiled code does not throw ZeroDivisionError (numba's
    # "python" error model would), it gives inf / NaN / 0 as numpy does.
    f = kernel_cache.kernel(_divide, cache=False)
    q, r, d = f(1.0, 0.0, 7, 0)
    assert q == float("inf") and r == 0 and d == 0
    assert f(7.0, 2.0, -7, 2) == (3.5, 1, -4)  # and Python's floored integer semantics


class _Proc:
    def __init__(self, alive: bool) -> None:
        self.alive = alive

    def poll(self):
        return None if self.alive else 0


class _Index:
    """A cache whose index shows ``key`` from the ``after``-th read on."""

    def __init__(self, key, after: int, broken: int = 0) -> None:
        self.key, self.after, self.reads, self.broken = key, after, 0, broken
        self._cache_file = self

    def _index_key(self, sig, codegen):
        return sig

    def _load_index(self):
        self.reads += 1
        if self.reads <= self.broken:
            raise EOFError("an index being written")
        return {self.key: 1} if self.reads >= self.after else {}


class _Target:
    def codegen(self):
        return None


def test_the_tick_waits_for_the_second_process_entry_and_no_longer(monkeypatch):
    # run_ticks' typing reaching the plant step while the second process still compiles it
    # waits for that entry (then loads it) rather than compiling it a second time; any other
    # signature loads at once; a process that has ended or a wait past _ASIDE_WAIT_S stops
    # the wait (the step is then compiled here, as without the second process).
    from sim import loop

    waits = loop._awaiting(_Proc(alive=True), "plant")
    index = _Index("plant", after=3)
    waits(index, "plant", _Target())
    assert index.reads == 3
    other = _Index("plant", after=10**9)
    waits(other, "another signature", _Target())
    assert other.reads == 0
    ended = _Index("plant", after=10**9)
    loop._awaiting(_Proc(alive=False), "plant")(ended, "plant", _Target())
    assert ended.reads == 0
    unreadable = _Index("plant", after=4, broken=2)  # the first reads fail: no traceback
    waits(unreadable, "plant", _Target())
    assert unreadable.reads == 4
    monkeypatch.setattr(loop, "_ASIDE_WAIT_S", 0.05)
    never = _Index("plant", after=10**9)
    waits(never, "plant", _Target())
    assert never.reads >= 1


_IN_BOUNDS = """
import dataclasses, sys, warnings
warnings.simplefilter("ignore")
from pathlib import Path
from sim.config import load_experiment
from sim.loop import run
B = Path({root!r}) / "bench_configs"
fig6, fig8, step = (load_experiment(B / f) for f in ("fig6.toml", "fig8.toml", "step_demo.toml"))
cut = dataclasses.replace
runs = [
    # a batch the plant sweeps, both noises; the bus and heat models with parameters per
    # member; the fixed-point law; an over-current trip
    run(cut(fig8, duration_s=0.6), batch=20,
        overrides={{"encoder.noise_rms_lsb": 2.0, "current_sense.noise_rms_lsb": 1.5}}),
    run(cut(fig6, duration_s=0.6), batch=3, overrides={{
        "supply.bus_model": True, "thermal.model": True, "motor.r_ohm": [1.0, 1.2, 1.4]}}),
    run(cut(step, duration_s=0.4), overrides={{"servo.arithmetic": "fixed"}}),
    run(cut(fig6, duration_s=0.6), overrides={{"safety.over_current_a": 5.05}}),
]
print("ok", [len(r.log) for r in runs])
"""


def test_the_compiled_tick_stays_within_its_arrays(tmp_path):
    """The kernels run without bounds checks: an index past an array's end reads or writes
    whatever memory follows (a test's table one column short once read a NaN that way). With
    ``NUMBA_BOUNDSCHECK=1`` (and a cache of its own) numba checks every index and raises
    instead: a batch the plant sweeps, the bus and heat models, the fixed-point law and a
    trip run through. ~40 s (every kernel compiled with its checks)."""
    import os
    import subprocess
    import sys

    env = {
        **os.environ, "PYTHONPATH": str(ROOT), "NUMBA_CACHE_DIR": str(tmp_path),
        "NUMBA_BOUNDSCHECK": "1",
    }  # fmt: skip
    out = subprocess.run(
        [sys.executable, "-c", _IN_BOUNDS.format(root=str(ROOT))],
        capture_output=True, text=True, env=env,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().splitlines()[-1] == "ok [300, 300, 200, 300]", out.stdout
