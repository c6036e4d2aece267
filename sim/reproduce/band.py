"""Issue 13, section 3: the paper's figures over the spread of what the bench model assumes.

The motor of the paper's bench is not known (seed 000 gives no motor data); `[motor]` holds
assumed values. This module runs the reproduction's experiments over a spread of them and
over the plant effects of issue 13 switched on one at a time, all members of an experiment
in **one lock-step batch** of the simulator (``sim.loop.run(batch=N)`` with ``(N,)``
parameter and gain arrays: member k computes what a one-axis run with its parameters
computes), and says what moves each figure and by how much.

**The motor design** (:func:`factorial_design`): R, Kt (= Ke, the same constant in SI) and J
each at x0.7, x1 and x1.3, a full 3^3 factorial (27 motors, the nominal one among them).
Why a factorial and not a Latin hypercube of the same size: the band is an *envelope*, and
for responses that are monotone in each factor the extremes sit at the corners, which a
factorial contains and a 27-point hypercube almost never does; the faces and the centre show
the curvature, and the interactions are large here (the step's overshoot under fixed gains
goes from 0 to 500 deg with Kt and R together, far from the sum of their main effects).

**Gains per member** (:data:`GAINS`):

* ``fixed``: the firmware as configured (its feed-forward model is the nominal motor's and
  its gains are the config's), whatever the motor: what happens when the motor changes and
  the gains do not.
* ``model``: the firmware's feed-forward model derived from the member's own motor
  (``sim.tuning.baselines.firmware_model_for``), the config's gains.
* ``classic`` (the default re-tune): that model plus the tuner's "classic" baseline on the
  member's bench (``sim.tuning.baselines.classic``: current PI from a bandwidth, velocity PI
  by the symmetric optimum, position P at a quarter of its crossover). Cheap (analytic) and
  checked by the tuner's linear gate.
* ``de``: that model plus the tuner's differential evolution (``sim.tuning.optimise.tune``,
  default settings, its default scenario: Fig. 8 compressed 4x, as ``turntable-sim tune``
  runs it), started from the classic gains: the honest "as a user would tune it", one tune
  per motor (seconds each), so only behind ``reproduce --sensitivity --retune de``.

The observer's Kt/J (``[estimator] accel_per_amp_dps2``) stays nominal for every member (the
batch takes it as one number); measured on single runs of eight motors of the design it
moves the Fig. 6 overshoot by at most 0.3 deg.

**Effects** (:data:`EFFECTS`): every switch of docs/model.md that the bench has off (or on,
for the gearbox drag), at the values docs/model.md assumes when it is on; the heat model
(``[thermal] model``) from ambient and from a warm motor. The bus and heat models
(``[supply] bus_model``, ``[thermal] model``) are switches the batch cannot vary per member;
their members run in batches of their own. Without a brake chopper the bus model **locks
the bridge out** in Fig. 6's braking (28 V) and the step overshoots by hundreds of degrees;
the report says so and the band figure marks it (it is not drawn inside the envelope, whose
scale it would flatten).

Noise: every member of a batch draws its own encoder noise, so ``noise_copies`` copies of
each member (every motor, gains and effect: :func:`more_copies`) give the spread that the
noise alone makes: the one-at-a-time tables print each member's mean ± sd over its copies,
the band tables the spread over motors of the per-motor means and, apart from it, the
per-motor standard deviations (:func:`per_motor`).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import statistics
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sim.config import BenchConfig, Experiment
from sim.loop import RunLog, apply_overrides, run

__all__ = [
    "EFFECTS",
    "GAINS",
    "LEVELS",
    "DESIGNS",
    "BandResult",
    "Member",
    "Motor",
    "PerMotor",
    "Study",
    "bench_value",
    "composite_design",
    "default_noise_copies",
    "factorial_design",
    "first_fault",
    "iter_members",
    "member_overrides",
    "more_copies",
    "one_at_a_time",
    "per_motor",
    "retune",
    "run_members",
    "spread",
    "tripped",
]

#: The factor levels of R, Kt (= Ke) and J: the issue's +-30 %.
LEVELS = (0.7, 1.0, 1.3)

#: How a member's firmware is set up (module doc).
GAINS = ("fixed", "model", "classic", "de")

#: Effect name -> the overrides that switch it on (docs/model.md section 6 values).
EFFECTS: dict[str, dict[str, Any]] = {
    "gearbox drag off": {"gearbox.drag_nm": 0.0, "gearbox.drag_viscous_nm_s_rad": 0.0},
    "stiction (motor 5 mN·m, platter 0.45 N·m)": {
        "motor.stiction_nm": 0.005,
        "motor.stribeck_rad_s": 1.0,
        "platter.stiction_nm": 0.45,
        "platter.stribeck_rad_s": 0.01,
    },
    "encoder INL 0.5° / 0.1°": {
        "encoder.inl_h1_deg": 0.5,
        "encoder.inl_h2_deg": 0.1,
        "encoder.inl_h2_phase_deg": 30.0,
    },
    "chip k_ILIS 3k (firmware 8.5k)": {"current_sense.k_ilis": 3000.0},
    "chip k_ILIS 14k (firmware 8.5k)": {"current_sense.k_ilis": 14000.0},
    "IS offset 50 µA": {"current_sense.is_offset_ua": 50.0},
    "IS offset 50 µA, calibrated at enable": {
        "current_sense.is_offset_ua": 50.0,
        "controller.current.sense_calibration": True,
    },
    "ADC at the ripple's valley": {"current_sense.sample_point": 0.0},
    "bridge switching times (typical)": {
        "bridge.pulse_shift_with_current_us": -0.7,
        "bridge.pulse_shift_against_current_us": 2.7,
    },
    "bus model, 2,200 µF, no brake": {"supply.bus_model": True},
    "bus model + chopper 10 Ω at 26.5 V": {
        "supply.bus_model": True,
        "supply.brake_resistor_ohm": 10.0,
    },
    "thermal model, motor at 25 °C ambient": {"thermal.model": True},
    "thermal model, warm motor (winding +55 K, housing +30 K)": {
        "thermal.model": True,
        "thermal.initial_winding_rise_k": 55.0,
        "thermal.initial_housing_rise_k": 30.0,
    },
}


@dataclass(frozen=True)
class Motor:
    """Factors on the bench's motor: ``r`` on R, ``kt`` on Kt and Ke, ``j`` on the rotor J."""

    r: float = 1.0
    kt: float = 1.0
    j: float = 1.0

    @property
    def nominal(self) -> bool:
        return self.r == 1.0 and self.kt == 1.0 and self.j == 1.0

    @property
    def label(self) -> str:
        parts = [f"{n}×{f:g}" for n, f in (("R", self.r), ("Kt", self.kt), ("J", self.j))]
        off = [p for p, f in zip(parts, (self.r, self.kt, self.j), strict=True) if f != 1.0]
        return " ".join(off) or "nominal motor"

    def overrides(self, bench: BenchConfig) -> dict[str, float]:
        """``{"table.key": value}`` of this motor on ``bench`` (scalars)."""
        m = bench.plant.motor
        return {
            "motor.r_ohm": float(m.r_ohm) * self.r,
            "motor.kt_nm_a": float(m.kt_nm_a) * self.kt,
            "motor.ke_v_s_rad": float(m.ke_v_s_rad) * self.kt,
            "motor.j_kgm2": float(m.j_kgm2) * self.j,
        }


