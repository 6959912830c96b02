"""The simulated laser CNC of the job world: it runs a part program and commands the height.

Per contour, as a laser CNC does (docs/interfaces.md, "CNC interface"; the sequence diagram
there): a rapid to the pierce point (with a leapfrog, or lift, wait in position, move), the
pierce (``pierce``: the controller approaches each stage height; the beam is on from the first
stage in position), XY waits for ``ready_to_move``, then the cut along the lead-in and the
contour at the feed (:mod:`.motion`), beam off at micro-joints and at the end. It reports its
motion every ``cycle_ticks`` (``CncMotion``: segment, beam, feeds, distance to the segment's
end, and the distance to the first void ahead under the nozzle: the outline, a hole or an
earlier kerf, which it computes from the job's sheet). A feed-hold request stops the XY feed
while it lasts, and a feed-override request (adaptive feed) scales the cutting feed
(``honour_override``); a FAULT of the controller aborts the job (the CNC stops and says why).
A contour smaller than ``small_contour_mm`` is pierced locked (``pierce`` with ``locked``: its
heights held by the encoder above the sheet level followed last, no capacitive following, as
plasmac's hole sensing), once a contour of this follow was cut followed (a level exists).

Plain Python; the same class runs headless (:mod:`.runner`) and behind the live CNC node.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any, Callable

from ladrc_contract.codes import FollowState, Segment, SubState
from ladrc_contract.tick import CncInput
import numpy as np

from .motion import PathMotion

RAPID, CUT, PIERCE, NONE = (int(Segment.RAPID), int(Segment.CUT), int(Segment.PIERCE),
                            int(Segment.NONE))
FAULT = int(FollowState.FAULT)
HOLD = int(SubState.HOLD)
COMMANDS = ('leapfrog', 'lift', 'pierce', 'stop_follow')
"""The follow commands the CNC sends (ladrc_contract.services names)."""


@dataclass(frozen=True)
class CncSettings:
    """The job's feeds, heights and sequence (the job file's ``cut`` and ``cnc`` sections)."""

    feed_mm_s: float = 100.0        # cutting feed
    rapid_mm_s: float = 500.0       # rapid feed
    accel_mm_s2: float = 2000.0     # XY path acceleration
    junction_mm: float = 0.05       # corner deviation of the planner (motion.py)
    cut_gap_mm: float = 1.0
    pierce_heights_mm: tuple[float, ...] = (3.0,)
    pierce_dwell_s: tuple[float, ...] = (0.2,)
    thc_delay_s: float = 0.1
    lift_mm: float = 8.0            # above the sheet during rapids (leapfrog peak, or the lift)
    leapfrog: bool = True           # False: lift, wait in position, rapid, pierce
    look_ahead_mm: float = 30.0     # edge-ahead look-ahead
    cycle_ticks: int = 2            # CNC cycle in controller ticks (2: 1 kHz)
    wait_timeout_s: float = 10.0    # a wait for the controller longer than this aborts the job
    honour_override: bool = True    # scale the cutting feed by the controller's request
    small_contour_mm: float = -1.0  # a contour smaller (its largest extent) is pierced and cut
    #                                 locked (no capacitive following); -1: the nozzle diameter
    #                                 (the job resolves it from its sensor), 0: none


@dataclass
class CncLog:
    """What the CNC did: pierce times, waits, feed holds, and why it stopped."""

    pierces: int = 0
    locked: int = 0                 # contours pierced and cut locked (small contours)
    feed_hold_ticks: int = 0
    waits: list[tuple[str, float]] = field(default_factory=list)  # (what, seconds)
    aborted: str = ''
    finished: bool = False


class Cnc:
    """Runs a :class:`~.program.Program` tick by tick (``step``), commanding ``command``."""

    def __init__(self, program: Any, settings: CncSettings, command: Callable[..., Any],
                 h_s: float, start_xy: tuple[float, float] = (0.0, 0.0),
                 void_ahead: Callable[[np.ndarray, float], float] | None = None) -> None:
        self.program = program
        self.s = settings
        self.command = command
        self.h = h_s
        self.void_ahead = void_ahead or (lambda pts, step: math.inf)
        self.log = CncLog()
        self.x, self.y = start_xy
        self.segment = NONE
        self.beam = False
        self.contour = 0           # 1-based index of the contour being cut, 0 between
        self.commanded_feed = 0.0
        self.move: PathMotion | None = None
        self._k = -1               # contour index in the program
        self._phase = 'start'
        self._wait_ticks = 0
        self._seq = 0
        self._tick = 0
        self.cut_done: list[int] = []  # contours finished this tick (the runner drops them)
        self._pierce_seen = False
        self._lift_target = start_xy
        self._lead_mm = 0.0
        self._ovr = 1.0            # the feed override of the cut (the controller's request)
        self._followed_cut = False  # a contour was cut followed in this follow (a level exists)
        self._locked = False       # the contour being pierced / cut is locked

    # ---- the sequence ------------------------------------------------------------------------
    def _cmd(self, name: str, **kw: Any) -> None:
        ok, msg = self.command(name, **kw)
        if not ok:
            self.refused(name, msg)

    def refused(self, name: str, message: str) -> None:
        """Abort the job: a command was refused (live: its answer may come ticks later)."""
        self._abort(f'{name} refused: {message}')

    def _abort(self, why: str) -> None:
        if not self.log.aborted:
            self.log.aborted = why
        self._phase = 'stopped'
        self.beam = False
        self.segment = NONE
        self.move = None

    def _rapid_to(self, xy: tuple[float, float]) -> None:
        pts = np.array([[self.x, self.y], xy])
        self.move = PathMotion(pts, self.s.rapid_mm_s, self.s.accel_mm_s2, self.s.junction_mm,
                               self.h)
        self.segment, self.beam = RAPID, False
        self.commanded_feed = self.s.rapid_mm_s

    def _rapid_time_s(self, length_mm: float) -> float:
        """Return a lower bound of a rapid's time: a triangle or trapezoid from rest to rest."""
        v, a = self.s.rapid_mm_s, self.s.accel_mm_s2
        return (2.0 * math.sqrt(length_mm / a) if length_mm < v * v / a
                else length_mm / v + v / a)

    def _next_contour(self, answers: dict) -> None:
        self._k += 1
        if self._k >= len(self.program.contours):
            self._cmd('stop_follow')
            self._phase = 'done'
            self.log.finished = True
            self.segment, self.beam, self.move = NONE, False, None
            return
        c = self.program.contours[self._k]
        target = c.pierce_xy
        length = math.hypot(target[0] - self.x, target[1] - self.y)
        following = answers.get('state') in (int(FollowState.PID), int(FollowState.LADRC))
        if following and self.s.leapfrog and length > 0.0:
            # lift with the rapid, arrive at the first pierce height as it ends
            self._cmd('leapfrog', lift_mm=self.s.lift_mm, rapid_length_mm=length,
                      rapid_feed_mm_s=length / self._rapid_time_s(length),
                      arrive_height_mm=self.s.pierce_heights_mm[0])
            self._rapid_to(target)
            self._phase = 'rapid'
        elif following:
            self._cmd('lift', mode=0, value_mm=self.s.lift_mm, velocity_mm_s=0.0)
            self._phase = 'lift'
            self.segment, self.beam, self.move = NONE, False, None
            self._lift_target = target
        else:  # the first contour: the head is up, the follow not started
            self._rapid_to(target)
            self._phase = 'rapid'

    def _start_cut(self) -> None:
        c = self.program.contours[self._k]
        path = np.vstack((c.lead_in_mm, c.points_mm[1:]))
        self.move = PathMotion(path, self.s.feed_mm_s, self.s.accel_mm_s2, self.s.junction_mm,
                               self.h)
        self._lead_mm = float(np.sum(np.hypot(*np.diff(c.lead_in_mm, axis=0).T)))
        self.segment, self.beam = CUT, True
        self.contour = self._k + 1
        self.commanded_feed = self.s.feed_mm_s
        self._phase = 'cut'

    def _waited(self, what: str) -> bool:
        """Count a tick of waiting; abort past the timeout. Return whether it timed out."""
        self._wait_ticks += 1
        if self._wait_ticks * self.h > self.s.wait_timeout_s:
            self._abort(f'waited {self.s.wait_timeout_s:g} s for {what} (contour {self._k + 1})')
            return True
        return False

    def _done_waiting(self, what: str) -> None:
        if self._wait_ticks:
            self.log.waits.append((what, self._wait_ticks * self.h))
        self._wait_ticks = 0

    # ---- the tick ----------------------------------------------------------------------------
    def step(self, answers: dict) -> CncInput | None:
        """Advance one controller tick; ``answers``: the controller's last FollowStatus values.

        Return the motion sample of this CNC cycle (None between cycles).
        """
        self.cut_done = []
        self._tick += 1
        if answers.get('state') == FAULT and self._phase not in ('stopped', 'done', 'start'):
            self._abort(f'the height controller faulted: {answers.get("fault_reason", "")}')
        hold = bool(answers.get('feed_hold_request')) and self._phase in ('rapid', 'cut')
        if hold:
            self.log.feed_hold_ticks += 1
        phase = self._phase
        if phase == 'start':
            self._next_contour(answers)
        elif phase == 'lift':
            if answers.get('in_position') and answers.get('substate') == 5:
                self._done_waiting('lift in position')
                self._rapid_to(self._lift_target)
                self._phase = 'rapid'
            else:
                self._waited('the lift')
        elif phase == 'rapid':
            self.x, self.y = self.move.step(hold)
            if self.move.done:
                c = self.program.contours[self._k]
                self._locked = self._followed_cut and c.size_mm < self.s.small_contour_mm
                self._cmd('pierce', heights_mm=self.s.pierce_heights_mm,
                          dwell_s=self.s.pierce_dwell_s, cut_gap_mm=self.s.cut_gap_mm,
                          thc_delay_s=self.s.thc_delay_s,
                          **({'locked': True} if self._locked else {}))
                self.log.pierces += 1
                self.log.locked += self._locked
                self._pierce_seen = False
                self.segment, self.move = PIERCE, None
                self.commanded_feed = 0.0
                self.x, self.y = c.pierce_xy
                self._phase = 'pierce'
        elif phase == 'pierce':
            sub = answers.get('substate')
            self._pierce_seen = self._pierce_seen or sub in (3, 4)  # (answers lag a tick)
            if self._pierce_seen and answers.get('in_position'):
                self.beam = True  # the stage is in position: the beam pierces
            if self._pierce_seen and answers.get('ready_to_move') and (
                    sub in (0, 4) or (self._locked and sub == HOLD)):
                self._done_waiting('pierce')
                self._followed_cut = self._followed_cut or not self._locked
                self._start_cut()
            else:
                self._waited('the pierce')
        elif phase == 'cut':
            self._ovr = self._override(answers)
            self.x, self.y = self.move.step(hold, self._ovr)
            c = self.program.contours[self._k]
            s_contour = self.move.s - self._lead_mm
            self.beam = not any(a <= s_contour <= b for a, b in c.micro_joints)
            if self.move.done:
                self.beam = False
                self.cut_done.append(self._k)
                self.contour = 0
                self._next_contour(answers)
        if self._tick % self.s.cycle_ticks:
            return None
        return self.sample(self._tick * self.h)

    @property
    def feed_mm_s(self) -> float:
        """Return the commanded path speed after the feed override (what ``CncMotion`` says)."""
        return self.commanded_feed * (self._ovr if self.segment == CUT else 1.0)

    def _override(self, answers: dict) -> float:
        """Return the feed fraction the controller asks for, within 0.05..1 (1: not honoured)."""
        r = answers.get('feed_override_request', 1.0)
        if not self.s.honour_override or not isinstance(r, float) or not r == r:
            return 1.0
        return min(max(r, 0.05), 1.0)

    def sample(self, t_s: float) -> CncInput:
        """Return the CNC's motion sample now (``CncMotion`` values; stamp = ``t_s``)."""
        self._seq += 1
        move = self.move
        v = move.v if move is not None else 0.0
        left = move.total_mm - move.s if move is not None else 0.0
        ahead = math.inf
        if self.segment == CUT and move is not None:
            step = 0.5
            ahead = self.void_ahead(move.ahead(self.s.look_ahead_mm, step), step)
        return CncInput(self._seq, t_s, self.segment, self.beam, self.contour, self.feed_mm_s, v,
                        left, ahead)
