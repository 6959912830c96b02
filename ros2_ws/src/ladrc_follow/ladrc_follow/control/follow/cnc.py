"""The CNC's partner: what the CNC reports and commands, what the controller answers it.

docs/interfaces.md, "CNC interface".

The CNC reports its path state every cycle (``CncMotion``: segment kind, beam, commanded and
actual feed, distance to the segment's end and to the outline or a kerf ahead); it commands a
pierce sequence, a lift and a hold (follow commands ``pierce``, ``lift``, ``hold``). The
controller answers in ``FollowStatus``: ``in_position`` (XY may start), ``ready_to_move``, a
feed-hold request, and the sub-state that holds or shapes its command with the reason.

:class:`CncPartner` judges; the machine (:mod:`.machine`) acts: a *hold* is the edge guard's
hold (the law keeps running, its observer fed the applied command, and only a command away
from the sheet passes), a *lift* a planned move up that overrides the law, a pierce stage a
change of the target. The anchors (plasmac ``plasmac.comp``, Beckhoff TF5200/TF5290, CypCut):

* corner lock: hold while the actual feed is below ``corner_lock_ratio`` x the commanded one,
  release above ``corner_unlock_ratio`` (plasmac ``cornerlock_threshold``, with hysteresis);
* edge ahead: hold from ``edge_ahead_hold_mm`` before the outline or a kerf the CNC reports
  until ``edge_release_mm`` of path after it (a partly covered sensor reads too wide);
* a stale CNC (no motion sample for ``stale_timeout_s`` once one came) holds: nothing it
  reported can be judged any more; silent for ``stale_lift_s`` while following, the CNC is
  gone: the head is lifted by ``stale_lift_mm`` (a planned move up) and held there;
* pierce: each stage height approached, in position, dwelled at; then the cut gap, in position,
  and the THC delay (held) before the follow closes in (plasmac pierce delay / THC delay);
* a locked pierce (a contour smaller than the sensor's field, the CNC's call: plasmac's hole
  sensing, a laser control's "no follow for small contours"): the stages and the cut gap are
  heights above the sheet level followed last (encoder − gap), reached and held by the encoder,
  no capacitive following, until the CNC's next command; a valid reading nearer than planned
  (a sheet higher there) raises the level, never lowers it (:class:`_Locked`);
* a CNC that moves XY before the pierce is complete is asked to hold its feed, with the reason;
* adaptive feed: while cutting and followed, a gap more than ``feed_override_error`` x the
  target below the target asks for less feed (``feed_override_request``), down to
  ``feed_override_min`` at twice that, back to 1 within ``feed_override_recover_s`` once it is
  small (plasmac's adaptive-feed request): more time for the axis where the sheet rises faster
  than it follows. A gap too wide (the sheet falling away, a kerf) asks for nothing: slowing
  would not make it safer.

Plain Python scalars, one tick at a time; no geometry (the CNC computes every distance).
"""

from __future__ import annotations

import math

from ladrc_contract.codes import FollowState, Segment, SubState
from ladrc_contract.tick import NO_CNC, CncInput

from ..cnc_params import CncParams
from ..interp import Interpolator, InterpParams
from .leapfrog import Leapfrog, plan

__all__ = ['CncParams', 'CncPartner']

(SUB_NONE, SUB_CORNER_LOCK, SUB_VOID_LOCK, SUB_PIERCE, SUB_THC_DELAY, SUB_LIFT, SUB_LEAPFROG,
 SUB_HOLD, SUB_EDGE_AHEAD, SUB_RETRACT) = (int(s) for s in SubState)
SEG_NONE, SEG_RAPID, SEG_CUT, SEG_PIERCE = (int(s) for s in Segment)
_IDLE, _PID, _LADRC, _FAULT = (int(FollowState[n]) for n in ('IDLE', 'PID', 'LADRC', 'FAULT'))

# pierce phases
_STAGE_APPROACH, _STAGE_DWELL, _CUT_APPROACH, _THC_DELAY = range(4)