def factorial_design(levels: Sequence[float] = LEVELS) -> tuple[Motor, ...]:
    """The full factorial over R, Kt, J at ``levels`` (27 motors), the nominal first."""
    motors = [Motor(r, kt, j) for r, kt, j in itertools.product(levels, levels, levels)]
    motors.sort(key=lambda m: not m.nominal)  # stable: the rest keep the product order
    return tuple(motors)


def one_at_a_time(levels: Sequence[float] = (LEVELS[0], LEVELS[-1])) -> tuple[Motor, ...]:
    """Each of R, Kt, J alone at each of ``levels`` (the others nominal)."""
    return tuple(Motor(**{name: lv}) for name in ("r", "kt", "j") for lv in levels)


def composite_design(lo: float = LEVELS[0], hi: float = LEVELS[-1]) -> tuple[Motor, ...]:
    """The face-centred composite design (15 motors): the nominal, the 8 corners of the
    box and the 6 centres of its faces (each factor alone at ``lo`` and ``hi``)."""
    corners = [Motor(r, kt, j) for r, kt, j in itertools.product((lo, hi), repeat=3)]
    return (Motor(), *corners, *one_at_a_time((lo, hi)))


#: Design name -> motors: ``"composite"`` (15, the default run) and ``"factorial"`` (27,
#: ``reproduce --sensitivity``).
DESIGNS: dict[str, Callable[[], tuple[Motor, ...]]] = {
    "composite": composite_design,
    "factorial": factorial_design,
}


@dataclass(frozen=True)
class Member:
    """One member of a study: a motor, how its firmware is set up, one effect (or none)
    and which noise copy it is."""

    motor: Motor = Motor()
    gains: str = "fixed"
    effect: str | None = None
    copy: int = 0

    def __post_init__(self) -> None:
        if self.gains not in GAINS:
            raise ValueError(f"gains = {self.gains!r}: must be one of {GAINS}")
        if self.effect is not None and self.effect not in EFFECTS:
            raise ValueError(f"effect = {self.effect!r}: must be one of {sorted(EFFECTS)}")

    @property
    def label(self) -> str:
        parts = [] if self.motor.nominal else [self.motor.label]
        parts += [self.effect] if self.effect else []
        return ", ".join(parts) or "bench"


def bench_value(bench: BenchConfig, dotted: str) -> Any:
    """The value of ``"table.key"`` on ``bench`` (the names of ``sim.loop.apply_overrides``)."""
    table, _, key = dotted.rpartition(".")
    part = getattr(bench.plant, table, None)
    if part is None or not dataclasses.is_dataclass(part):
        part = getattr(bench.firmware, table.removeprefix("controller."))
    return getattr(part, key)


def retune(bench: BenchConfig, motor: Motor, how: str, *, seed: int = 0) -> dict[str, float]:
    """The firmware overrides of a ``how``-tuned member with ``motor`` (``GAINS``; empty for
    ``fixed``): the feed-forward model of its motor and, but for ``model``, its gains
    re-tuned by the tuner's own code on its own bench."""
    from sim.tuning import baselines
    from sim.tuning.gains import GainSet

    if how == "fixed":
        return {}
    own = apply_overrides(bench, motor.overrides(bench))
    model = baselines.firmware_model_for(own)
    own = apply_overrides(own, model)
    gains = GainSet.from_bench(own)
    if how in ("classic", "de"):
        gains = baselines.classic(own, gains)
    if how == "de":
        from sim.tuning.optimise import TuneSettings, tune
        from sim.tuning.scenarios import DEFAULT_SCENARIO, scenario

        scen = [scenario(DEFAULT_SCENARIO, own, time_scale=4.0, tail_s=1.0)]
        gains = tune(scen, gains, TuneSettings(seed=seed)).gains
    return {**model, **gains.overrides()}


def member_overrides(
    bench: BenchConfig, member: Member, tuned: Mapping[tuple[Motor, str], Mapping[str, float]]
) -> dict[str, Any]:
    """Everything member ``member`` changes on ``bench``: its motor, its firmware
    (``tuned[(motor, gains)]``, from :func:`retune`) and its effect."""
    ov: dict[str, Any] = member.motor.overrides(bench)
    ov.update(tuned.get((member.motor, member.gains), {}))
    ov.update(EFFECTS[member.effect] if member.effect else {})
    return ov


#: The most members run as one batch: a full study's 3,900 members of a 10 s run would
#: hold about 2 GB of logs at once; chunks of this size run as fast per member-tick.
MAX_BATCH = 512


