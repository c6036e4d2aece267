"""Keeps numba's on-disk cache of the compiled kernels consistent across source files.

Numba caches a compiled function (``cache=True``) keyed on its own source file only: a
kernel that calls kernels of other files (``sim/tick.py``'s ``run_ticks`` calls the law,
the plant, the encoder...) or freezes their constants would load stale machine code after
one of those files changed. So: a digest of every kernel source file is kept next to the
cache; when it changes, the cached kernels of all those files are dropped and compile again
(once; ``sim.loop.compile_notice`` says so if it takes more than a second).

``kernel`` is how every kernel of the compiled tick is compiled: ``numba.njit`` with
``cache=True`` and without numba's reference counting (``_nrt=False``). A call from one
compiled function to another that is not inlined increfs and decrefs every array it passes
(an atomic operation each, on the function's entry and exit, and on every view taken or
array unpacked from a tuple): that was ~40 % of an N = 1 tick (``perf``, 2 December). The
kernels never allocate an array nor return one (the Python caller owns every array and holds
it for the call's duration), so the counts protect nothing. A new kernel uses ``@kernel`` (or
``@kernel(inline="always", ...)``); one that must allocate uses ``@kernel(_nrt=True)``
(numba then refuses the allocation at compile time otherwise, with "Only accept returning of
array passed into the function as argument").

Every kernel uses numba's ``error_model="numpy"``: a division (or an integer modulo) by zero
gives inf / NaN (0 for integers), as numpy does, instead of raising ``ZeroDivisionError``
out of compiled code. The board never raises: a non-finite value goes where the firmware's
checks meet it (a framer refuses NaN, the trip screens compare). The "python" model's test
before every division also cost ~2 % of ``run_ticks``' time (a 2 s N = 256 run, 2 December).
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numba
from numba.core.caching import FunctionCache

__all__ = ["KERNEL_SOURCES", "check", "kernel", "prepare"]


class _KernelCache(FunctionCache):
    """numba's on-disk cache of one kernel, loaded without refreshing numba's registries.

    ``FunctionCache.load_overload`` first calls ``target_context.refresh()``: the first call
    of a process imports and installs every implementation numba has (``numba.np.*``,
    ``numba.typed``, the NRT...), 0.1-0.2 s of a fresh process's start-up on a quiet machine
    (0.26-0.31 s of CPU for the whole kernel load under load 1-2, 0.11-0.15 s without it;
    2 December). A cached kernel is machine code: loading it unpickles and links an object
    file and needs none of those implementations, and with ``_nrt=False`` not the NRT either.
    A cache miss still refreshes (numba's compiler does, ``compiler.compile_extra``)."""

    #: A callable ``(cache, sig, target_context)`` run before each load, or None
    #: (``sim.loop._compile_plant_aside``: wait for the second compiling process's entry).
    before_load = None

    def load_overload(self, sig, target_context):
        if self.before_load is not None:
            self.before_load(self, sig, target_context)
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)


def kernel(fn=None, /, **options):
    """``numba.njit(cache=True, _nrt=False, error_model="numpy", **options)`` (see the module
    docstring); used bare (``@kernel``), with options (``@kernel(inline="always")``) or as a
    call (``kernel(py_function)``). A kernel without the NRT loads from the cache through
    :class:`_KernelCache` (a private attribute of numba's dispatcher, ``_cache``, replaced:
    ``tests/firmware_model/test_kernel_cache.py`` fails if a numba release changes it)."""
    options.setdefault("cache", True)
    options.setdefault("_nrt", False)
    options.setdefault("error_model", "numpy")
    if fn is None:
        return lambda f: kernel(f, **options)
    dispatcher = numba.njit(**options)(fn)
    if options["cache"] and not options["_nrt"]:
        dispatcher._cache = _KernelCache(dispatcher.py_func)
    return dispatcher


_ROOT = Path(__file__).resolve().parents[1]
#: Every source file with compiled kernels or constants frozen into them (repo-relative):
#: every project module ``sim/tick.py`` imports, directly or through others (frame layout
#: and CRC tables, message enums, parameter tables, the profile's phase arrays...).
#: ``tests/firmware_model/test_kernel_cache.py`` derives that set from the imports and fails
#: when a module is missing here.
KERNEL_SOURCES = (
    "firmware_model/as5048.py",
    "firmware_model/fixedpoint.py",
    "firmware_model/kernel_cache.py",
    "firmware_model/laws/dispatch.py",
    "firmware_model/laws/fixed_q.py",
    "firmware_model/laws/float64.py",
    "firmware_model/laws/law.py",
    "firmware_model/laws/layout.py",
    "firmware_model/params.py",
    "firmware_model/safety.py",
    "firmware_model/sense_calibration.py",
    "firmware_model/thermal.py",
    "firmware_model/tick.py",
    "firmware_model/units.py",
    "planner/profile.py",
    "serial_protocol/frame.py",
    "serial_protocol/messages.py",
    "serial_protocol/uart.py",
    "sim/bridge.py",
    "sim/drivetrain.py",
    "sim/encoder.py",
    "sim/motor.py",
    "sim/params.py",
    "sim/plant.py",
    "sim/plant_kernel.py",
    "sim/supply.py",
    "sim/thermal.py",
    "sim/tick.py",
)


_PREPARED: list[bool] = []


def prepare() -> None:
    """Load numba's implementation registries (what its first compile or cache load of the
    process does anyway) without importing ``scipy.linalg``: numba imports it there only to
    set ``numba.np.arraymath._HAVE_BLAS``, which picks the inner product of its
    ``np.convolve``/``np.correlate`` (none in our kernels; ``np.dot`` checks for BLAS again
    when it compiles). The import costs 0.15-0.3 s, a third of a fresh process's kernel
    load (cProfile, 2 December). The tick's kernels skip the refresh (:class:`_KernelCache`);
    a process about to load kernels that need it (the planner's, with the NRT: ``serve``)
    calls this first. Idempotent; a no-op once ``scipy.linalg`` is imported (a command that
    uses it keeps numba's default)."""
    if _PREPARED:
        return
    _PREPARED.append(True)
    if "scipy.linalg" in sys.modules:
        return
    from numba.core.registry import cpu_target

    # None in sys.modules makes "import scipy.linalg[.anything]" raise ImportError, which
    # numba's check catches (BLAS "not available" for that one choice); removed right after.
    sys.modules["scipy.linalg"] = None  # type: ignore[assignment]
    try:
        cpu_target.target_context.refresh()
    finally:
        if sys.modules.get("scipy.linalg", 0) is None:
            del sys.modules["scipy.linalg"]


def check() -> None:
    """Drop the cached kernels if any kernel source changed since they were cached."""
    paths = [_ROOT / name for name in KERNEL_SOURCES]
    digest = hashlib.sha1()
    for path in paths:
        try:
            digest.update(path.read_bytes())
        except OSError:
            return  # not a source tree (e.g. a zipped install): nothing to keep in step
    stamp = _ROOT / "firmware_model" / "__pycache__" / "kernels.sha1"
    want = digest.hexdigest()
    try:
        if stamp.read_text() == want:
            return
    except OSError:
        pass
    for cache_dir in {path.parent / "__pycache__" for path in paths}:
        for stem in {path.stem for path in paths if path.parent == cache_dir.parent}:
            for pattern in (f"{stem}.*.nbi", f"{stem}.*.nbc"):
                for cached in cache_dir.glob(pattern):
                    try:
                        cached.unlink()
                    except OSError:
                        pass
    try:
        stamp.parent.mkdir(exist_ok=True)
        stamp.write_text(want)
    except OSError:
        pass