class CncPartner:
    """What the CNC said and commanded, and what the controller answers it, tick by tick."""

    def __init__(self) -> None:
        self.cnc: CncInput = NO_CNC
        self.sub = SUB_NONE
        self.reason = ''
        self.in_position = False
        self.ready_to_move = True
        self.feed_hold = False
        self._holding = False
        self._corner = False
        self._edge_left_mm = 0.0   # path still to go before the edge hold releases
        self._hold = ''            # commanded hold: its reason ('' = none)
        self._hold_next: tuple[bool, str] | None = None  # a hold / release at the next segment
        self._segment_key: tuple[int, int] | None = None
        self._stages: list[tuple[float, int]] = []   # pierce: (height, dwell ticks)
        self._stage = 0
        self._phase = -1           # pierce phase; -1: no pierce running
        self._count = 0            # dwell / THC delay ticks left
        self._cut = (math.nan, 0)  # pierce: (cut gap, THC delay ticks)
        self._move: _Lift | Leapfrog | None = None  # a planned move (lift, leapfrog) running
        self._move_sub = SUB_NONE  # its sub-state: SUB_LIFT or SUB_LEAPFROG
        self._inpos = 0            # ticks within tolerance of the target
        self._inpos_target = math.nan
        self.feed_override = 1.0   # fraction of the programmed feed asked for (adaptive feed)
        self._stale_lifted = False  # lifted for the CNC's present silence (a sample resets it)
        self._cnc_live = False  # a sample of the CNC was fresh at a tick: it was live

    def configure(self, p, h_s: float) -> None:
        """Take the ``cnc`` section and the in-position rule (pid.followed_*) of a set."""
        self.p = p.cnc
        self._h = h_s
        self._tol = p.pid.followed_tol_mm
        self._hold_ticks = max(1, int(round(p.pid.followed_hold_s / h_s)))
        self._v_cap = p.limits.v_max_mm_s
        self._a = p.limits.a_max_mm_s2
        self._leap_v = min(p.cnc.leapfrog_velocity_mm_s, p.limits.v_max_mm_s)
        self._leap_a = min(p.cnc.leapfrog_accel_mm_s2, p.limits.a_max_mm_s2)

    @property
    def active(self) -> bool:
        """A CNC motion came or a CNC command runs (otherwise nothing here acts)."""
        return (self.cnc.seq != 0 or self._phase >= 0 or self.planned
                or bool(self._hold) or self._hold_next is not None)

    @property
    def planned(self) -> bool:
        """A planned move (lift, leapfrog) owns the axis: running, or held at its height."""
        return self._move is not None

    # ---- commands (applied at a tick's start by the machine) ------------------------------
    def start_pierce(self, heights_mm, dwell_s, cut_gap_mm: float, thc_delay_s: float) -> float:
        """Start a pierce program; return the first stage height (the new target)."""
        h = self._h
        self._stages = [(float(z), int(round(t / h)))
                        for z, t in zip(heights_mm, dwell_s, strict=True)]
        self._cut = (float(cut_gap_mm), int(round(thc_delay_s / h)))
        self._stage, self._phase = 0, _STAGE_APPROACH
        self.end_move()
        self._inpos = 0
        return self._stages[0][0]

    def start_locked(self, level_mm: float, heights_mm, dwell_s, cut_gap_mm: float,
                     thc_delay_s: float) -> None:
        """Start a locked pierce over the sheet level ``level_mm`` (encoder coordinate)."""
        h = self._h
        stages = [(float(z), int(round(t / h))) for z, t in zip(heights_mm, dwell_s, strict=True)]
        stages.append((float(cut_gap_mm), int(round(thc_delay_s / h))))
        self._start_move(_Locked(level_mm, stages, h, self.p.leapfrog_settle_s,
                                 min(self._leap_v, self._v_cap), self._tol, self._hold_ticks),
                         SUB_PIERCE)

    def start_lift(self, distance_mm: float, velocity_mm_s: float, u_mm_s: float) -> None:
        """Lift by ``distance_mm`` (> 0) at ``velocity_mm_s`` from the applied command."""
        v = min(velocity_mm_s if velocity_mm_s > 0.0 else self.p.lift_velocity_mm_s, self._v_cap)
        self._start_move(_Lift(distance_mm, v, self._a, self._h, u_mm_s), SUB_LIFT)

    def start_leapfrog(self, enc_mm: float, sheet_mm: float, lift_mm: float, arrive_mm: float,
                       rapid_s: float) -> Leapfrog:
        """Start a leapfrog from ``enc_mm`` over a sheet at ``sheet_mm``; return it."""
        settle = self.p.leapfrog_settle_s  # the plan leaves it for the final approach
        leap = Leapfrog(plan(enc_mm, sheet_mm, lift_mm, arrive_mm, max(rapid_s - settle, 0.0),
                             self._leap_v, self._leap_a), arrive_mm, self._h, settle)
        self._start_move(leap, SUB_LEAPFROG)
        return leap

    def _start_move(self, move, sub: int) -> None:
        self._move, self._move_sub = move, sub
        self._phase = -1  # a planned move ends a pierce program

    def end_move(self) -> None:
        """End a planned move (running or held at its height)."""
        self._move = None

    def planned_velocity(self, enc_mm: float, gap_mm: float) -> float:
        """Return the planned move's command this tick (its answers set); held once there.

        ``gap_mm``: a valid reading, NaN when there is none (a rapid over a hole).
        """
        move = self._move
        if isinstance(move, _Locked):
            v = move.velocity(enc_mm, gap_mm)
            self.sub, self.reason = move.sub, move.reason
            self.in_position, self.ready_to_move = move.in_position, move.ready
            return v
        what = 'lift' if self._move_sub == SUB_LIFT else 'leapfrog'
        self.sub = self._move_sub
        v = move.velocity(enc_mm, gap_mm)  # a leapfrog holds its arrival level; a lift 0
        if not move.done:
            self.reason = f'{what}: moving'
            return v
        self.reason = f'{what}: at height, held'
        self.in_position = self.ready_to_move = True
        return v

    def command_hold(self, hold: bool, at_next_segment: bool, reason: str) -> None:
        """Hold (``hold``) or release, now or when the CNC's segment next changes."""
        if at_next_segment:
            self._hold_next = (hold, reason)
        else:
            self._hold_next = None
            self._hold = (reason or 'commanded hold') if hold else ''

    def stop(self) -> None:
        """End programs and holds (the follow stops or faults); the CNC's values stay."""
        self._phase = -1
        self.end_move()
        self._hold, self._hold_next = '', None
        self._corner = False
        self._edge_left_mm = 0.0
        self._inpos = 0
        self.feed_override = 1.0

    # ---- the tick -------------------------------------------------------------------------
    def begin(self, idle: bool) -> None:
        """Start a tick: nothing held, not in position; ready to move only when idle."""
        self.sub, self.reason, self.feed_hold, self._holding = SUB_NONE, '', False, False
        self.in_position, self.ready_to_move = False, idle

    def void_lock(self, reason: str) -> None:
        """Say that the edge guard or the input gate holds (a fast fall, a sink, a jump)."""
        self.sub, self.reason = SUB_VOID_LOCK, reason

    def motion(self, t_s: float, cnc: CncInput | None) -> None:
        """Take this tick's CNC sample; a commanded hold 'at the next segment' applies here."""
        if cnc is None or cnc.seq == 0:
            return
        self.cnc = cnc
        self._stale_lifted = False
        key = (cnc.segment, cnc.contour)
        changed = self._segment_key is not None and key != self._segment_key
        if self._hold_next is not None and changed:
            hold, reason = self._hold_next
            self._hold_next = None
            self._hold = (reason or 'commanded hold') if hold else ''
        self._segment_key = key

    def _untrusted(self, t_s: float) -> str:
        """Why the CNC's sample cannot be judged this tick ('' when it can)."""
        c = self.cnc
        age = t_s - c.stamp_s
        if not age <= self.p.stale_timeout_s:  # NaN too
            return (f'CNC motion stale: last sample {age * 1e3:.1f} ms old (limit '
                    f'{self.p.stale_timeout_s * 1e3:g} ms)')
        if not (c.commanded_feed_mm_s >= 0.0 and c.actual_feed_mm_s >= 0.0
                and math.isfinite(c.commanded_feed_mm_s) and math.isfinite(c.actual_feed_mm_s)
                and not math.isnan(c.edge_ahead_mm) and c.edge_ahead_mm >= 0.0):
            return (f'CNC motion not plausible: feed {c.commanded_feed_mm_s!r} / '
                    f'{c.actual_feed_mm_s!r} mm/s, edge ahead {c.edge_ahead_mm!r} mm')
        return ''

    def judge(self, t_s: float, gap_mm: float, target_mm: float, settled: bool) -> float:
        """Judge a following tick: set :attr:`sub`, :attr:`reason`; return a new target or NaN.

        ``settled``: the machine is in PID/LADRC and followed. Holds: :attr:`holding`.
        """
        if target_mm != self._inpos_target:
            self._inpos_target, self._inpos = target_mm, 0
        if settled and abs(gap_mm - target_mm) <= self._tol:
            self._inpos += 1
        else:
            self._inpos = 0
        at_target = settled and self._inpos >= self._hold_ticks
        new_target = math.nan
        c = self.cnc
        moving = c.seq != 0 and c.actual_feed_mm_s > self.p.moving_feed_mm_s
        if self._phase >= 0:
            new_target = self._pierce(at_target)
            if moving and self._phase in (_STAGE_APPROACH, _STAGE_DWELL, _CUT_APPROACH):
                # the CNC did not wait for in position: ask it to hold, hold the height
                self.feed_hold, self._holding = True, True
                self.reason = (f'CNC moving ({c.actual_feed_mm_s:.3g} mm/s) before the pierce '
                               f'is complete: {self.reason}; feed hold requested')
        if self.sub == SUB_NONE and self._hold:
            self.sub, self.reason, self._holding = SUB_HOLD, self._hold, True
        if self.sub == SUB_NONE and c.seq != 0:
            self._judge_motion(t_s, settled)
        self._adapt_feed(gap_mm, target_mm, settled)
        self.in_position = at_target and self._phase in (-1, _STAGE_DWELL, _THC_DELAY)
        self.ready_to_move = settled and self._phase not in (
            _STAGE_APPROACH, _STAGE_DWELL, _CUT_APPROACH)
        return new_target

    def stale_lift_due(self, t_s: float) -> bool:
        """Return True once per silence of the CNC longer than ``stale_lift_s`` (0: never).

        A silence of a CNC that was live: its last sample was fresh (within ``stale_timeout_s``)
        at some tick. A sample that comes stale is held, not lifted for: the CNC did not go
        silent, it never spoke in time.
        """
        p = self.p
        if p.stale_lift_s <= 0.0 or self._stale_lifted or self.cnc.seq == 0:
            return False
        age = t_s - self.cnc.stamp_s
        if age < p.stale_timeout_s:
            self._cnc_live = True
            return False
        if not self._cnc_live or not age >= p.stale_lift_s:
            return False
        self._stale_lifted = True
        return True

    @property
    def holding(self) -> bool:
        """This tick's command is held (nothing toward the sheet)."""
        return self._holding

    def _judge_motion(self, t_s: float, settled: bool) -> None:
        """Corner lock and edge ahead from the CNC's sample, while cutting and followed."""
        why = self._untrusted(t_s)
        if why:
            self.sub, self.reason, self._holding = SUB_HOLD, why, True
            return
        c, p = self.cnc, self.p
        cutting = c.segment == SEG_CUT and c.beam_on
        if not cutting:
            self._corner = False
            self._edge_left_mm = 0.0
            return
        # edge ahead: held from edge_ahead_hold_mm before it until edge_release_mm after it
        if p.edge_ahead_hold_mm > 0.0 and c.edge_ahead_mm <= p.edge_ahead_hold_mm:
            self._edge_left_mm = c.edge_ahead_mm + p.edge_release_mm
        elif self._edge_left_mm > 0.0:
            self._edge_left_mm -= c.actual_feed_mm_s * self._h
        if self._edge_left_mm > 0.0:
            self.sub, self._holding = SUB_EDGE_AHEAD, True
            self.reason = (f'outline or kerf {c.edge_ahead_mm:.1f} mm ahead: held for '
                           f'{self._edge_left_mm:.1f} mm of path')
            return
        if p.corner_lock and settled:
            cmd = c.commanded_feed_mm_s
            ratio = c.actual_feed_mm_s / cmd if cmd >= p.corner_min_feed_mm_s else 0.0
            if ratio < p.corner_lock_ratio:
                self._corner = True
            elif ratio >= p.corner_unlock_ratio:
                self._corner = False
            if self._corner:
                self.sub, self._holding = SUB_CORNER_LOCK, True
                self.reason = (f'corner lock: feed {c.actual_feed_mm_s:.3g} of {cmd:.3g} mm/s '
                               f'({ratio:.0%} < {p.corner_unlock_ratio:.0%})')

    def _adapt_feed(self, gap_mm: float, target_mm: float, settled: bool) -> None:
        """Set :attr:`feed_override` from this tick's gap error (module docstring)."""
        p, c = self.p, self.cnc
        want = 1.0
        if (p.feed_override_min < 1.0 and settled and c.seq != 0 and c.segment == SEG_CUT
                and c.beam_on and self.sub in (SUB_NONE, SUB_CORNER_LOCK)):
            e0 = p.feed_override_error
            e = (target_mm - gap_mm) / target_mm  # closer than the target (NaN: none asked)
            if e > e0:
                want = max(p.feed_override_min, 1.0 - (1.0 - p.feed_override_min) * (e - e0) / e0)
        if want < self.feed_override:
            self.feed_override = want
        elif self.feed_override < 1.0:
            up = (1.0 - p.feed_override_min) * self._h / p.feed_override_recover_s
            self.feed_override = min(want, self.feed_override + up)

    def _pierce(self, at_target: bool) -> float:
        """Advance the pierce program; return the next target (NaN: unchanged)."""
        n = len(self._stages)
        phase = self._phase
        if phase == _STAGE_APPROACH:
            height, dwell = self._stages[self._stage]
            self.sub = SUB_PIERCE
            self.reason = f'pierce stage {self._stage + 1}/{n}: to {height:g} mm'
            if at_target:
                self._phase, self._count = _STAGE_DWELL, dwell
            return math.nan
        if phase == _STAGE_DWELL:
            self.sub, self._holding = SUB_PIERCE, True
            self.reason = (f'pierce stage {self._stage + 1}/{n}: dwell, '
                           f'{self._count * self._h:.3f} s left')
            self._count -= 1
            if self._count > 0:
                return math.nan
            self._stage += 1
            self._inpos = 0
            if self._stage < n:
                self._phase = _STAGE_APPROACH
                return self._stages[self._stage][0]
            self._phase = _CUT_APPROACH
            return self._cut[0]
        if phase == _CUT_APPROACH:
            self.sub = SUB_PIERCE
            self.reason = f'pierce done: to the cut gap {self._cut[0]:g} mm'
            if at_target:
                self._phase, self._count = _THC_DELAY, self._cut[1]
            return math.nan
        # THC delay: at the cut gap, held until the follow closes in
        self._count -= 1
        if self._count <= 0:
            self._phase = -1
            return math.nan
        self.sub, self._holding = SUB_THC_DELAY, True
        self.reason = f'THC delay: {self._count * self._h:.3f} s left'
        return math.nan

    def answers(self, state: int, followed: bool, retracting: bool) -> dict:
        """Return the FollowStatus answers to the CNC and the CNC values used this tick."""
        c = self.cnc
        sub, reason, feed_hold = self.sub, self.reason, self.feed_hold
        in_position, ready = self.in_position, self.ready_to_move
        if state == _FAULT:
            sub = SUB_RETRACT if retracting else SUB_NONE
            feed_hold, ready = True, False  # any FAULT: the CNC stops its feed
        elif not self.active:  # no CNC: in position once followed
            in_position = followed and (state == _PID or state == _LADRC)
            ready = in_position or state == _IDLE
        return dict(substate=sub, hold_reason=reason, in_position=in_position,
                    ready_to_move=ready, feed_hold_request=feed_hold,
                    feed_override_request=self.feed_override,
                    cnc_seq=c.seq, cnc_stamp_s=c.stamp_s, cnc_segment=c.segment,
                    cnc_beam_on=c.beam_on, cnc_contour=c.contour,
                    cnc_commanded_feed_mm_s=c.commanded_feed_mm_s,
                    cnc_actual_feed_mm_s=c.actual_feed_mm_s,
                    cnc_segment_left_mm=c.segment_left_mm, cnc_edge_ahead_mm=c.edge_ahead_mm)