def iter_members(
    exp: Experiment,
    members: Sequence[Member],
    tuned: Mapping[tuple[Motor, str], Mapping[str, float]],
    *,
    seed: int = 0,
    max_batch: int = MAX_BATCH,
) -> Iterator[tuple[int, RunLog]]:
    """Run every member of ``members`` on ``exp``; ``(member index, its log)`` batch by
    batch (a batch's logs are freed once the caller has dropped them).

    Members whose switches (boolean settings such as ``[supply] bus_model``, which a batch
    cannot vary per member) agree run as one batch with ``(N,)`` arrays for everything
    else, in chunks of at most ``max_batch``. Telemetry is off in these runs (nothing reads
    it; the metrics come from the log).
    """
    bench = exp.bench
    per = [member_overrides(bench, m, tuned) for m in members]
    groups: dict[tuple, list[int]] = {}
    for k, ov in enumerate(per):
        switches = tuple(sorted((key, v) for key, v in ov.items() if isinstance(v, bool)))
        groups.setdefault(switches, []).append(k)
    chunks = [
        (switches, idx[i : i + max_batch])
        for switches, idx in groups.items()
        for i in range(0, len(idx), max_batch)
    ]
    for switches, idx in chunks:
        keys = sorted({key for k in idx for key, v in per[k].items() if not isinstance(v, bool)})
        ov: dict[str, Any] = dict(switches)
        for key in keys:
            default = bench_value(bench, key)
            ov[key] = np.array([float(per[k].get(key, default)) for k in idx])
        ov["telemetry.decimation"] = 0
        log = run(exp, batch=len(idx), seed=seed, overrides=ov).log
        for j, k in enumerate(idx):
            yield k, log.member(j)
        del log


def run_members(
    exp: Experiment,
    members: Sequence[Member],
    tuned: Mapping[tuple[Motor, str], Mapping[str, float]],
    *,
    seed: int = 0,
    max_batch: int = MAX_BATCH,
) -> list[RunLog]:
    """Run every member of ``members`` on ``exp`` (:func:`iter_members`); the logs in
    member order."""
    logs: list[RunLog | None] = [None] * len(members)
    for k, log in iter_members(exp, members, tuned, seed=seed, max_batch=max_batch):
        logs[k] = log
    return [log for log in logs if log is not None]


def first_fault(log: RunLog) -> dict[str, float]:
    """``{"fault code": c, "fault at (s)": t}`` of the first fault latched (0 and NaN if
    none); the code is ``serial_protocol.messages.Fault``."""
    k = np.flatnonzero(log.fault)
    if not k.size:
        return {"fault code": 0.0, "fault at (s)": math.nan}
    return {"fault code": float(log.fault[k[0]]), "fault at (s)": float(log.t_s[k[0]])}


def spread(values: Sequence[float]) -> tuple[float, float, float, float]:
    """``(mean, standard deviation, min, max)`` of the finite values (NaN if none)."""
    vals = [v for v in values if not math.isnan(v)]
    if not vals:
        return (math.nan,) * 4
    sd = statistics.stdev(vals) if len(vals) > 1 else 0.0
    return statistics.fmean(vals), sd, min(vals), max(vals)


@dataclass(frozen=True)
class Study:
    """Members of one experiment, their metrics and (if kept) some log columns.

    ``metrics[k]`` is ``metric(log of member k)``; ``columns[name]`` is ``(len(kept),
    n_ticks)`` for the columns kept, row j of member ``kept[j]`` (:meth:`column`), ``t_s``
    ``(n_ticks,)``.
    """

    name: str
    members: tuple[Member, ...]
    metrics: tuple[dict[str, float], ...]
    t_s: np.ndarray
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    wall_s: float = 0.0
    kept: tuple[int, ...] = ()

    def column(self, name: str, idx: Sequence[int]) -> np.ndarray:
        """Log column ``name`` of the members ``idx`` (kept ones), ``(len(idx), n_ticks)``."""
        row = {k: j for j, k in enumerate(self.kept)}
        missing = [k for k in idx if k not in row]
        if missing:
            raise KeyError(f"{name!r} was not kept for members {missing}")
        return self.columns[name][[row[k] for k in idx]]

    def select(self, **match: Any) -> list[int]:
        """Indices of the members whose attributes equal ``match``."""
        return [
            k
            for k, m in enumerate(self.members)
            if all(getattr(m, name) == value for name, value in match.items())
        ]

    @functools.cached_property
    def _copies(self) -> dict[tuple[Motor, str, str | None], list[int]]:
        # (motor, gains, effect) -> the indices of its noise copies: the tables of a full
        # study look up thousands of members' copies (a scan each would be quadratic)
        out: dict[tuple[Motor, str, str | None], list[int]] = {}
        for k, m in enumerate(self.members):
            out.setdefault((m.motor, m.gains, m.effect), []).append(k)
        return out

    def copies_of(self, k: int) -> list[int]:
        """Member ``k`` and its noise copies (the same motor, gains and effect), in order."""
        m = self.members[k]
        return self._copies[(m.motor, m.gains, m.effect)]

    def values(self, metric: str, idx: Sequence[int]) -> list[float]:
        return [self.metrics[k][metric] for k in idx]


def run_study(
    name: str,
    exp: Experiment,
    members: Sequence[Member],
    metric: Callable[[RunLog], dict[str, float]],
    *,
    seed: int = 0,
    keep: Sequence[str] = (),
    keep_for: Callable[[Member], bool] | None = None,
    tuned: Mapping[tuple[Motor, str], Mapping[str, float]] | None = None,
) -> Study:
    """Re-tune what ``members`` need (:func:`retune`, once per motor and kind), run them
    (:func:`iter_members`) and measure each with ``metric``; the log columns ``keep`` of
    the members for which ``keep_for`` holds (all by default) are kept."""
    wall0 = time.perf_counter()
    tuned = dict(tuned or {})
    for m in members:
        if (m.motor, m.gains) not in tuned:
            tuned[(m.motor, m.gains)] = retune(exp.bench, m.motor, m.gains, seed=seed)
    kept = tuple(k for k, m in enumerate(members) if keep_for is None or keep_for(m))
    row = {k: j for j, k in enumerate(kept)}
    metrics: list[dict[str, float]] = [{}] * len(members)
    cols: dict[str, np.ndarray] = {}
    t_s = np.zeros(0)
    for k, log in iter_members(exp, members, tuned, seed=seed):
        metrics[k] = {**metric(log), **first_fault(log)}
        t_s = log.t_s
        if k in row:
            for c in keep:
                if c not in cols:
                    cols[c] = np.empty((len(kept), log.t_s.size))
                cols[c][row[k]] = getattr(log, c)
    return Study(name, tuple(members), tuple(metrics), t_s, cols, time.perf_counter() - wall0, kept)


