"""The bridge's logic: LinuxCNC's state and the height controller's answers -> both sides' inputs.

Plain Python (no ROS, no HAL): the node (:mod:`.bridge_node`) calls :meth:`Sequencer.step` once
per LinuxCNC sample with the newest ``follow/status`` answers, publishes the ``CncMotion`` it
returns, calls the follow services it lists and sends the HAL outputs to the component. It
plays the role the project's simulated CNC plays (``ladrc_sim/job/cnc.py``, docs/interfaces.md
"CNC interface") for a CNC that runs a G-code program of its own:

* **Beam-on -> pierce.** ``M3`` (``spindle.0.on``) while the program runs is a cut's request:
  the bridge calls ``follow/pierce`` with the program's pierce where it gave one (a CAM post's
  ``o<touchoff> call [pierce height] [pierce delay] [cut height]``: the subroutine puts them
  on ``motion.analog-out-00..02`` before its M3; one stage), else with the stages of the job
  or the configuration (:class:`BridgeParams`), keeps ``spindle.0.at-speed`` low (LinuxCNC
  waits for it before the first feed move after each M3, without breaking the path: the G0
  before it has ended) and opens the beam (``ladrc.beam-on``) once the controller is in
  position at the first stage; when the controller answers ``ready_to_move`` (from its THC
  delay on) it raises at-speed and the cut starts. XY never moves before: LinuxCNC's own
  planner waits.
* **Hold / THC off.** ``motion.digital-out-02`` (``M62 P2`` synchronised with the next move,
  ``M64 P2`` at once; ``M63``/``M65`` release) -> ``follow/hold`` now (the output changes when
  the move starts, so "at the next segment" is LinuxCNC's part). ``digital-out-03`` (``M62 P3``)
  closes the beam while moving (micro-joints).
* **Rapids.** A G0 while the controller follows starts a leapfrog (``follow/leapfrog``, its
  length from ``motion.distance-to-go`` at the rapid's start, its time from LinuxCNC's rapid
  feed and acceleration: a lower bound, so the plan is early and the rapid never waits) where
  the configuration enables it; otherwise an ``M5`` ends the cut with a lift
  (``follow/lift``) and the feed is held until the lift is in position (lift, stop, move).
* **FAULT -> feed hold and pause.** A FAULT of the controller (the collision retract
  included), a feed-hold request, a refused command, a wait longer than ``wait_timeout_s`` or
  a controller gone silent: ``motion.feed-hold``, at-speed low, beam off, and (but for a plain
  feed-hold request) the program paused (``halui.program.pause``) and the job aborted with the
  reason (the simulated CNC's rule).
* **LinuxCNC gone, estop or machine off while the program runs**: the job is aborted and the
  head lifted (``follow/lift``), then the follow stopped; the controller never waits for
  LinuxCNC.
* **The end.** The program idle after it ran: ``follow/stop``; the job's log
  (:class:`BridgeLog`) is published once the controller commands zero (the job runner's
  ``JobEnd`` rule). A program that ended without a cut request (0 pierces) is not finished:
  the job is aborted with that reason. ``ladrc.program-error`` (the headless display: LinuxCNC
  stopped the program on an error) aborts the job in any phase, before the run included.

Adaptive feed: ``motion.adaptive-feed`` is the controller's ``feed_override_request`` (M52 P1 is
in the configuration's start-up code).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any

from ladrc_contract.codes import FollowState, Segment, SubState
from ladrc_contract.schema import Section, param

from . import protocol as p

# follow states and sub-states, as FollowStatus carries them (ladrc_contract.codes)
IDLE, PID, LADRC, FAULT = (int(FollowState.IDLE), int(FollowState.PID),
                           int(FollowState.LADRC), int(FollowState.FAULT))
SUB_NONE, SUB_PIERCE, SUB_THC_DELAY, SUB_LIFT = (int(SubState.NONE), int(SubState.PIERCE),
                                                 int(SubState.THC_DELAY), int(SubState.LIFT))
# CncMotion.SEGMENT_*
SEG_NONE, SEG_RAPID, SEG_CUT, SEG_PIERCE = (int(Segment.NONE), int(Segment.RAPID),
                                            int(Segment.CUT), int(Segment.PIERCE))
MOVING_MM_S = 0.5
"""XY counts as moving above this path speed (the controller's cnc.moving_feed_mm_s)."""
MOVED_MM = 0.01
"""A pierce point left by more than this before ready_to_move: XY started a contour early."""


@dataclass(frozen=True)
class BridgeParams(Section):
    """The bridge node's parameters, declared once (``ladrc_contract.schema``)."""

    socket_path: str = param('', '', "the HAL component's Unix socket ([LADRC]SOCKET of the "
                             "run's INI)", runtime=False)
    pierce_heights_mm: tuple[float, ...] = param(
        (3.0,), 'mm', "pierce stage heights above the sheet, first to last (the job's "
        'cnc.pierce_heights_mm)', gt=0.0, le=50.0, runtime=False)
    pierce_dwell_s: tuple[float, ...] = param(
        (0.2,), 's', 'dwell at each pierce stage (as many as the heights)', ge=0.0, le=10.0,
        runtime=False)
    cut_gap_mm: float = param(1.0, 'mm', 'the follow gap while cutting', gt=0.0, le=10.0,
                              runtime=False)
    thc_delay_s: float = param(0.1, 's', 'at the cut gap, held this long before the follow '
                               'closes in (XY moves from its start)', ge=0.0, le=10.0,
                               runtime=False)
    lift_mm: float = param(8.0, 'mm', "above the sheet over rapids (the leapfrog's peak, or "
                           'the lift)', gt=0.0, le=50.0, runtime=False)
    leapfrog: bool = param(True, '', 'leapfrog over rapids; false: M5 lifts, the feed is held '
                           'until the lift is in position', runtime=False)
    rapid_mm_s: float = param(0.0, 'mm/s', "LinuxCNC's rapid feed for a leapfrog's plan (0: "
                              "the INI's [TRAJ]MAX_LINEAR_VELOCITY, from the component)",
                              ge=0.0, le=10000.0, runtime=False)
    accel_mm_s2: float = param(0.0, 'mm/s²', "LinuxCNC's path acceleration for a leapfrog's "
                               "plan (0: the INI's [TRAJ]MAX_LINEAR_ACCELERATION)", ge=0.0,
                               le=1e6, runtime=False)
    honour_override: bool = param(True, '', "the controller's feed override request drives "
                                  'motion.adaptive-feed', runtime=False)
    hold_on_thc_off: bool = param(True, '', 'M62/M64 P2 (digital-out-02) holds the height',
                                  runtime=False)
    wait_timeout_s: float = param(10.0, 's', 'a wait for the controller (pierce, lift) longer '
                                  'than this aborts the job: feed hold, pause', gt=0.0,
                                  le=600.0, runtime=False)
    controller_timeout_s: float = param(0.5, 's', 'no follow/status for this long while the '
                                        'program runs: feed hold, beam off, pause, abort',
                                        gt=0.0, le=60.0, runtime=False)
    link_timeout_s: float = param(0.5, 's', 'no LinuxCNC sample for this long: LinuxCNC is '
                                  'gone (the job aborted, the head lifted)', gt=0.0, le=60.0,
                                  runtime=False)
    sample_delay_limit_s: float = param(0.1, 's', 'a LinuxCNC sample reaching the node later '
                                        'than this after its pins were read, while the '
                                        'program runs: the controller knows XY too late: '
                                        'feed hold, pause, abort, the head up', gt=0.0,
                                        le=60.0, runtime=False)
    end_timeout_s: float = param(5.0, 's', "after the job's end, publish its log at the latest "
                                 'this long after (else once the controller commands zero)',
                                 gt=0.0, le=60.0, runtime=False)
    job: str = param('', '', "the job's name (the log names it)", runtime=False)
    wait_for_controller_s: float = param(60.0, 's', 'at start, wait this long for the height '
                                         "controller's services and status", gt=0.0, le=3600.0,
                                         runtime=False)
    wait_for_linuxcnc_s: float = param(60.0, 's', "at start, wait this long for the HAL "
                                       "component's socket", gt=0.0, le=3600.0, runtime=False)
    exit_at_end: bool = param(True, '', "exit once the job's log is published", runtime=False)
    thread_priority: int = param(45, '', 'SCHED_FIFO priority of the loop thread (0: normal); '
                                 'below the follow and sim loops (50): the CNC is 1 kHz and '
                                 'waits for nothing of theirs', ge=0, le=98, runtime=False)
    lock_memory: bool = param(True, '', 'mlockall the process', runtime=False)


ABORT_CODES = ('refused', 'linuxcnc_gone', 'controller_fault', 'program_error',
               'controller_gone', 'linuxcnc_late', 'estop', 'wait_timeout', 'no_cut',
               'interrupted')
"""Why the bridge aborted a job, by kind (``BridgeLog.aborted_code``; the reason says more).
``linuxcnc_late``, ``linuxcnc_gone`` and ``controller_gone`` are the bridge's link guards: a
stall of a process can trip them as a crash does (the processes' exit codes tell which)."""


@dataclass
class BridgeLog:
    """What the bridge and LinuxCNC did: the simulated CNC's log keys and LinuxCNC's own."""

    pierces: int = 0
    feed_hold_ticks: int = 0       # samples with motion.feed-hold set (the figures' feed hold)
    waits: list[tuple[str, float]] = field(default_factory=list)
    aborted: str = ''
    aborted_code: str = ''         # why, as one of ABORT_CODES (the reason's kind)
    finished: bool = False
    contours: list[dict[str, Any]] = field(default_factory=list)
    holds: int = 0                 # M62/M64 P2 holds
    leapfrogs: int = 0
    lifts: int = 0
    fault_holds: list[dict[str, Any]] = field(default_factory=list)
    moved_before_ready: int = 0    # contours whose pierce point XY left before ready_to_move
    moved_during_lift: int = 0     # lifts (no leapfrog) during which XY left the contour's end
    linuxcnc_samples: int = 0
    linuxcnc_max_gap_ms: float = 0.0  # the node's longest wait for a sample (both processes)
    component_max_gap_ms: float = 0.0  # the component's longest gap between two polls
    delays_ms: list[float] = field(default_factory=list)  # sample read -> step (1 in 10)
    safe_samples: int = 0          # samples with the component on its safe outputs

    def as_dict(self) -> dict[str, Any]:
        """Return the log as JSON-ready values (``cnc/job``)."""
        return {'pierces': self.pierces, 'feed_hold_ticks': self.feed_hold_ticks,
                'waits': [list(w) for w in self.waits], 'aborted': self.aborted,
                'aborted_code': self.aborted_code,
                'finished': self.finished, 'contours': self.contours, 'holds': self.holds,
                'leapfrogs': self.leapfrogs, 'lifts': self.lifts,
                'fault_holds': self.fault_holds, 'moved_before_ready': self.moved_before_ready,
                'moved_during_lift': self.moved_during_lift,
                'linuxcnc_samples': self.linuxcnc_samples,
                'linuxcnc_max_gap_ms': round(self.linuxcnc_max_gap_ms, 2),
                'component_max_gap_ms': round(self.component_max_gap_ms, 2),
                'sample_delay_ms_p99': _p99(self.delays_ms),
                'sample_delay_ms_max': round(max(self.delays_ms, default=0.0), 2),
                'safe_samples': self.safe_samples}


def _p99(values: list[float]) -> float:
    if not values:
        return 0.0
    v = sorted(values)
    return round(v[min(len(v) - 1, int(0.99 * len(v)))], 2)


@dataclass
class StepOut:
    """One step's results: the motion sample (None: nothing new), outputs, commands."""

    motion: dict[str, Any] | None
    outputs: p.HalOutputs
    commands: list[tuple[str, dict[str, Any]]]


def rapid_time_s(length_mm: float, v_mm_s: float, a_mm_s2: float) -> float:
    """Return a lower bound of a rapid's time: a triangle or trapezoid from rest to rest."""
    if not (v_mm_s > 0 and a_mm_s2 > 0):
        return math.inf
    return (2.0 * math.sqrt(length_mm / a_mm_s2) if length_mm < v_mm_s * v_mm_s / a_mm_s2
            else length_mm / v_mm_s + v_mm_s / a_mm_s2)


def program_pierce(s: p.LcncSample) -> bool:
    """Return whether a sample carries the program's pierce (M68 E0 set: a touchoff call).

    The height and the cut height positive, the delay not negative, all finite; anything else
    (0: no call yet) is the job's pierce. The controller checks the values (a refusal aborts).
    """
    h, t, c = s.pierce_height_mm, s.pierce_delay_s, s.cut_height_mm
    return all(math.isfinite(v) for v in (h, t, c)) and h > 0.0 and c > 0.0 and t >= 0.0


class Sequencer:
    """The bridge's state (module docstring); one :meth:`step` per LinuxCNC sample."""

    def __init__(self, params: BridgeParams) -> None:
        self.p = params
        self.log = BridgeLog()
        self.rapid_mm_s = params.rapid_mm_s
        self.accel_mm_s2 = params.accel_mm_s2
        self.phase = 'idle'        # idle, between, pierce, cut, lift, done, aborted
        self.contour = 0           # the beam request's number while requested
        self.requests = 0          # beam requests so far
        self.pierce_seen = False
        self.beam_open = False     # in position at the first stage: the beam may open
        self.at_speed = False
        self.ran = False           # the program has run (its end is an end)
        self.seq = 0
        self.pause_count = 0
        self.prev: p.LcncSample | None = None
        self.t_wait = -1.0         # when the current wait began (node clock, s)
        self.pierce_xy = (math.nan, math.nan)
        self.pierce_t = 0.0
        self.moved_mm = 0.0
        self.rapid_started = False
        self.holding = False       # a follow/hold(True) is in force
        self.lift_hold = False     # the feed held for a lift (no leapfrog)
        self.lift_xy = (math.nan, math.nan)  # where XY stood at the M5 of that lift
        self.moved_lift_mm = 0.0
        self.end_t = -1.0          # when the job ended (finished / aborted)
        self.ended_sent = False    # the end's commands sent
        self.fault_t = -1.0        # when the FAULT was first seen
        self.fault_logged: dict[str, Any] | None = None
        self.stop_sent = False
        self.lift_after_abort = False  # the abort lifted the head: stop the follow after it
        self.last_sample_t = -1.0

    # ---- helpers -------------------------------------------------------------------------
    def hello(self, info: dict[str, Any]) -> None:
        """Take LinuxCNC's limits from the component's hello where not configured."""
        if not self.rapid_mm_s > 0 and isinstance(info.get('max_velocity_mm_s'), (int, float)):
            self.rapid_mm_s = float(info['max_velocity_mm_s'])
        if not self.accel_mm_s2 > 0 and isinstance(info.get('max_accel_mm_s2'), (int, float)):
            self.accel_mm_s2 = float(info['max_accel_mm_s2'])

    def abort(self, why: str, now_s: float, pause: bool = True, code: str = '') -> None:
        """Abort the job: feed hold, beam off, pause (once), the reason and its code logged.

        The first abort wins; ``code`` is one of :data:`ABORT_CODES`.
        """
        if self.phase in ('aborted',):
            return
        if not self.log.aborted:
            self.log.aborted = why
            self.log.aborted_code = code
        self.phase = 'aborted'
        self.at_speed = False
        self.beam_open = False
        if pause:
            self.pause_count += 1
        if self.end_t < 0:
            self.end_t = now_s

    def refused(self, name: str, message: str, now_s: float) -> None:
        """Abort the job: a follow command was refused (its answer came later)."""
        self.abort(f'{name} refused: {message}', now_s, code='refused')

    def linuxcnc_gone(self, why: str, now_s: float, answers: dict[str, Any] | None = None
                      ) -> list[tuple[str, dict[str, Any]]]:
        """LinuxCNC stopped talking (socket closed, silent): abort, lift; return the commands."""
        if self.phase in ('done', 'aborted'):
            return []
        self.abort(f'LinuxCNC gone: {why}', now_s, pause=False, code='linuxcnc_gone')
        return self._up_and_stop(answers)

    def _up_and_stop(self, answers: dict[str, Any] | None) -> list[tuple[str, dict[str, Any]]]:
        """Return the commands of a CNC gone: the head up, the follow stopped.

        Following: lift the head (then stop, :meth:`end_step`). Approaching or piercing (a lift
        is refused there): stop the follow at once; the head stays where the approach has
        brought it, above the sheet, and nothing moves it any more.
        """
        state = int((answers or {}).get('state', IDLE))
        if state in (PID, LADRC):
            self.lift_after_abort = True
            return [self._lift(by_distance=True)]  # (a rapid's reading may be a hole's)
        if state == FAULT:
            return []  # the controller's own (a retract)
        self.stop_sent = True
        return [('stop_follow', {})]

    def _lift(self, by_distance: bool = False) -> tuple[str, dict[str, Any]]:
        """Return a lift to ``lift_mm`` above the sheet (the reading), or by it (no reading)."""
        self.log.lifts += 1
        return ('lift', {'mode': 1 if by_distance else 0, 'value_mm': self.p.lift_mm,
                         'velocity_mm_s': 0.0})

    def pierce_args(self, s: p.LcncSample) -> dict[str, Any]:
        """Return the ``follow/pierce`` arguments of a cut request: the program's or the job's."""
        if program_pierce(s):
            return {'heights_mm': (s.pierce_height_mm,), 'dwell_s': (s.pierce_delay_s,),
                    'cut_gap_mm': s.cut_height_mm, 'thc_delay_s': self.p.thc_delay_s}
        return {'heights_mm': tuple(self.p.pierce_heights_mm),
                'dwell_s': tuple(self.p.pierce_dwell_s), 'cut_gap_mm': self.p.cut_gap_mm,
                'thc_delay_s': self.p.thc_delay_s}

    def _waited(self, what: str, now_s: float) -> None:
        if self.t_wait >= 0:
            self.log.waits.append((what, round(now_s - self.t_wait, 4)))
        self.t_wait = -1.0

    # ---- one step --------------------------------------------------------------------------
    def step(self, s: p.LcncSample, answers: dict[str, Any] | None, status_age_s: float,
             now_s: float, delay_s: float = math.nan) -> StepOut:
        """Take one LinuxCNC sample and the controller's newest answers (None: none yet).

        ``status_age_s``: how long ago that status arrived; ``now_s``: the node's clock;
        ``delay_s``: how long ago the component read this sample's pins (NaN: unknown).
        """
        cmds: list[tuple[str, dict[str, Any]]] = []
        prev = self.prev
        self.prev = s
        log = self.log
        log.linuxcnc_samples += 1
        if self.last_sample_t >= 0:
            log.linuxcnc_max_gap_ms = max(log.linuxcnc_max_gap_ms,
                                          (now_s - self.last_sample_t) * 1e3)
        self.last_sample_t = now_s
        if prev is not None:
            log.component_max_gap_ms = max(log.component_max_gap_ms, (s.t_ns - prev.t_ns) * 1e-6)
        if log.linuxcnc_samples % 10 == 0 and delay_s == delay_s:
            log.delays_ms.append(max(0.0, delay_s * 1e3))
        if s.flag(p.F_LINK_SAFE):
            log.safe_samples += 1
        if s.flag(p.F_FEED_HOLD_IN) and self.ran and self.phase not in ('done',):
            log.feed_hold_ticks += 1
        a = answers or {}
        state = int(a.get('state', IDLE))
        sub = int(a.get('substate', 0))
        alive = answers is not None and status_age_s <= self.p.controller_timeout_s
        running = s.flag(p.F_RUNNING) or s.flag(p.F_PAUSED)
        spindle = s.flag(p.F_SPINDLE_ON)
        was_spindle = prev is not None and prev.flag(p.F_SPINDLE_ON)
        following = state in (PID, LADRC)
        moving = s.actual_vel_mm_s > MOVING_MM_S or s.current_vel_mm_s > MOVING_MM_S
        if running:
            self.ran = True
        if self.phase == 'idle' and running:
            self.phase = 'between'

        # ---- faults, lost controller, LinuxCNC stopped ----------------------------------------
        active = self.phase not in ('idle', 'done', 'aborted')
        if active and state == FAULT:
            if self.fault_t < 0:
                self.fault_t = now_s
                self.fault_logged = {'t_s': round(now_s, 4), 'reason': str(a.get(
                    'fault_reason', '')), 'line': s.program_line, 'xy_mm': [
                    round(s.x_mm, 3), round(s.y_mm, 3)], 'vel_mm_s': round(
                    s.current_vel_mm_s, 3)}
                log.fault_holds.append(self.fault_logged)
            self.abort(f'the height controller faulted: {a.get("fault_reason", "")}', now_s,
                       code='controller_fault')
        elif s.flag(p.F_PROGRAM_ERROR) and self.phase not in ('done', 'aborted'):
            self.abort('LinuxCNC stopped the program on an error (its text and line: the '
                       "display's error)", now_s, pause=False, code='program_error')
            cmds += self._up_and_stop(answers)
        elif active and not alive:
            why = ('no follow/status from the height controller' if answers is None else
                   f'follow/status {status_age_s * 1e3:.0f} ms old (limit '
                   f'{self.p.controller_timeout_s * 1e3:g} ms)')
            self.abort(f'the height controller is gone: {why}', now_s, code='controller_gone')
        elif (active and delay_s == delay_s
              and delay_s > self.p.sample_delay_limit_s):
            self.abort(f'LinuxCNC samples {delay_s * 1e3:.0f} ms late (limit '
                       f'{self.p.sample_delay_limit_s * 1e3:g} ms): XY known too late', now_s,
                       code='linuxcnc_late')
            cmds += self._up_and_stop(answers)
        elif active and (s.flag(p.F_ESTOP) or not s.flag(p.F_MACHINE_ON)):
            self.abort('LinuxCNC estop' if s.flag(p.F_ESTOP) else 'LinuxCNC machine off',
                       now_s, pause=False, code='estop')
            cmds += self._up_and_stop(answers)
        # how the FAULT's feed hold went: LinuxCNC's own state shows it
        fl = self.fault_logged
        if fl is not None:
            if 'feed_hold_after_ms' not in fl and s.flag(p.F_FEED_HOLD_IN):
                fl['feed_hold_after_ms'] = round((now_s - self.fault_t) * 1e3, 2)
            if 'stopped_after_ms' not in fl and not moving:
                fl['stopped_after_ms'] = round((now_s - self.fault_t) * 1e3, 2)
            if 'paused_after_ms' not in fl and s.flag(p.F_PAUSED):
                fl['paused_after_ms'] = round((now_s - self.fault_t) * 1e3, 2)

        # ---- the sequence -------------------------------------------------------------------
        if self.phase not in ('idle', 'done', 'aborted'):
            if spindle and not was_spindle:  # M3: a cut's request -> the pierce
                self.requests += 1
                self.contour = self.requests
                self.phase = 'pierce'
                self.at_speed = self.beam_open = self.pierce_seen = False
                self.pierce_xy, self.pierce_t, self.moved_mm = (s.x_mm, s.y_mm), now_s, 0.0
                self.t_wait = now_s
                self.lift_hold = False
                pierce = self.pierce_args(s)
                cmds.append(('pierce', pierce))
                log.pierces += 1
                log.contours.append({'contour': self.contour, 'line': s.program_line,
                                     'pierce_xy_mm': [round(s.x_mm, 3), round(s.y_mm, 3)],
                                     'pierce': {**{k: v for k, v in pierce.items()
                                                   if k != 'thc_delay_s'},
                                                'from': 'program' if program_pierce(s)
                                                else 'job'}})
            elif self.phase == 'pierce':
                self.moved_mm = max(self.moved_mm, math.hypot(s.x_mm - self.pierce_xy[0],
                                                              s.y_mm - self.pierce_xy[1]))
                self.pierce_seen = self.pierce_seen or sub in (SUB_PIERCE, SUB_THC_DELAY)
                if self.pierce_seen and a.get('in_position'):
                    self.beam_open = True
                if self.pierce_seen and a.get('ready_to_move') and sub in (SUB_NONE,
                                                                           SUB_THC_DELAY):
                    self._waited('pierce', now_s)
                    c = log.contours[-1]
                    c['ready_after_s'] = round(now_s - self.pierce_t, 4)
                    c['moved_before_ready_mm'] = round(self.moved_mm, 4)
                    if self.moved_mm > MOVED_MM:
                        log.moved_before_ready += 1
                    self.at_speed = True
                    self.phase = 'cut'
                elif now_s - self.pierce_t > self.p.wait_timeout_s:
                    self.abort(f'waited {self.p.wait_timeout_s:g} s for the pierce (contour '
                               f'{self.contour}, line {s.program_line})', now_s,
                               code='wait_timeout')
                if not spindle:  # M5 before the pierce was done (a program without a cut)
                    self.phase, self.contour = 'between', 0
                    self.at_speed = self.beam_open = False
            elif self.phase == 'cut' and not spindle:  # M5: the contour's end
                log.contours[-1]['end_line'] = prev.program_line if prev is not None else 0
                self.at_speed = self.beam_open = False
                self.contour = 0
                self.phase = 'between'
                self.rapid_started = False
                if not self.p.leapfrog and following:
                    cmds.append(self._lift())
                    self.lift_hold = True
                    self.t_wait = now_s
                    self.lift_xy, self.moved_lift_mm = (s.x_mm, s.y_mm), 0.0
            if self.lift_hold:
                self.moved_lift_mm = max(self.moved_lift_mm, math.hypot(
                    s.x_mm - self.lift_xy[0], s.y_mm - self.lift_xy[1]))
                if a.get('in_position') and sub == SUB_LIFT:
                    self.lift_hold = False
                    self._waited('lift in position', now_s)
                    log.contours[-1]['moved_during_lift_mm'] = round(self.moved_lift_mm, 4)
                    if self.moved_lift_mm > MOVED_MM:
                        log.moved_during_lift += 1
                elif now_s - self.t_wait > self.p.wait_timeout_s:
                    self.abort(f'waited {self.p.wait_timeout_s:g} s for the lift', now_s,
                               code='wait_timeout')
            if self.phase in ('pierce', 'cut') and log.contours and not log.contours[-1]['line']:
                log.contours[-1]['line'] = s.program_line  # 0 until the cut's first move
            # a rapid: leapfrog at its start (the controller following)
            traverse = s.motion_type == p.MOTION_TRAVERSE and s.distance_to_go_mm > 0.0
            if (traverse and not self.rapid_started and self.phase == 'between'
                    and self.p.leapfrog and following):
                length = s.distance_to_go_mm
                t = rapid_time_s(length, self.rapid_mm_s, self.accel_mm_s2)
                if math.isfinite(t) and t > 0:
                    cmds.append(('leapfrog', {'lift_mm': self.p.lift_mm,
                                              'rapid_length_mm': length,
                                              'rapid_feed_mm_s': length / t,
                                              'arrive_height_mm': self.p.pierce_heights_mm[0]}))
                    log.leapfrogs += 1
            if traverse:
                self.rapid_started = True
            elif s.motion_type != p.MOTION_TRAVERSE:
                self.rapid_started = False
            # M62/M64 P2: hold the height; M63/M65: release
            thc_off = s.flag(p.F_THC_OFF) and self.p.hold_on_thc_off
            if thc_off and not self.holding and self.phase in ('cut', 'pierce', 'between'):
                self.holding = True
                log.holds += 1
                cmds.append(('hold', {'hold': True, 'at_next_segment': False,
                                      'reason': f'LinuxCNC M62/M64 P2 (line {s.program_line})'}))
            elif not thc_off and self.holding:
                self.holding = False
                cmds.append(('hold', {'hold': False, 'at_next_segment': False,
                                      'reason': 'LinuxCNC M63/M65 P2'}))
            # the program's end
            if self.ran and not running and self.phase not in ('aborted',):
                if log.pierces == 0:  # nothing cut: never a finished job
                    self.abort('the program ended without a cut: 0 pierces (no M3, no '
                               'o<touchoff> call reached)', now_s, pause=False, code='no_cut')
                else:
                    self.phase = 'done'
                    log.finished = True
                    self.end_t = now_s
                self.at_speed = self.beam_open = False
                self.contour = 0
        cmds += self.end_step(a, now_s)

        # ---- outputs ------------------------------------------------------------------------
        faulted = state == FAULT or self.phase == 'aborted'
        ready = (alive and int(a.get('gap_seq', 0)) > 0 and state != FAULT
                 and self.phase not in ('aborted',))
        flags = 0
        if self.at_speed and spindle and not faulted:
            flags |= p.O_AT_SPEED
        beam = (self.beam_open and spindle and not s.flag(p.F_TORCH_OFF) and not faulted
                and self.phase in ('pierce', 'cut'))
        if beam:
            flags |= p.O_BEAM
        hold = (faulted or bool(a.get('feed_hold_request')) or self.lift_hold
                or (self.ran and self.phase not in ('done',) and not alive))
        if hold:
            flags |= p.O_FEED_HOLD
        if ready:
            flags |= p.O_HEIGHT_READY
        r = a.get('feed_override_request', 1.0)
        adaptive = (min(max(float(r), 0.05), 1.0) if self.p.honour_override
                    and isinstance(r, (int, float)) and math.isfinite(r) else 1.0)
        self.seq += 1
        outputs = p.HalOutputs(self.seq, adaptive, flags, self.pause_count)
        return StepOut(self.motion(s, adaptive), outputs, cmds)

    def end_step(self, answers: dict[str, Any] | None, now_s: float
                 ) -> list[tuple[str, dict[str, Any]]]:
        """Return the end's commands: stop the follow at once (finished) or after an abort's lift.

        Called with every sample, and without one once LinuxCNC is gone. A FAULT's retract is
        the controller's: nothing is sent then.
        """
        if self.end_t < 0 or self.stop_sent:
            return []
        a = answers or {}
        lifted = (a.get('in_position') and int(a.get('substate', 0)) == SUB_LIFT
                  and a.get('velocity_mm_s', 0.0) == 0.0)
        if self.phase == 'done' or (self.lift_after_abort and (
                lifted or now_s - self.end_t > self.p.wait_timeout_s)):
            self.stop_sent = True
            return [('stop_follow', {})]
        return []

    def motion(self, s: p.LcncSample, adaptive: float) -> dict[str, Any]:
        """Return the ``CncMotion`` values of sample ``s`` (docs/linuxcnc.md has the mapping)."""
        running = s.flag(p.F_RUNNING) or s.flag(p.F_PAUSED)
        if not running or self.phase in ('idle', 'done'):
            segment = SEG_NONE
        elif self.phase == 'pierce':
            segment = SEG_PIERCE
        elif s.motion_type == p.MOTION_TRAVERSE:
            segment = SEG_RAPID
        elif s.motion_type in (p.MOTION_FEED, p.MOTION_ARC):
            segment = SEG_CUT
        else:
            segment = SEG_NONE
        requested = s.requested_vel_mm_s
        if self.rapid_mm_s > 0:
            requested = min(requested, self.rapid_mm_s)
        commanded = requested * (s.feed_override if math.isfinite(s.feed_override) else 1.0)
        if segment == SEG_CUT:
            commanded *= adaptive
        if s.flag(p.F_FEED_HOLD_IN) or s.flag(p.F_PAUSED):  # LinuxCNC's net feed scale is 0
            commanded = 0.0
        return {'x_mm': s.x_mm, 'y_mm': s.y_mm, 'commanded_feed_mm_s': max(commanded, 0.0),
                'actual_feed_mm_s': max(s.actual_vel_mm_s, 0.0), 'segment': segment,
                'beam_on': s.flag(p.F_BEAM_GATE), 'contour': self.contour,
                'segment_left_mm': max(s.distance_to_go_mm, 0.0), 'edge_ahead_mm': math.inf}

    def end_ready(self, answers: dict[str, Any] | None, now_s: float) -> bool:
        """Return whether the job's log can go out.

        Once the controller commands zero (after an abort's lift: once the follow is stopped)
        and, after a FAULT, once LinuxCNC's samples showed its feed held (the log says how soon;
        a loaded machine's component can be tens of ms late), or ``end_timeout_s`` after the
        end at the latest.
        """
        if self.end_t < 0:
            return False
        limit = self.p.end_timeout_s + (self.p.wait_timeout_s if self.lift_after_abort else 0.0)
        if now_s - self.end_t > limit:
            return True
        if self.fault_logged is not None and 'feed_hold_after_ms' not in self.fault_logged:
            return False
        if self.lift_after_abort and not self.stop_sent:
            return False
        zero = answers is not None and answers.get('velocity_mm_s', 0.0) == 0.0
        return zero and now_s - self.end_t >= 0.01
