"""The board's motion-program queue (issue #14 §1): segments with look-ahead, as grbl's.

The PC appends blocks ``(target_deg, v_max_dps, dwell_s)``; the board keeps at most
``capacity`` of them (those not finished) and plans their junction speeds with seed 001's
streaming look-ahead, :class:`planner.lookahead.LookaheadQueue` (the one implementation):
every time a block is appended, the blocks not yet entered are replanned as if the path
stopped at the end of what the queue holds, so the axis can always stop there (an underrun
is a planned deceleration to rest at the last queued target, never an overshoot).
Same-direction junctions are passed at speed; a reversal or a dwell is a junction at rest.

A block is *committed* when the axis enters it (or the look-ahead declares its speeds
final). An append replans the rest of the block in progress from the commanded position and
speed at that instant (as grbl replans its executing block) when its end speed is still the
queue's final stop; every other committed block keeps its profile. So a replan never makes
the setpoint jump in position or velocity.
What the axis follows is one piecewise-polynomial :class:`planner.profile.Profile` (the
committed blocks, the dwells, then the pending blocks as planned): the same setpoint source
as a ``Move``, which the compiled tick evaluates from its phase arrays.

Feed hold is the board's Stop from the program's commanded state (the queue is kept);
resume replans what was not reached from where the axis stopped. Abort stops and empties
the queue. The speed override (percent, as grbl's) scales the speed limit of the blocks not entered
and of the rest of the block in progress, at once (docs/protocol.md section 4.5).

Everything here is pure bookkeeping: no I/O, no exceptions escape to the board (the firmware
checks the command fields before calling, see ``Firmware._cmd_queue_segment``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from planner.lookahead import LookaheadQueue
from planner.profile import Profile

__all__ = ["ProgramQueue", "QUEUE_CAPACITY"]

#: Blocks the board holds (grbl holds 16 planner blocks; this is the Hello-announced size).
QUEUE_CAPACITY = 32
# Same-position test for a block of zero length (deg).
_EPS_DEG = 1e-9


@dataclass
class _Block:
    """A committed block: the arc-length profile from ``p_start`` along ``direction``
    (+1 / -1; 0 for a dwell only), starting at board time ``t_start_s``, then a dwell."""

    t_start_s: float
    p_start: float
    direction: float
    profile: Profile | None
    dwell_s: float
    target_deg: float
    v_max_dps: float

    @property
    def t_move_end_s(self) -> float:
        return self.t_start_s + (self.profile.duration if self.profile is not None else 0.0)

    @property
    def t_end_s(self) -> float:
        return self.t_move_end_s + self.dwell_s


class ProgramQueue:
    """The board's queue of program blocks; see the module docstring.

    Args:
        capacity: the most unfinished blocks held (>= 16).
        period_s: the servo period (the look-ahead's interpolation period).
    """

    def __init__(self, capacity: int = QUEUE_CAPACITY, period_s: float = 0.002) -> None:
        self.capacity = capacity
        self.period_s = period_s
        self.override_pct = 100.0
        self.done = 0  # blocks finished since boot (a u32 on the wire, wraps)
        self._clear()

    def _clear(self) -> None:
        self._la: LookaheadQueue | None = None
        self._committed: deque[_Block] = deque()
        self._pending: deque[list[float]] = deque()  # [target, v_max (unscaled), dwell]
        self._limits = (0.0, 0.0)  # v_max, a_max of the look-ahead
        self.held = False
        self._held_rest: list[tuple[float, float, float]] = []

    # ------------------------------------------------------------------ state
    def active(self) -> bool:
        """True while blocks are held (running, held or stopping)."""
        return bool(self._committed or self._pending or self.held)

    def finish(self, t_s: float) -> None:
        """Forget the committed blocks finished by ``t_s`` (counted in ``done``)."""
        if self._la is not None and not self.held:
            self._commit_started(t_s)
        while self._committed and self._committed[0].t_end_s <= t_s and not self.held:
            self._committed.popleft()
            self.done += 1
        if not self.held and not self._pending and not self._committed:
            self._la = None

    def queued(self, t_s: float) -> int:
        """Blocks held and not finished at ``t_s``."""
        self.finish(t_s)
        if self.held:
            return len(self._held_rest)
        return len(self._committed) + len(self._pending)

    def free(self, t_s: float) -> int:
        return max(0, self.capacity - self.queued(t_s))

    def clear(self) -> None:
        """Abort: drop every block (the caller has stopped the axis)."""
        self._clear()

    # ------------------------------------------------------------------ append
    def append(
        self,
        t_s: float,
        p_deg: float,
        target_deg: float,
        v_max_dps: float,
        dwell_s: float,
        *,
        v_limit_dps: float,
        a_max_dps2: float,
    ) -> Profile:
        """Append one block at board time ``t_s``; returns the program's profile from the
        start of the first unfinished block (its start time is :attr:`t_start_s`).

        ``p_deg`` is where the axis rests if the queue is empty (the start of the path).
        The caller has checked the fields and that there is a free slot.
        """
        self.finish(t_s)
        if self.held:
            self._held_rest.append((target_deg, v_max_dps, dwell_s))
            return self.profile
        if self._la is None:
            self._start(t_s, p_deg, v_limit_dps, a_max_dps2)
        self._commit_started(t_s)
        self._reopen_current(t_s)
        self._add(target_deg, v_max_dps, dwell_s, t_s)
        return self._build(t_s)

    def _start(self, t_s: float, p_deg: float, v_limit: float, a_max: float) -> None:
        self._limits = (v_limit, a_max)
        self._la = LookaheadQueue(
            p_deg, v_max=v_limit, a_max=a_max, period=self.period_s, window=self.capacity
        )
        self._t_next_s = t_s  # where the next committed block starts
        self._p_next = p_deg

    def _scaled(self, v_max: float) -> float:
        return min(v_max * self.override_pct / 100.0, self._limits[0])

    def _add(self, target: float, v_max: float, dwell: float, t_s: float) -> None:
        la = self._la
        assert la is not None
        last = float(la.end_point[0])
        if abs(target - last) <= _EPS_DEG:
            # No motion: a dwell at the last point (the pending block's, or a block of its
            # own after the committed ones, which end at rest when nothing is pending).
            if self._pending:
                self._pending[-1][2] += dwell
                self._rebuild_pending()
            else:
                t0 = max(self._t_next_s, t_s)
                self._committed.append(_Block(t0, last, 0.0, None, dwell, target, v_max))
                self._t_next_s = t0 + dwell
            return
        self._pending.append([target, v_max, dwell])
        for seg in la.append(target, v_max=self._scaled(v_max), stop=dwell > 0.0):
            self._commit(seg)  # a full window (the board's capacity check prevents it)
        for seg in la.pop_ready():
            self._commit(seg)

    def _rebuild_pending(self) -> None:
        """Replan the pending blocks (after their dwell or speed changed): a fresh
        look-ahead from the end of the committed blocks, which end at the speed the old one
        started the pending blocks with."""
        la = self._la
        assert la is not None
        v_in = la.v_in
        rest = list(self._pending)
        self._la = LookaheadQueue(
            self._p_next, v_max=self._limits[0], a_max=self._limits[1], period=self.period_s,
            window=self.capacity,
        )  # fmt: skip
        self._la.v_in = v_in
        self._pending.clear()
        for target, v_max, dwell in rest:
            self._la.append(target, v_max=max(self._scaled(v_max), v_in), stop=dwell > 0.0)
            v_in = 0.0
            self._pending.append([target, v_max, dwell])

    def _reopen_current(self, t_s: float) -> None:
        """Replan the rest of the block in progress from the commanded state at ``t_s``
        if it is the last committed one (its end speed is then the stop at the end of the
        queue, which what follows may raise; as grbl replans its executing block)."""
        if not self._committed:
            return
        last = self._committed[-1]
        if last.profile is None or last.dwell_s > 0.0:
            return  # a dwell ends at rest whatever follows
        if not last.t_start_s < t_s < last.t_move_end_s:
            return
        s, ds, _ = last.profile.at(t_s - last.t_start_s)
        if last.profile.p1 - float(s) <= _EPS_DEG:
            return
        self._committed.pop()
        la = self._la
        assert la is not None
        self._p_next = last.p_start + last.direction * float(s)
        self._t_next_s = t_s
        la.v_in = max(0.0, float(ds))
        self._pending.appendleft([last.target_deg, last.v_max_dps, 0.0])
        self._rebuild_pending()

    def _commit(self, seg: object) -> None:
        target, v_max, dwell = self._pending.popleft()
        prof = seg.profile  # type: ignore[attr-defined]
        direction = float(seg.direction[0])  # type: ignore[attr-defined]
        block = _Block(self._t_next_s, self._p_next, direction, prof, dwell, target, v_max)
        self._committed.append(block)
        self._t_next_s = block.t_end_s
        self._p_next = target

    def _commit_started(self, t_s: float) -> None:
        """Commit the pending blocks the axis has entered by ``t_s`` (their planned
        profiles are what it follows; later appends must not change them)."""
        la = self._la
        assert la is not None
        if not self._pending:
            return
        t = self._t_next_s
        count = 0
        for prof, (_, _, dwell) in zip(la.preview(), self._pending, strict=True):
            if t >= t_s:
                break  # not entered yet: its start state is fixed, the rest may change
            count += 1
            t += prof.duration + dwell
        for seg in la.release(count):
            self._commit(seg)

    # ------------------------------------------------------------------ the profile
    def _build(self, t_s: float) -> Profile:
        """The committed blocks, then the pending ones as planned, as one profile."""
        la = self._la
        assert la is not None
        t0s: list[float] = []
        ps: list[float] = []
        vs: list[float] = []
        accs: list[float] = []
        js: list[float] = []
        blocks: list[tuple[float, float, Profile | None, float, float]] = [
            (b.p_start, b.direction, b.profile, b.dwell_s, b.target_deg) for b in self._committed
        ]
        p = self._p_next
        for prof, (target, _, dwell) in zip(la.preview(), self._pending, strict=True):
            blocks.append((p, 1.0 if target > p else -1.0, prof, dwell, target))
            p = target
        t_first = self._committed[0].t_start_s if self._committed else self._t_next_s
        t = 0.0
        p_end = self._p_next if not blocks else p
        for p_start, d, prof, dwell, target in blocks:
            if prof is not None:
                for k in range(len(prof.t0)):
                    t0s.append(t + prof.t0[k])
                    ps.append(p_start + d * prof.p[k])
                    vs.append(d * prof.v[k])
                    accs.append(d * prof.a[k])
                    js.append(d * prof.j[k])
                t += prof.duration
                p_start = target  # exactly (not start + length, which rounds)
            if dwell > 0.0:
                t0s.append(t)
                ps.append(p_start)
                vs.append(0.0)
                accs.append(0.0)
                js.append(0.0)
                t += dwell
            p_end = p_start
        p0 = ps[0] if ps else p_end
        self.t_start_s = t_first
        self.profile = Profile(
            "trapezoid", "program", tuple(t0s), tuple(ps), tuple(vs), tuple(accs), tuple(js),
            t, p0, vs[0] if vs else 0.0, accs[0] if accs else 0.0, p_end, 0.0,
        )  # fmt: skip
        return self.profile

    # ------------------------------------------------------------------ hold / resume
    def hold(self, t_s: float, p_stop_deg: float) -> None:
        """Feed hold at ``t_s``; the axis stops at ``p_stop_deg`` (the caller's stop plan).
        The blocks not reached are kept for :meth:`resume`."""
        self.finish(t_s)
        if self.held or self._la is None:
            return
        rest: list[tuple[float, float, float, float]] = []  # target, v, dwell, direction
        for b in self._committed:
            if b.t_end_s > t_s:
                rest.append((b.target_deg, b.v_max_dps, b.dwell_s, b.direction))
        p = self._p_next
        for target, v_max, dwell in self._pending:
            rest.append((target, v_max, dwell, 1.0 if target > p else -1.0))
            p = target
        # Drop the blocks the stop ran through (same-direction junctions passed at speed);
        # a block with a dwell is kept (its target is then reached, the dwell is still due).
        kept: list[tuple[float, float, float]] = []
        dropping = True
        for target, v_max, dwell, d in rest:
            if dropping and dwell == 0.0 and d != 0.0 and (target - p_stop_deg) * d <= _EPS_DEG:
                self.done += 1
                continue
            dropping = False
            kept.append((target, v_max, dwell))
        self._committed.clear()
        self._pending.clear()
        self._la = None
        self.held = True
        self._held_rest = kept

    def resume(self, t_s: float, p_deg: float) -> Profile | None:
        """Replan the held blocks from rest at ``p_deg``; None if nothing is left."""
        rest = self._held_rest
        limits = self._limits
        self._clear()
        if not rest:
            return None
        self._start(t_s, p_deg, *limits)
        for target, v_max, dwell in rest:
            self._add(target, v_max, dwell, t_s)
        return self._build(t_s)

    def set_override(self, t_s: float, pct: float) -> Profile | None:
        """Speed override in percent: the pending blocks are replanned at once (returns
        the new profile), committed blocks keep theirs."""
        self.override_pct = float(pct)
        if self.held or self._la is None or not self._pending:
            return None
        self.finish(t_s)
        self._commit_started(t_s)
        self._reopen_current(t_s)
        if not self._pending:
            return None
        self._rebuild_pending()
        return self._build(t_s)