@dataclass(frozen=True)
class BandResult:
    """Fig. 6 over a motor design (:func:`fig6_band`)."""

    study: Study
    target_deg: float
    retune: str
    design: str
    effects_everywhere: bool

    @property
    def motors(self) -> tuple[Motor, ...]:
        return DESIGNS[self.design]()


def fig6_band_members(
    *,
    retune_how: str = "classic",
    design: str = "composite",
    noise_copies: int = 3,
    effects_everywhere: bool = False,
) -> list[Member]:
    """The members of the Fig. 6 band: every motor of ``design`` with fixed gains, with the
    firmware model of its motor, and re-tuned by ``retune_how``; every effect on the nominal
    motor with fixed gains, or (``effects_everywhere``) on every motor, fixed and re-tuned.
    Each of them in ``noise_copies`` noise realisations (copies 0 .. n - 1; copy 0 first):
    every number of the band is a per-motor mean ± sd, as the one-at-a-time variants'."""
    motors = DESIGNS[design]()
    kinds = ("fixed", "model", retune_how)
    members = [Member(m, g) for g in kinds for m in motors]
    if effects_everywhere:
        members += [Member(m, g, e) for e in EFFECTS for g in ("fixed", retune_how) for m in motors]
    else:
        members += [Member(Motor(), "fixed", e) for e in EFFECTS]
    return members + more_copies(members, noise_copies)


def is_variant(m: Member) -> bool:
    """One thing at a time off the nominal bench: one motor factor off nominal (no effect),
    or one effect on the nominal motor; fixed or re-tuned gains (the rows of REPORT.md's
    one-at-a-time tables)."""
    if m.gains == "model":
        return False
    if m.effect is None:
        return m.motor in one_at_a_time()
    return m.motor.nominal


def more_copies(
    members: Sequence[Member], noise_copies: int, which: Callable[[Member], bool] | None = None
) -> list[Member]:
    """Noise copies 1 .. ``noise_copies`` - 1 of the members (copy 0) among ``members`` for
    which ``which`` holds (all by default)."""
    return [
        dataclasses.replace(m, copy=c)
        for m in members
        if m.copy == 0 and (which is None or which(m))
        for c in range(1, noise_copies)
    ]


def fig6_band(
    *,
    retune_how: str = "classic",
    design: str = "composite",
    noise_copies: int = 3,
    effects_everywhere: bool = False,
    seed: int = 0,
    tuned: Mapping[tuple[Motor, str], Mapping[str, float]] | None = None,
) -> BandResult:
    """Fig. 6's step (``bench_configs/fig6.toml``, as written) over
    :func:`fig6_band_members`: one batch, plus one for the bus-model members."""
    from sim.reproduce.experiments import load
    from sim.reproduce.sensitivity import fig6_metrics

    exp = load("fig6")
    target = float(exp.commands[-1].get("target_mdeg")) / 1000.0
    limit = float(exp.bench.firmware.limits.current_limit_a)
    members = fig6_band_members(
        retune_how=retune_how,
        design=design,
        noise_copies=noise_copies,
        effects_everywhere=effects_everywhere,
    )
    study = run_study(
        "Fig. 6 without planning (step)",
        exp,
        members,
        lambda log: fig6_metrics(log, target, limit),
        seed=seed,
        keep=("pos_deg", "vel_dps"),
        keep_for=lambda m: m.copy == 0 and m.effect is None,  # what the figure draws
        tuned=tuned,
    )
    return BandResult(study, target, retune_how, design, effects_everywhere)


_COLOURS = {"fixed": "tab:red", "model": "tab:orange", "classic": "tab:blue", "de": "tab:green"}
_NAMES = {
    "fixed": "fixed gains (firmware as configured)",
    "model": "firmware model of its motor, config gains",
    "classic": "re-tuned: its motor's model + classic gains",
    "de": "re-tuned: its motor's model + DE-tuned gains",
}