class _Lift:
    """A lift: a planned move up (the approach's planner, :mod:`..interp`), never down."""

    def __init__(self, distance_mm: float, v_mm_s: float, a_mm_s2: float, h_s: float,
                 u_mm_s: float) -> None:
        self._it = Interpolator(InterpParams(v_mm_s, a_mm_s2), h_s)
        self._it.reset(max(u_mm_s, 0.0))
        self._it.go_distance(distance_mm)
        self.done = False

    def velocity(self, enc_mm: float, gap_mm: float) -> float:
        """Return this tick's command (>= 0); 0 once there (held)."""
        if self.done:
            return 0.0
        v = max(self._it.step(), 0.0)
        self.done = self._it.is_finished()
        return v


class _Locked:
    """A locked pierce and cut: heights above a sheet level held by the encoder, never the law.

    ``stages``: (height above the level, dwell ticks), the last one the cut gap (its dwell: the
    THC delay). Each height is approached as an exponential of time constant ``settle_s``
    (toward the sheet never faster than the distance left over it, as the leapfrog's final
    approach), capped at ``v_mm_s``; in position within ``tol_mm`` for ``hold_ticks``; then its
    dwell. Once at the cut gap it holds there (``SUB_HOLD``, ready to move) until the CNC's next
    command ends it. A valid reading below the height planned at the encoder's position (the
    sheet nearer than the level says) raises the level to ``encoder − reading``; it is never
    lowered (a reading over voids reads wider, never nearer).
    """

    def __init__(self, level_mm: float, stages: list[tuple[float, int]], h_s: float,
                 settle_s: float, v_mm_s: float, tol_mm: float, hold_ticks: int) -> None:
        self.level_mm = level_mm
        self._stages = stages
        self._k = 0
        self._count = -1           # dwell ticks left; -1: approaching
        self._inpos = 0
        self._settle, self._v, self._tol, self._hold = settle_s, v_mm_s, tol_mm, hold_ticks
        self.sub, self.reason = SUB_PIERCE, ''
        self.in_position = self.ready = False
        self.done = False          # (a planned move's flag: never ends by itself)

    def velocity(self, enc_mm: float, gap_mm: float) -> float:
        """Return this tick's command; ``gap_mm``: a valid reading, else NaN."""
        if gap_mm < enc_mm - self.level_mm:  # (False for NaN) the sheet nearer: level up
            self.level_mm = enc_mm - gap_mm
        n = len(self._stages) - 1
        height, dwell = self._stages[self._k]
        z = self.level_mm + height
        err = z - enc_mm
        u = min(max(err / self._settle, -self._v), self._v)
        self._inpos = self._inpos + 1 if abs(err) <= self._tol else 0
        at = self._inpos >= self._hold
        last = self._k == n
        if self._count < 0 and at:
            self._count = dwell
        if self._count == 0 and not last:
            self._k, self._count, self._inpos = self._k + 1, -1, 0
        elif self._count > 0:
            self._count -= 1
        stage = f'stage {self._k + 1}/{n}' if self._k < n else 'cut gap'
        self.in_position = self._count >= 0
        self.ready = last and self._count == 0
        if self.ready:
            self.sub = SUB_HOLD
            self.reason = (f'height locked: {height:g} mm above the sheet level followed last '
                           f'({self.level_mm:.3f} mm, encoder), no capacitive following')
        else:
            self.sub = SUB_PIERCE
            self.reason = (f'locked pierce {stage}: {height:g} mm above the level followed '
                           f'last, by the encoder' + (', dwell' if self._count > 0 else ''))
        return u