def plot(band: BandResult, path: str | Path | None) -> Any:
    """The band figure: envelope and median over the motors of the axis velocity and of
    the position past the target, fixed gains against re-tuned gains; members that tripped
    a fault are drawn as thin lines, outside the envelope (returns the figure, saved to
    ``path`` if given)."""
    from matplotlib.figure import Figure

    st = band.study
    t = st.t_s
    fig = Figure(figsize=(11, 8), layout="constrained")
    ax_v, ax_p = fig.subplots(2, 1)
    nominal = st.select(motor=Motor(), gains="fixed", effect=None, copy=0)[0]
    for kind in ("fixed", band.retune):
        idx = st.select(gains=kind, effect=None, copy=0)
        ok = [k for k in idx if not tripped(st, k)]
        bad = [k for k in idx if k not in ok]
        over = per_motor(st, "overshoot (deg)", ok).means  # as section 8's table
        label = f"{_NAMES[kind]}: {len(ok)} motors, overshoot " + (
            f"{min(over):.0f}–{max(over):.0f}° (median {float(np.median(over)):.0f}°)"
            if over
            else "-"
        )
        colour = _COLOURS[kind]
        bad_label = f"{len(bad)} motors that tripped (in some realisation)"
        for ax, col, shift in ((ax_v, "vel_dps", 0.0), (ax_p, "pos_deg", band.target_deg)):
            if ok:
                y = st.column(col, ok) - shift
                ax.fill_between(t, y.min(axis=0), y.max(axis=0), color=colour, alpha=0.2, lw=0)
                ax.plot(t, np.median(y, axis=0), color=colour, lw=1.6, label=label)
            for j, k in enumerate(bad):
                ax.plot(
                    t, st.column(col, [k])[0] - shift, color=colour, lw=0.6, ls=":",
                    label=bad_label if j == 0 else None,
                )  # fmt: skip
    ax_p.plot(
        t, st.column("pos_deg", [nominal])[0] - band.target_deg, color="k", lw=0.8, ls="--",
        label="nominal motor, fixed gains (the reproduction's Fig. 6)",
    )  # fmt: skip
    peak, peak_sd, _, _ = spread(st.values("overshoot (deg)", st.copies_of(nominal)))
    ax_p.axhline(peak, color="k", lw=0.6, ls=":")
    ax_p.text(
        0.99, peak, f"nominal overshoot {peak:.1f} ± {peak_sd:.2g}° over "
        f"{len(st.copies_of(nominal))} noise realisations (the paper prints no number: "
        "\"large\")",
        transform=ax_p.get_yaxis_transform(), ha="right", va="bottom", fontsize=8,
    )  # fmt: skip
    ax_p.axhline(0.0, color="0.5", lw=0.6)
    notes = [
        f"{st.members[k].effect}: overshoot {{:.1f}} ± {{:.2g}}°".format(
            *_variant(st, "overshoot (deg)", k)
        )
        for k in st.select(motor=Motor(), gains="fixed", copy=0)
        if "bus" in (st.members[k].effect or "")
    ]
    if notes:
        ax_p.text(
            0.01, 0.97, "Not drawn (nominal motor, fixed gains):\n" + "\n".join(notes)
            + "\n(without a brake the bus locks the bridge out at 28 V while braking)",
            transform=ax_p.transAxes, va="top", fontsize=8,
            bbox={"facecolor": "white", "alpha": 0.8, "lw": 0.5},
        )  # fmt: skip
    ax_v.set_ylabel("axis velocity (°/s, firmware's estimate)")
    ax_p.set_ylabel(f"position − target {band.target_deg:g}° (axis °)")
    ax_v.set_xlabel("time (s)")
    ax_p.set_xlabel("time (s)")
    ax_v.legend(loc="upper right", fontsize=8)
    ax_p.legend(loc="upper right", fontsize=8)
    ax_p.set_xlim(2.5, t[-1])
    ax_p.set_ylim(-150.0, None)
    for ax in (ax_v, ax_p):
        ax.grid(alpha=0.3)
    what = {
        "factorial": "each ×0.7 / 1 / 1.3 (full 3³ factorial)",
        "composite": "×0.7 / 1.3 (face-centred composite: corners, face centres, nominal)",
    }[band.design]
    fig.suptitle(
        f"Fig. 6 (step S = 3e6 m°, no planning) over {len(band.motors)} motors: R, Kt = Ke, J "
        f"{what}\nbands: envelope of the motors that did not trip, thick lines: their median; "
        "positions in the firmware's frame\ncurves: noise realisation 0 of each motor; "
        f"numbers: each motor's mean over its {len(st.copies_of(nominal))} noise realisations",
        fontsize=10.5,
    )
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


# ------------------------------------------------------------------ the whole study


def effects_members(*, retune_how: str = "classic", noise_copies: int = 3) -> list[Member]:
    """One thing at a time: the bench in ``noise_copies`` noise realisations with fixed and
    re-tuned gains, each of R, Kt, J at x0.7 and x1.3 with fixed and re-tuned gains, each
    effect with fixed gains."""
    members = [Member(gains=g, copy=c) for g in ("fixed", retune_how) for c in range(noise_copies)]
    members += [Member(m, g) for m in one_at_a_time() for g in ("fixed", retune_how)]
    members += [Member(effect=e) for e in EFFECTS]
    return members + more_copies(members, noise_copies, is_variant)


@dataclass(frozen=True)
class SensitivityResult:
    """The Fig. 6 band and the one-at-a-time studies of Fig. 7 and Fig. 8."""

    band: BandResult
    studies: tuple[Study, ...]
    quick_forms: bool
    noise_copies: int
    wall_s: float


def default_noise_copies(full: bool = False) -> int:
    """Noise realisations of a run when none are asked for: 3, or 5 for the full study."""
    return 5 if full else 3


def run_sensitivity(
    *,
    quick: bool = False,
    full: bool = False,
    retune_how: str = "classic",
    noise_copies: int | None = None,
    seed: int = 0,
) -> SensitivityResult:
    """The Fig. 6 band (:func:`fig6_band`) and one-at-a-time studies of Fig. 7 (the move
    to S_1, from the interrupt on) and Fig. 8.

    Default (the cheap form ``reproduce`` runs): the composite design, effects on the
    nominal motor, 3 noise realisations, Fig. 7 and 8 in their ``--quick`` forms. ``full``
    (``reproduce --sensitivity``): the 3^3 factorial, every effect on every motor, 5 noise
    realisations, Fig. 7 and 8 as the reproduction runs them (``quick``: their quick
    forms). Each motor is re-tuned once; every study uses those gains."""
    from sim.reproduce.experiments import load, move_commands, scale_quick
    from sim.reproduce.sensitivity import fig8_metrics

    if retune_how not in ("classic", "de"):
        raise ValueError(f"retune = {retune_how!r}: must be 'classic' or 'de'")
    copies = default_noise_copies(full) if noise_copies is None else noise_copies
    if isinstance(copies, bool) or not isinstance(copies, int) or not 1 <= copies <= 64:
        raise ValueError(f"noise copies = {copies!r}: must be an integer in 1..64")
    wall0 = time.perf_counter()
    design = "factorial" if full else "composite"
    bench = load("fig6").bench
    kinds = ("fixed", "model", retune_how)
    tuned = {(m, g): retune(bench, m, g, seed=seed) for m in DESIGNS[design]() for g in kinds}
    band = fig6_band(
        retune_how=retune_how,
        design=design,
        noise_copies=copies,
        effects_everywhere=full,
        seed=seed,
        tuned=tuned,
    )
    quick_forms = quick or not full
    members = effects_members(retune_how=retune_how, noise_copies=copies)
    studies = []
    for name, file in (("Fig. 7 (S_1, case a)", "fig7"), ("Fig. 8 / Table 1", "fig8")):
        exp = load(file)
        if quick_forms:
            exp = scale_quick(exp)
        t_move = move_commands(exp)[-1][1].t_s if file == "fig7" else 0.0
        studies.append(
            run_study(
                name,
                exp,
                members,
                lambda log, t0=t_move: fig8_metrics(log, t0),
                seed=seed,
                tuned=tuned,
            )
        )
    return SensitivityResult(band, tuple(studies), quick_forms, copies, time.perf_counter() - wall0)


# ------------------------------------------------------------------ REPORT.md


def _cell(x: float, digits: int = 3) -> str:
    return "-" if math.isnan(x) else f"{x:.{digits}g}"


def _faults_by_name(st: Study, idx: list[int]) -> str:
    """`` (OVER_CURRENT 4, THERMAL 1)``: which first fault the members of ``idx`` tripped
    with, most frequent first ("" when none tripped)."""
    from collections import Counter

    from serial_protocol.messages import Fault

    names = Counter(
        Fault(int(st.metrics[k]["fault code"])).name for k in idx if st.metrics[k]["fault code"]
    )
    return f" ({', '.join(f'{n} {c}' for n, c in names.most_common())})" if names else ""


def _fault(metrics: Mapping[str, float]) -> str:
    from serial_protocol.messages import Fault

    code = int(metrics["fault code"])
    if not code:
        return "none"
    return f"{Fault(code).name} at {metrics['fault at (s)']:.3f} s"


def _base(st: Study, metric: str, gains: str) -> tuple[float, float]:
    """Mean and standard deviation of ``metric`` over the noise realisations of the nominal
    member with ``gains``."""
    mean, sd, _, _ = spread(st.values(metric, st.select(motor=Motor(), gains=gains, effect=None)))
    return mean, sd


def _variant(st: Study, metric: str, k: int) -> tuple[float, float]:
    """Mean and standard deviation of ``metric`` over member ``k``'s noise copies (NaN
    where none has a value; sd 0 for one)."""
    mean, sd, _, _ = spread(st.values(metric, st.copies_of(k)))
    return mean, sd


def _pm(mean: float, sd: float, n: int) -> str:
    """``mean ± sd`` of a variant's ``n`` noise copies (the mean alone for one)."""
    return _cell(mean, 4) if n < 2 or math.isnan(mean) else f"{_cell(mean, 4)} ± {_cell(sd, 2)}"


def _moves(v: float, mean: float, sd: float) -> bool:
    """Beyond the noise: more than 3 standard deviations (``sd``: the variant's and the
    nominal's noise together) and more than 2 % of the nominal value (or defined for one
    of the two only)."""
    if math.isnan(v) or math.isnan(mean):
        return math.isnan(v) != math.isnan(mean)
    return abs(v - mean) > max(3.0 * sd, 0.02 * abs(mean), 1e-12)


def _beyond(st: Study, metric: str, k: int) -> tuple[float, float, float, float, bool]:
    """Variant ``k`` against the nominal member with its gains: (variant mean, sd, nominal
    mean, sd, whether it moves beyond the noise)."""
    v, v_sd = _variant(st, metric, k)
    mean, sd = _base(st, metric, st.members[k].gains)
    return v, v_sd, mean, sd, _moves(v, mean, math.hypot(sd, v_sd))


def _fault_copies(st: Study, k: int) -> str:
    """The first fault of member ``k``'s copies (with in how many, if not in all)."""
    idx = st.copies_of(k)
    tripped = [j for j in idx if st.metrics[j]["fault code"]]
    if not tripped:
        return "none"
    text = _fault(st.metrics[tripped[0]])
    return text if len(tripped) == len(idx) else f"{text} (in {len(tripped)} of {len(idx)})"


def _oat_rows(st: Study, headline: str) -> list[int]:
    """The one-at-a-time members (one motor factor off nominal, or one effect on the
    nominal motor), largest change of ``headline`` first (trips first of all)."""
    rows = [k for k, m in enumerate(st.members) if m.copy == 0 and is_variant(m)]

    def size(k: int) -> float:
        mean, _ = _base(st, headline, st.members[k].gains)
        v, _ = _variant(st, headline, k)
        if tripped(st, k) or math.isnan(v) or math.isnan(mean):
            return math.inf
        return abs(v - mean) / max(abs(mean), 1e-12)

    return sorted(rows, key=size, reverse=True)


def _study_table(st: Study, metrics: Sequence[str], rows: Sequence[int]) -> list[str]:
    head = ["variant", "gains", *metrics, "first fault"]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    kinds = sorted({st.members[k].gains for k in rows}, key=GAINS.index)
    for kind in kinds:
        n = len(st.select(motor=Motor(), gains=kind, effect=None))
        cells = []
        for m in metrics:
            mean, sd = _base(st, m, kind)
            cells.append(f"{_cell(mean, 4)} ± {_cell(sd, 2)}")
        out.append(f"| nominal ({n} noise realisations: mean ± sd) | {kind} | "
                   + " | ".join(cells) + " | none |")  # fmt: skip
    for k in rows:
        mem = st.members[k]
        n = len(st.copies_of(k))
        cells = []
        for m in metrics:
            v, v_sd, mean, _, moves = _beyond(st, m, k)
            rel = ""
            tripped = bool(st.metrics[k]["fault code"])  # the fault column says why
            if not (tripped or math.isnan(v) or math.isnan(mean)) and mean != 0.0:
                rel = f" ({100.0 * (v - mean) / abs(mean):+.0f} %)"
            star = "**" if moves else ""
            cells.append(f"{star}{_pm(v, v_sd, n)}{rel}{star}")
        out.append("| " + " | ".join([mem.label, mem.gains, *cells, _fault_copies(st, k)]) + " |")
    return out + [""]


def _summary(st: Study, metric: str, rows: Sequence[int], top: int = 5) -> str:
    """One sentence: what moves ``metric`` most (each against the nominal member with the
    same gains), what trips, what stays within the noise."""
    moved, trips, quiet = [], [], []
    for k in rows:
        mem = st.members[k]
        name = mem.label + ("" if mem.gains == "fixed" else f" ({mem.gains} gains)")
        v, _, mean, _, moves = _beyond(st, metric, k)
        if st.metrics[k]["fault code"]:
            trips.append(f"{name} ({_fault_copies(st, k)})")
        elif moves:
            moved.append(f"{name} {_cell(mean, 3)} → {_cell(v, 3)}")
        else:
            quiet.append(name)
    mean, sd = _base(st, metric, "fixed")
    text = f"**{metric}** (nominal {_cell(mean, 4)} ± {_cell(sd, 2)}): "
    text += "moved most by " + ("; ".join(moved[:top]) if moved else "nothing")
    if len(moved) > top:
        text += f" (and {len(moved) - top} more in the table)"
    text += ". "
    if trips:
        text += "Trips: " + "; ".join(trips) + ". "
    text += "Within the noise (or 2 %): " + (", ".join(quiet) if quiet else "nothing") + "."
    return text


def tripped(st: Study, k: int) -> bool:
    """Whether any noise realisation of member ``k`` tripped a fault."""
    return any(st.metrics[j]["fault code"] for j in st.copies_of(k))


@dataclass(frozen=True)
class PerMotor:
    """A metric of one motor per member over their noise realisations (:func:`per_motor`):
    ``means`` and ``sds`` (standard deviations) of the motors where it is defined in at
    least one realisation; ``undefined`` of the ``realisations`` in all had it undefined
    (NaN: e.g. not settled by the end of the run)."""

    means: list[float]
    sds: list[float]
    undefined: int
    realisations: int
    #: the most realisations any motor has the metric defined in (< 2: no noise spread)
    most_defined: int = 0

    def over_motors(self) -> str:
        """``median (min–max)`` of the per-motor means, and the realisations left out."""
        m = self.means
        if not m:
            return "-"
        text = f"{_cell(float(np.median(m)), 4)} ({_cell(min(m))}–{_cell(max(m))})"
        if self.undefined:
            text += f" [undefined in {self.undefined} of {self.realisations} realisations]"
        return text

    def over_noise(self) -> str:
        """``median (largest)`` of the per-motor standard deviations over the noise ("-"
        when no motor has two realisations to spread)."""
        if not self.sds or self.most_defined < 2:
            return "-"
        return f"{_cell(float(np.median(self.sds)), 2)} ({_cell(max(self.sds), 2)})"


def per_motor(st: Study, metric: str, idx: Sequence[int]) -> PerMotor:
    """``metric`` of the members ``idx`` (copy 0 of each; one per motor) over their noise
    realisations."""
    means, sds, undefined, n, most = [], [], 0, 0, 0
    for k in idx:
        vals = st.values(metric, st.copies_of(k))
        n += len(vals)
        nan = sum(math.isnan(v) for v in vals)
        undefined += nan
        most = max(most, len(vals) - nan)
        mean, sd, _, _ = spread(vals)
        if not math.isnan(mean):
            means.append(mean)
            sds.append(sd)
    return PerMotor(means, sds, undefined, n, most)


def _trips(st: Study, idx: Sequence[int]) -> tuple[list[int], str]:
    """The members of ``idx`` (one per motor) none of whose realisations tripped, and the
    text ``"1 of 15 (Kt×0.7: OVER_CURRENT at 3.258 s (in 2 of 3))"`` for the others."""
    ok = [k for k in idx if not tripped(st, k)]
    bad = [k for k in idx if k not in ok]
    names = "; ".join(f"{st.members[k].motor.label}: {_fault_copies(st, k)}" for k in bad)
    return ok, f"{len(bad)} of {len(idx)}" + (f" ({names})" if names else "")


def _band_table(b: BandResult, metrics: Sequence[str]) -> list[str]:
    """Per gains: the motors that tripped, then two rows over the motors that did not:
    the spread over motors of the per-motor means, and the spread the noise makes (the
    per-motor standard deviations)."""
    st = b.study
    head = ["gains", "tripped", "spread", *metrics]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for kind in ("fixed", "model", b.retune):
        ok, trip_txt = _trips(st, st.select(gains=kind, effect=None, copy=0))
        motors, noise = [], []
        for m in metrics:
            pm = per_motor(st, m, ok)
            motors.append(pm.over_motors())
            noise.append(pm.over_noise())
        out.append("| " + " | ".join([kind, trip_txt, "motors", *motors]) + " |")
        out.append("| " + " | ".join([kind, "", "noise", *noise]) + " |")
    return out + [""]


def _noisiest(st: Study, metric: str, kinds: Sequence[str]) -> list[str]:
    """One sentence: the motor of the band (no effect; gains ``kinds``; not tripped) whose
    ``metric`` the noise moves most, with its realisations' mean ± sd and range."""
    idx = [k for g in kinds for k in st.select(gains=g, effect=None, copy=0) if not tripped(st, k)]
    spreads = {k: spread(st.values(metric, st.copies_of(k))) for k in idx}
    spreads = {k: v for k, v in spreads.items() if not math.isnan(v[1])}
    if not spreads:
        return []
    k = max(spreads, key=lambda j: spreads[j][1])
    mean, sd, lo, hi = spreads[k]
    m = st.members[k]
    return [
        f"Where the noise matters most: the {metric.split(' (')[0]} of {m.motor.label} with "
        f"{m.gains} gains, {_cell(mean, 4)} ± {_cell(sd, 2)} ({_cell(lo, 4)}–{_cell(hi, 4)}) over "
        f"its {len(st.copies_of(k))} realisations.",
        "",
    ]


def _effects_everywhere_table(b: BandResult) -> list[str]:
    """Per effect, the overshoot over every motor (fixed and re-tuned): per-motor means
    over the noise realisations, and the noise's per-motor standard deviations."""
    st = b.study
    head = ["effect"] + [
        f"{g}: tripped; overshoot (deg) over motors, median (min–max); noise sd, median (largest)"
        for g in ("fixed", b.retune)
    ]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for effect in (None, *EFFECTS):
        cells = []
        for kind in ("fixed", b.retune):
            idx = st.select(gains=kind, effect=effect, copy=0)
            ok = [k for k in idx if not tripped(st, k)]
            # each tripped motor named by its first realisation that tripped
            bad = [
                next(j for j in st.copies_of(k) if st.metrics[j]["fault code"])
                for k in idx
                if k not in ok
            ]
            pm = per_motor(st, "overshoot (deg)", ok)
            txt = f"{len(idx) - len(ok)} of {len(idx)}{_faults_by_name(st, bad)}; "
            txt += f"{pm.over_motors()}; noise sd {pm.over_noise()}"
            cells.append(txt)
        out.append("| " + " | ".join([effect or "none (the bench)", *cells]) + " |")
    return out + [""]


FIG6_METRICS = (
    "braking from (s)",
    "overshoot (deg)",
    "overshoot at (s)",
    "settled within 0.1 deg at (s)",
    "peak current (A)",
)
TRACKING_METRICS = ("max following error (deg)", "max velocity error (deg/s)", "peak current (A)")


def report_lines(res: SensitivityResult, section: int = 8) -> list[str]:
    """REPORT.md's section on what moves each figure, from the runs of ``res``."""
    b = res.band
    st = b.study
    how = {
        "classic": "the tuner's classic baseline (`sim.tuning.baselines.classic`: analytic)",
        "de": "the tuner's differential evolution (`sim.tuning.optimise.tune`, its default "
        "scenario and settings, started from the classic gains)",
    }[b.retune]
    lines = [
        f"## {section}. Which effects and parameters matter, per figure (issue 13 §3)",
        "",
        "The paper gives no motor data; `[motor]` holds assumed values. Each figure's "
        "experiment was run over a spread of them and with the plant effects of docs/model.md "
        "switched on one at a time, every member of an experiment in one lock-step batch "
        "(`sim.reproduce.band`; the bus-model members in a batch of their own). Gains: "
        "**fixed** = the firmware as configured (feed-forward model of the nominal motor, "
        "the config's gains); **model** = the feed-forward model of the member's own motor "
        f"(R, back-EMF, inertia), the config's gains; **{b.retune}** = that model and the "
        f"gains re-tuned for the member's motor by {how}. Each variant is compared with the "
        "nominal motor under the same gains. Error bars: every member (each motor of the "
        f"band, the nominal, every variant) runs in {res.noise_copies} noise realisations "
        "(every member of a batch draws its own encoder noise). In the one-at-a-time "
        "tables a cell is the member's mean ± standard deviation over them (a value "
        "without ± is NaN in some realisations, e.g. after a trip); the band tables keep "
        "the spread over motors and the spread over noise apart (below). **Bold**: the "
        "variant's mean differs from the nominal's by more than 3 standard deviations (the "
        "two spreads together) and 2 %. "
        + (
            "Fig. 7 and Fig. 8 ran in their --quick form (times / 4: positions / 16, "
            "velocities / 4), Fig. 6 as written. "
            if res.quick_forms
            else ""
        )
        + f"All runs of this section: {res.wall_s:.1f} s of wall time"
        + (
            "; `turntable-sim reproduce --sensitivity` runs the full study (27 motors, every "
            "effect on every motor)."
            if b.design != "factorial"
            else "."
        ),
        "",
        f"### Fig. 6 without planning: a band over {len(b.motors)} motors",
        "",
        {
            "factorial": "R, Kt (= Ke) and J each at ×0.7, ×1 and ×1.3: the full 3³ factorial.",
            "composite": "R, Kt (= Ke) and J at ×0.7 and ×1.3: a face-centred composite "
            "design (the nominal motor, the 8 corners of the box and its 6 face centres, "
            "i.e. each factor alone).",
        }[b.design]
        + " Why not a Latin hypercube of the same size: a band is an envelope, and for "
        "responses monotone in each factor the extremes sit at the corners, which these "
        "designs contain and a hypercube almost never does. Each motor ran in "
        f"{res.noise_copies} noise realisations; a motor that tripped in any of them is "
        "counted under *tripped* (with the realisations it tripped in) and left out of the "
        "two rows of numbers, which are over the others: **motors** = the median (min–max) "
        "over motors of each motor's mean over its realisations, the spread the motor "
        "parameters make; **noise** = the median (largest) over the same motors of each "
        "motor's standard deviation over its realisations, the spread the encoder noise "
        "makes. A realisation where a number is undefined (e.g. not settled by the end of "
        "the run) is left out of its motor's mean (a motor where it is undefined in all "
        "is left out) and counted in the cell.",
        "",
    ]
    lines += _band_table(b, FIG6_METRICS)
    lines += _noisiest(st, "overshoot (deg)", ("fixed", "model", b.retune))
    fixed = st.select(gains="fixed", effect=None, copy=0)
    retuned = st.select(gains=b.retune, effect=None, copy=0)

    def over(idx: list[int]) -> str:  # the per-motor means' range
        ok = [k for k in idx if not tripped(st, k)]
        means = per_motor(st, "overshoot (deg)", ok).means
        trips = len(idx) - len(ok)
        return f"{_cell(min(means))}–{_cell(max(means))} deg ({trips} tripped)" if means else "-"

    lines += [
        "![Fig. 6 band](fig6_band.png)",
        "",
        f"What re-tuning buys: with the firmware fixed the step's overshoot spans "
        f'{over(fixed)}; re-tuned for each motor, {over(retuned)}. The row "model" '
        "separates the two parts: most of it is the firmware's feed-forward model (R, "
        "back-EMF and inertia, which also set its regenerative clamp), not the feedback "
        "gains. What no re-tune removes: the position loop starts braking v_max / Kp before "
        "the target and asks for more deceleration than the motor gives at 5 A (Kt / J), so "
        "the step overshoots by an amount set by the motor; the planned move does not.",
        "",
    ]
    if b.effects_everywhere:
        lines += ["Every effect on every motor (Fig. 6 step):", ""]
        lines += _effects_everywhere_table(b)
    lines += ["One thing at a time:", ""]
    rows = _oat_rows(st, "overshoot (deg)")
    lines += _study_table(st, FIG6_METRICS, rows)
    for m in ("overshoot (deg)", "braking from (s)"):
        lines += [_summary(st, m, rows), ""]
    bus = [
        k
        for k in st.select(motor=Motor(), gains="fixed", copy=0)
        if st.members[k].effect == "bus model, 2,200 µF, no brake"
    ]
    if bus:
        lines += [
            "The bus model without a brake chopper **locks the bridge out** (28 V) during "
            "the braking: the step overshoots by "
            f"{_pm(*_variant(st, 'overshoot (deg)', bus[0]), len(st.copies_of(bus[0])))} "
            "deg. That is the bus model's verdict on a bench without a brake resistor, not "
            'a numerical artefact; the paper shows no brake. docs/model.md ("Supply and '
            "bus\") has the runs with a chopper and with the firmware's regenerative limit.",
            "",
        ]
    for sub in res.studies:
        rows = _oat_rows(sub, "max following error (deg)")
        lines += [f"### {sub.name}", ""]
        lines += _study_table(sub, TRACKING_METRICS, rows)
        for m in ("max following error (deg)", "peak current (A)"):
            lines += [_summary(sub, m, rows), ""]
    return lines
