"""The follow state machine (notes §3.5 ``Follow_OnStep``): one tick function per state.

:data:`TICK` maps each state to the function that runs its tick; every change of state passes
:meth:`FollowController.enter`, which refuses a (from, to) pair not in
:data:`.states.TRANSITIONS`. The helpers return verdicts (:mod:`.input_gate`, the edge guard)
and commands (:mod:`.limiter`); only this module changes the state.

* LOCKING (seed ``Locking_OnStep``, not in the notes): command 0 until the inputs are fresh and
  valid and the drive is enabled and unfaulted, then initialise and approach.
* PREINTERPOLATE (seed): every tick ``Interp_GoDistance(target − gap − cached length)``; the
  interpolator's velocity is the command; the PID runs alongside from the interpolator's
  velocity (``FollowPID_SetPreOutUnitV``) and takes over when the seed's rule holds
  (``nDir·nNextAcc < 0 && |nNextAcc| ≤ acc && |err| ≤ 1 mm``) or, so the phase cannot get
  stuck, when the interpolation has finished within the window.
* PID (seed ``FS_PID_CONTROL``): PID follow with feed-forward; "followed" = in position for the
  hold time. The seed re-initialises the LADRC every PID tick from the PID output and the
  reading (``InitLADRC(height, height, pidOut)``); :meth:`LADRC.reset` is memoryless, so the
  machine re-initialises it once, at the switch, from the previous tick's reading and output:
  the identical state, without paying a reset on every PID tick.
* LADRC: ``UpdateLADRC`` once followed and (seed) not machining; ``ladrc_while_machining``
  lifts the machining restriction.

Every output passes the one limiter (:class:`.limiter.OutputLimiter`), so no hand-over steps the
velocity by more than a_max·h. Invalid or stale data never reaches PID/LADRC: the input gate
runs before either is stepped. docs/follow-state-machine.md gives the decisions taken where the
seed is silent, and its diagram is drawn from the transition table.
"""

from __future__ import annotations

from dataclasses import replace
import math
from typing import Any, Callable, NamedTuple

from ladrc_contract.codes import FaultCode
from ladrc_contract.ops import SCALAR

from ..edge import EDGE, FALLING, HOLD, VERIFY, EdgeGuard
from ..follow_params import FollowParams
from ..interp import Interpolator, InterpParams
from ..kalman import kalman_gated_step
from ..ladrc import LADRC
from ..params import ControllerParams, check
from ..pid import FollowPID
from ..target_wave import TargetWave
from ..void_lock import VoidLock
from . import input_gate as gate
from .cnc import CncPartner
from .commands import TABLE, CommandView, projected_state
from .input_gate import InputGate
from .limiter import OutputLimiter
from .states import (
    FAULT,
    IDLE,
    LIMIT_ACCELERATION,
    LIMIT_ESO_STATE,
    LIMIT_VELOCITY,
    LOCKING,
    PID,
    PREINTERPOLATE,
    SOURCE_INTERP,
    SOURCE_LADRC,
    SOURCE_NONE,
    SOURCE_PID,
    TRANSITIONS,
    FollowState,
)
from .states import (
    LADRC as LADRC_STATE,
)

_COLLISION_CODE, _NOT_FOLLOWED, _DRIVE, _START = (int(c) for c in (
    FaultCode.COLLISION, FaultCode.NOT_FOLLOWED, FaultCode.DRIVE, FaultCode.START))
_PID_KALMAN_RESET = (math.nan, 0.0, 0, 0.0)  # the PID's Kalman filter restarts on the next reading


def _ticks(t_s: float, h_s: float) -> int:
    return max(1, int(round(t_s / h_s)))


class PreparedSet(NamedTuple):
    """A checked parameter set, its controller parts built (:meth:`FollowController.prepare`)."""

    params: ControllerParams
    follow: FollowParams
    ladrc: LADRC | None
    pid: FollowPID
    interp: Interpolator


def _build(params: ControllerParams | None, follow: FollowParams | None,
           mode: str | None = None) -> PreparedSet:
    params = params if params is not None else ControllerParams()
    if follow is not None:
        params = replace(params, follow=follow)
    if mode is not None:
        params = replace(params, follow=replace(params.follow, controller=mode))
    check(params)  # the whole set (ParameterError is a ValueError)
    return PreparedSet(params, params.follow, LADRC(params), FollowPID(params.pid, params.h_s),
                       Interpolator(params.interp, params.h_s))


class FollowController:
    """Follow state machine driving PID / LADRC; ``step(tick) -> velocity_mm_s``.

    ``command(name, **kwargs) -> (accepted, message)`` queues a follow command (applied at the
    start of the next :meth:`step`), ``set_params`` queues a parameter set likewise, so a
    replay that re-issues the same commands before the same ticks reproduces the commands
    bit for bit. ``follow`` overrides ``params.follow``; ``mode`` ('ladrc' | 'pid') overrides
    ``follow.controller`` (also for later :meth:`set_params`).

    Every set, at construction and in :meth:`set_params`, is validated as a whole; the
    stability gate (``ladrc_follow.analysis.gate``) is its caller's: the node gates what it
    runs, replay and the suite's study variants reproduce sets as they were.
    """

    def __init__(self, params: ControllerParams | None = None,
                 follow: FollowParams | None = None, *, mode: str | None = None) -> None:
        self.counts = {'predicted': 0, 'frozen': 0, 'jump': 0, 'invalid': 0,
                       'out_of_range': 0, 'nonfinite': 0, 'fall_hold': 0, 'sink_hold': 0,
                       'verify': 0, 'edge_hold': 0, 'void_lock': 0}
        """Ticks run on the encoder-predicted gap, samples rejected per cause, void locks."""
        self._void = VoidLock(self.counts)  # one lock for the gate's jump and the guard's fall
        self._input_gate = InputGate(self.counts, self._void)
        self._partner = CncPartner()  # the CNC interface (.cnc)
        self._limiter = OutputLimiter()
        self._pending: list[tuple[str, dict]] = []
        self._pending_build: PreparedSet | None = None
        self._mode = mode  # 'ladrc' | 'pid' overrides follow.controller (CLI --controller)
        self._install(_build(params, follow, mode))
        self._state = IDLE
        self._tick = -1
        self._u = 0.0            # last applied command (mm/s)
        self._u_unlimited = 0.0
        self._flags = 0
        self._source = SOURCE_NONE  # where this tick's command came from
        self._override = math.nan  # edge guard: a verification's command, -inf up only
        self._target = math.nan  # commanded target (without compensation)
        self._offset = 0.0       # active height compensation
        self._target_eff = math.nan
        self._machining = False
        self._followed = False
        self._fault_reason = ''
        self._fault_code = 0  # FaultCode of the present FAULT (0: none)
        self._comp: list[tuple[int, float]] = []  # (due tick, offset)
        self._gradients: list[tuple[int, float, float, float]] = []  # (due, target, v, a)
        self._wave: TargetWave | None = None  # test signal on the target (seed SIN_GEN)
        self._closing = False  # a step run by the law (reinterpolate false) is closing in
        self._pid_kalman_state = _PID_KALMAN_RESET  # the PID's Kalman x, P, outliers, encoder
        self._wave_k = 0
        self._retracting = False
        self._retracted = False  # a retract has run since the fault latched
        self._retract: Interpolator | None = None
        self._last_gap = math.nan
        self._last_enc = math.nan
        self._level = math.nan  # sheet level (encoder − gap) at the last followed, unheld tick
        self._drive_bad = False
        self._lock_ticks = 0
        self._lock_ok = False
        self._inpos_ticks = 0
        self._approach_ticks = 0
        self._dir = 1.0
        self._enc0 = 0.0
        self._enc_now = 0.0  # encoder position of this tick (soft travel limits)
        self._reapproach = False  # a lift or leapfrog ended: approach at the next usable tick

    # ------------------------------------------------------------------ parameters
    def _install(self, b: PreparedSet) -> None:
        p, f = b.params, b.follow
        h = p.h_s
        self.params, self.follow_params = p, f
        self._ladrc = b.ladrc
        self._ladrc_step = b.ladrc.step
        self._pid = b.pid
        self._interp_default = b.interp
        self._interp = b.interp
        self._h = h
        self._limiter.configure(p.limits, h)
        self._input_gate.configure(f, h)
        e = p.edge
        self._void.configure(f.jump_mm, f.jump_confirm_s, e.fall_mm_s, e.fall_tau_s,
                             e.void_lock_ticks, e.void_unlock_ticks, h)
        self._partner.configure(p, h)
        self._pid_du = p.pid.a_max_mm_s2 * h
        self._use_ladrc = f.controller == 'ladrc'
        self._lag_comp = f.approach_lag_compensation
        self._ladrc_machining = f.ladrc_while_machining
        self._window = f.handover_window_mm
        self._retarget = f.retarget_threshold_mm if f.reinterpolate else math.inf
        self._retarget_mm = f.retarget_threshold_mm
        self._target_lim = (f.min_target_gap_mm, f.max_target_gap_mm)
        kp = p.kalman
        # the gated Kalman filter on the PID's gap too (kalman.on_pid; control/kalman.py)
        self._pid_kalman = kp.enabled and kp.on_pid
        self._pid_kalman_consts = (kp.q_mm2, kp.r_mm2, kp.p0_mm2, kp.gate_mm,
                                   float(kp.gate_confirm_ticks))
        self._tol = p.pid.followed_tol_mm
        self._wide_tol = f.followed_wide_tol_mm
        self._hold_ticks = max(1, int(round(p.pid.followed_hold_s / h)))
        self._widen_ticks = _ticks(f.followed_widen_s, h)
        self._timeout_ticks = _ticks(f.followed_timeout_s, h)
        self._lock_max = _ticks(f.locking_timeout_s, h)
        old_guard = getattr(self, '_guard', None)
        self._guard = EdgeGuard(p.edge, h, self._void)
        if old_guard is not None:
            self._guard.carry_over(old_guard)  # what this follow verified stays verified
        ext = p.eso.disturbance_limit
        self._ext_limit = ext if ext > 0.0 else math.inf

    def set_params(self, params: ControllerParams, follow: FollowParams | None = None) -> None:
        """Queue a new parameter set; it takes effect at the next tick boundary, bumplessly.

        Raises ValueError (``ParameterError``) naming every problem if the set is invalid;
        the running set is then unchanged.
        """
        self._pending_build = self.prepare(params, follow)

    def prepare(self, params: ControllerParams, follow: FollowParams | None = None
                ) -> PreparedSet:
        """Check and build ``params`` for :meth:`set_prepared`; raises like :meth:`set_params`.

        Touches no state of the running controller, so a node does it off its loop thread:
        the build takes milliseconds, a tick has 0.5 ms (the follow node's parameter thread).
        """
        return _build(params, follow, self._mode)

    def set_prepared(self, prepared: PreparedSet) -> None:
        """Queue a set built by :meth:`prepare`: it takes effect at the next tick, bumplessly."""
        self._pending_build = prepared

    def _swap_params(self) -> None:
        b, self._pending_build = self._pending_build, None
        old_interp, custom = self._interp, self._interp is not self._interp_default
        self._install(b)
        self._pid_kalman_state = _PID_KALMAN_RESET  # the PID's filter restarts with the set
        st, u = self._state, self._u
        gap, enc, target = self._last_gap, self._last_enc, self._target_eff
        if custom:
            self._interp = old_interp  # a gradient move keeps its own v/a
        elif st == PREINTERPOLATE:
            self._interp.reset(u)
            self._interp.go_distance(old_interp.cached_length_mm)
        if st in (PREINTERPOLATE, PID, LADRC_STATE) and math.isfinite(gap):
            enc_ = enc if math.isfinite(enc) else None
            self._pid.reset(gap, target, u, enc_)
            if st == PID:
                self._pid_modes()
            self._ladrc.reset(gap, u, target, enc_)

    # ------------------------------------------------------------------ properties
    @property
    def state(self) -> FollowState:
        """Current state."""
        return FollowState(self._state)

    @property
    def projected_state(self) -> FollowState:
        """Return the state once the queued commands apply at the next tick."""
        return FollowState(projected_state(self._state, self._pending))

    @property
    def followed(self) -> bool:
        """In position within tolerance for the hold time since the last approach (随动到位)."""
        return self._followed

    @property
    def fault_reason(self) -> str:
        """Why the controller is in FAULT ('' otherwise)."""
        return self._fault_reason

    @property
    def fault_code(self) -> int:
        """The :class:`~ladrc_contract.codes.FaultCode` of the present FAULT (0 otherwise)."""
        return self._fault_code

    @property
    def target_gap_mm(self) -> float:
        """Follow target incl. the active height compensation (NaN when not following)."""
        return self._target_eff

    @property
    def machining(self) -> bool:
        """Machining flag as last commanded."""
        return self._machining

    @property
    def velocity_mm_s(self) -> float:
        """The command of the last tick."""
        return self._u

    @property
    def enable(self) -> bool:
        """Drive enable bit: following, retracting, or still ramping a non-zero command down."""
        return PREINTERPOLATE <= self._state <= LADRC_STATE or self._retracting or self._u != 0.0

    # ------------------------------------------------------------------ commands
    def command(self, name: str, **kwargs: Any) -> tuple[bool, str]:
        """Queue a follow command for the next tick; return ``(accepted, message)``.

        ``start_follow(target_gap_mm)``, ``stop_follow()``, ``set_target(target_gap_mm)``,
        ``machining(on)``, ``height_compensation(offset_mm, delay_s=0)``,
        ``gradient_follow(target_gap_mm, delay_s, velocity_mm_s=0, accel_mm_s2=0)``,
        ``reset_fault()``, ``target_wave(kind='sine', amp_mm, freq_hz, freq_end_hz=0,
        duration_s=0)`` (a test signal on the target once followed, :mod:`..target_wave`;
        ``amp_mm`` 0 ends a running one). A rejected command changes nothing; the message
        says why (:mod:`.commands`).
        """
        entry = TABLE.get(name)
        if entry is None:
            return False, f'unknown command {name!r} (known: {", ".join(TABLE)})'
        extra = sorted(set(kwargs) - set(entry.args))
        if extra:
            return False, (f'{name}: unknown argument(s) {", ".join(extra)} '
                           f'(allowed: {", ".join(entry.args) or "none"})')
        view = CommandView(projected_state(self._state, self._pending), self.follow_params,
                           self.params, self._target, self._offset, self._fault_reason,
                           self._retracting, self._drive_bad, self._pending, self._level)
        why, message, kwargs = entry.check(view, kwargs)
        if why:
            return False, why
        self._pending.append((name, kwargs))
        return True, message

    def _apply_commands(self) -> None:
        pending, self._pending = self._pending, []
        for name, kw in pending:
            TABLE[name].apply(self, self._state, kw)

    def _stop(self, state: int) -> None:
        """Leave following: clear target, queues and caps (the command ramps to 0)."""
        self.enter(state)
        self._target = self._target_eff = math.nan
        self._offset = 0.0
        self._comp = []
        self._gradients = []
        self._followed = False
        self._wave = None
        self._closing = False
        self._limiter.uncap()
        self._partner.stop()
        self._reapproach = False
        self._level = math.nan

    def _end_lift(self) -> None:
        """End a lift or a leapfrog: the next usable reading starts an approach from there."""
        if self._partner.planned:
            self._partner.end_move()
            self._reapproach = True

    def _set_target(self, target: float) -> None:
        self._target = target
        self._change_target_eff(target + self._offset)

    def _change_target_eff(self, eff: float) -> None:
        old, self._target_eff = self._target_eff, eff
        self._wave = None  # any change of the target ends a test wave (it was checked on it)
        st = self._state
        if self._reapproach:
            return  # an approach starts at the next usable reading anyway (a lift ended)
        if (st == PID or st == LADRC_STATE) and abs(eff - old) > self._retarget:
            # seed comment in FS_PID_CONTROL: a large change is smoother interpolated
            self._enter_approach(self._last_gap, self._last_enc, None)
        elif (st == PID or st == LADRC_STATE) and abs(eff - old) > self._retarget_mm:
            # follow.reinterpolate false (seed): the law runs the step; the closing in is
            # measured as on an approach (edge guard) until the gap reaches the target
            self._closing = True

    # ------------------------------------------------------------------ transitions
    def enter(self, state: int) -> None:
        """Change the state; a (from, to) pair outside :data:`.states.TRANSITIONS` raises."""
        if (self._state, state) not in TRANSITIONS:
            raise RuntimeError(f'transition {FollowState(self._state).name} -> '
                               f'{FollowState(state).name} is not in the transition table')
        self._state = state

    def _enter_approach(self, gap: float, enc: float, va: tuple[float, float] | None) -> None:
        """Enter PREINTERPOLATE from the applied command (seed ``InitPreInterpolate``)."""
        h = self._h
        if va is None:
            self._interp = self._interp_default
            self._limiter.uncap()
        else:
            self._interp = Interpolator(InterpParams(va[0], va[1]), h)
            # seed FollowPID_SetSpeedCtrlParam: the gradient's v/a bound the PID until followed
            self._limiter.cap(va[0], va[1] * h)
        self._interp.reset(self._u)
        self._enc0 = enc
        target = self._target_eff
        self._guard.reset(gap - target)
        self._pid_kalman_state = _PID_KALMAN_RESET
        self._wave = None  # a re-approach ends a test wave
        self._closing = False
        self._dir = 1.0 if target >= gap else -1.0
        pid = self._pid
        pid.reset(gap, target, self._u, enc)
        pid.set_suppress(False)
        self.enter(PREINTERPOLATE)
        self._followed = False
        self._inpos_ticks = 0
        self._approach_ticks = 0

    def _fault(self, reason: str, retract: bool = False, code: int = 0) -> float:
        self._stop(FAULT)
        self._fault_reason = reason
        self._fault_code = code or (_COLLISION_CODE if retract else _NOT_FOLLOWED)
        if self._u < 0.0:
            self._u = 0.0  # safety: motion toward the sheet stops at once, upward may ramp
        self._retracted = retract
        if retract:
            f = self.follow_params
            lim = self.params.limits
            self._retract = Interpolator(InterpParams(
                min(f.retract_velocity_mm_s, lim.v_max_mm_s), lim.a_max_mm_s2), self._h)
            self._retract.reset(self._u)
            self._retract.go_distance(f.retract_distance_mm)
            self._retracting = True
        return self._fault_out(False)

    def _drive_fault(self, dfault: bool) -> float:
        # The drive no longer executes commands (it stops on its own ramp): command 0 at once,
        # so nothing is pending when it comes back.
        self._stop(FAULT)
        self._fault_reason = ('drive fault reported by the drive: command 0' if dfault else
                              'drive disabled during follow: command 0')
        self._fault_code = _DRIVE
        self._retracting = False
        return self._out_zero()

    def fail(self, reason: str, code: int = FaultCode.INTERNAL) -> float:
        """Enter FAULT with a zero command now (exceptions, non-finite values); return 0.0.

        ``code``: the :class:`FaultCode` (default INTERNAL; the node's own faults name theirs).
        """
        self._stop(FAULT)
        self._fault_reason = reason
        self._fault_code = int(code)
        self._retracting = False
        return self._out_zero()

    # ------------------------------------------------------------------ output
    def _out_zero(self) -> float:
        self._u = self._u_unlimited = 0.0
        self._flags = 0
        self._source = SOURCE_NONE
        return 0.0

    def _limit(self, u_c: float) -> float:
        """Limit the output (:class:`.limiter.OutputLimiter`); a non-finite one is a FAULT."""
        if not math.isfinite(u_c):  # nan or ±inf from a law: no limiter may hide it
            self.counts['nonfinite'] += 1
            return self.fail(f'non-finite command ({u_c!r}) in state '
                             f'{FollowState(self._state).name}')
        u, self._flags = self._limiter.limit(u_c, self._u, self._enc_now)
        self._u_unlimited = u_c
        self._u = u
        return u

    def _ramp_to_zero(self) -> float:
        self._source = SOURCE_NONE
        return self._limit(0.0)

    def _fault_out(self, drive_bad: bool) -> float:
        if self._retracting:
            if drive_bad:
                self._retracting = False
                return self._out_zero()
            # a retract only moves up: the planner's rounding residue of its last tick
            # (~1e-13 mm/s either way) must not become a command toward the sheet
            v = max(self._retract.step(), 0.0)
            if self._retract.is_finished():
                self._retracting = False
            self._source = SOURCE_NONE
            return self._limit(v)
        if drive_bad:
            return self._out_zero()
        return self._ramp_to_zero()

    # ------------------------------------------------------------------ tick
    def step(self, tick: tuple, cnc: tuple | None = None) -> float:
        """One tick: return the velocity command in mm/s (+ = up, widens the gap).

        ``cnc``: the CNC's motion sample this tick uses (:class:`~ladrc_contract.tick.CncInput`;
        None: none new, the last one holds).

        Every exception inside the tick and every non-finite command ends in FAULT with a zero
        command (:meth:`fail`): the caller always gets a finite number.
        """
        try:
            self._tick += 1
            if self._pending_build is not None:
                self._swap_params()
            if self._pending:
                self._apply_commands()
            partner = self._partner
            partner.begin(self._state == IDLE)
            partner.motion(tick[0], cnc)
            if len(tick) != 9:
                tick = (*tick, 0)  # an 8-field tick (the sim runner's): status not reported
            self._drive_bad = not tick[6] or tick[7]
            enc = tick[4]
            if math.isfinite(enc):
                self._enc_now = enc  # for the soft travel limits (the last finite position)
            u = TICK[self._state](self, tick)
        except Exception as exc:  # noqa: BLE001 - any bug must end in a zero command
            return self.fail(f'exception in the controller tick: {type(exc).__name__}: {exc}')
        if not math.isfinite(u):
            self.counts['nonfinite'] += 1
            return self.fail(f'non-finite command ({u!r}) in state '
                             f'{FollowState(self._state).name}')
        return u

    def _tick_idle(self, tick: tuple) -> float:
        if self._u < 0.0:
            self._u = 0.0  # not following: nothing moves toward the sheet
        return self._ramp_to_zero()

    def _tick_fault(self, tick: tuple) -> float:
        drive_bad = self._drive_bad
        if not (self._retracted or drive_bad) and self._input_gate.collision_evidence(
                tick[1], tick[2], tick[8]):
            # collision evidence retracts in every state, FAULT included: once per fault
            # (a sensor stuck low must not walk the axis up without end)
            first = self._fault_reason.split(';')[0]
            return self._fault(f'collision while in FAULT ({first}): gap reading '
                               f'{tick[1]:.3f} mm, status {tick[8]}; retracting '
                               f'{self.follow_params.retract_distance_mm:g} mm', True)
        return self._fault_out(drive_bad)

    def _tick_locking(self, tick: tuple) -> float:
        verdict, why = self._input_gate.lock(tick)
        if verdict == gate.COLLISION:
            return self._fault(why, True)
        if verdict == gate.USABLE:
            if self._lock_ok:
                # seed Locking_IsFinished -> PREINTERPOLATE (InitPreInterpolate there)
                gap, enc = tick[1], tick[4]
                self._enter_approach(gap, enc, None)
                if self._guard.verifying:
                    return self._move_up(0.0, enc)  # the gain is verified before closing in
                return self._approach(gap, enc)
            # usable inputs on two consecutive ticks: one tick to initialise, then approach
            self._lock_ok = True
            return self._ramp_to_zero()
        self._lock_ok = False
        self._lock_ticks += 1
        if self._lock_ticks >= self._lock_max:
            return self._fault(f'start_follow failed: {why} '
                               f'(LOCKING timeout {self.follow_params.locking_timeout_s:g} s)',
                               code=_START)
        return self._ramp_to_zero()

    def _tick_planned(self, tick: tuple) -> float:
        """Run a tick of a lift or a leapfrog: the plan's command; the law is not stepped.

        Only the drive, the encoder and collision evidence are screened (a rapid crosses
        holes, a lift may leave the sensor's range); the follow resumes with an approach
        (:meth:`_end_lift`).
        """
        ig = self._input_gate
        verdict = ig.screen_axis(tick)
        if verdict != gate.USABLE:
            if verdict == gate.DRIVE:
                return self._drive_fault(tick[7])
            return self._fault(ig.reason, verdict == gate.COLLISION, ig.code)
        gap = tick[1] if (tick[2] and not tick[8]) else math.nan
        u = self._limit(self._partner.planned_velocity(tick[4], gap))
        self._source = SOURCE_NONE
        return u

    def _tick_following(self, tick: tuple) -> float:
        """PREINTERPOLATE, PID, LADRC: the input gate, a due gradient, the edge guard, the law."""
        if self._partner.planned:
            return self._tick_planned(tick)
        ig = self._input_gate
        verdict = ig.screen(tick)
        if verdict != gate.USABLE:
            if verdict == gate.HOLD:  # a jump (the void lock) or a reading not usable yet
                self._partner.void_lock(ig.reason)
                return self._hold_up_only()
            if verdict == gate.DRIVE:
                return self._drive_fault(tick[7])
            return self._fault(ig.reason, verdict == gate.COLLISION, ig.code)
        gap, enc = ig.gap_mm, tick[4]
        if self._reapproach:  # after a lift or a leapfrog: from the gap as it is now
            self._reapproach = False
            self._enter_approach(gap, enc, None)
        if self._gradients and self._gradients[0][0] <= self._tick:
            _, gt, gv, ga = self._gradients.pop(0)
            self._target = gt
            self._target_eff = gt + self._offset
            # seed: gradient -> LOCKING -> PREINTERPOLATE with the gradient's speed/acc
            self._enter_approach(gap, enc, (gv, ga))
        u = self._edge_verdict(gap, enc)
        if u is not None:
            return u
        if self._partner.active:
            u = self._cnc_verdict(gap, enc)
            if u is not None:
                return u
        if self._state == PREINTERPOLATE:
            return self._approach(gap, enc)
        if self._comp and self._comp[0][0] <= self._tick:
            self._offset = self._comp.pop(0)[1]  # seed UpdateCompHeightQueue
            self._change_target_eff(self._target + self._offset)
            if self._state == PREINTERPOLATE:
                return self._approach(gap, enc)
        prev_gap, prev_enc = self._last_gap, self._last_enc
        self._last_gap, self._last_enc = gap, enc
        why = self._guard.far_drop(enc, gap)
        if why:  # held as an edge from this tick (edge.py): nothing further down
            self._edge_hold(why, gap)
        elif self._followed and not self._partner.holding and self._override != self._override:
            self._level = enc - gap  # a locked pierce's level (CncPartner.start_locked)
        return LAW[self._state](self, gap, enc, self._law_target(gap), prev_gap, prev_enc)

    def _edge_verdict(self, gap: float, enc: float) -> float | None:
        """Act on the edge guard's verdict: a command that ends the tick, or None (go on)."""
        st = self._state
        guard = self._guard
        # closing in is measured until followed (approach, then the PID's first settling)
        verdict = guard.update(self._tick * self._h, enc, gap,
                               st == PREINTERPOLATE or not self._followed
                               or self._closing or self._wave is not None,
                               self._target_eff, self._input_gate.fresh)
        if verdict == FALLING:
            # faster than a sheet falls: not followed down; closing in afterwards is probed
            self.counts['fall_hold'] += 1
            self._partner.void_lock(self._void.reason)
            if not self._followed:
                self._approach_ticks += 1  # held time counts toward the not-followed alarm
                if self._approach_ticks >= self._timeout_ticks:
                    return self._fault(self._timeout_reason(gap - self._target_eff))
            return self._hold_up_only()
        # the law keeps running under an override (its observer fed the applied command): it
        # resumes bumplessly however long the override lasts
        self._override = math.nan
        if (verdict == HOLD or verdict == VERIFY) and self._u < 0.0:
            self._u = 0.0  # nothing further down at once: the sink is evidence enough
        if verdict == HOLD:
            # sunk below the verified level while too fast to verify (or where a verification
            # could not tell): not followed further down
            self.counts['sink_hold'] += 1
            self._partner.void_lock('sunk below the verified level too fast to verify: held')
            if st == PREINTERPOLATE:
                return self._hold_up_only()
            self._override = -math.inf  # up only
        elif verdict == VERIFY:
            # the apparent surface sank below its last verified level (or a follow starts
            # close to its target): a short move up measures the feedback gain
            self.counts['verify'] += 1
            if st == PREINTERPOLATE:
                return self._move_up(guard.verify_velocity_mm_s, enc)
            self._override = guard.verify_velocity_mm_s
        if verdict == EDGE:
            held = self._edge_hold(guard.reason, gap)
            if held is not None:
                return held
        self._limiter.down_cap_mm_s = guard.down_cap_mm_s
        return None

    def _edge_hold(self, reason: str, gap: float) -> float | None:
        """Hold at an edge until the guard finds the nozzle over the sheet again (edge.py).

        Only commands away from the sheet; not a latched FAULT. Return the tick's command when
        the hold ends the tick (the approach), else None (the law runs on, overridden).
        """
        self.counts['edge_hold'] += 1
        self._partner.void_lock(reason)
        if self._u < 0.0:
            self._u = 0.0
        if self._state == PREINTERPOLATE:
            # the approach is not stepped while held: its time counts toward the not-followed
            # alarm here (the PID counts its own, held or not)
            self._approach_ticks += 1
            if self._approach_ticks >= self._timeout_ticks:
                return self._fault(f'{self._timeout_reason(gap - self._target_eff)}; {reason}')
            return self._hold_up_only()
        self._override = -math.inf
        return None

    def _cnc_verdict(self, gap: float, enc: float) -> float | None:
        """Act on the CNC partner's verdict (.cnc): a command that ends the tick, or None.

        A pierce stage changes the target; a lift overrides the law with its move up; a hold
        (corner lock, edge ahead, dwell, THC delay, commanded) passes only commands away from
        the sheet, the law running on (as the edge guard's hold).
        """
        p = self._partner
        st = self._state
        settled = (st == PID or st == LADRC_STATE) and self._followed
        new_target = p.judge(self._tick * self._h, gap, self._target_eff, settled)
        if (st == PID or st == LADRC_STATE) and p.stale_lift_due(self._tick * self._h):
            # the CNC is gone (silent for cnc.stale_lift_s): the head goes up and stays there
            p.start_lift(p.p.stale_lift_mm, 0.0, self._u)
            p.reason = (f'CNC silent for {p.p.stale_lift_s:g} s: lifting by '
                        f'{p.p.stale_lift_mm:g} mm')
            return self._hold_up_only()
        if new_target == new_target:  # a pierce stage (checked against the limits at accept)
            self._set_target(new_target)
            st = self._state
        if p.holding:
            if st == PREINTERPOLATE:
                return self._hold_up_only()
            if self._override != self._override:  # the edge guard's own override goes first
                self._override = -math.inf
        return None

    def _law_target(self, gap: float) -> float:
        """PID and LADRC: this tick's target (with the test wave, ``follow.target_wave``)."""
        target = self._target_eff
        if self._closing and abs(gap - target) <= self._tol:
            self._closing = False
        if self._wave is not None and self._followed and not self._machining:
            # seed SIN_GEN: the test signal rides on the target once followed, not machining;
            # never outside the allowed gaps, whatever changed since it was accepted
            wave = self._wave
            lo, hi = self._target_lim
            target = min(max(target + wave.value_mm(self._wave_k * self._h), lo), hi)
            self._wave_k += 1
            if self._wave_k * self._h >= wave.length_s:
                self._wave = None
        return target

    def _law_pid(self, gap: float, enc: float, target: float, prev_gap: float,
                 prev_enc: float) -> float:
        """PID: followed (in position for the hold time), then the switch to the LADRC."""
        if not self._followed:
            tol = self._tol if self._approach_ticks < self._widen_ticks else self._wide_tol
            if abs(gap - target) <= tol:
                self._inpos_ticks += 1
            else:
                self._inpos_ticks = 0
            if self._inpos_ticks >= self._hold_ticks:
                self._followed = True
                if self._limiter.capped:  # seed: GRADIENT_FOLLOWING -> IDLE, speed params back
                    self._limiter.uncap()
            else:
                self._approach_ticks += 1
                if self._approach_ticks >= self._timeout_ticks:
                    return self._fault(self._timeout_reason(gap - target))
        if (self._followed and self._use_ladrc
                and (self._ladrc_machining or not self._machining)):
            # seed: InitLADRC(height, height, pidOut) of the previous PID tick
            self._ladrc.reset(prev_gap, self._u, target, prev_enc)
            self.enter(LADRC_STATE)
            return self._ladrc_tick(gap, enc, target)
        return self._pid_tick(gap, enc, target)

    def _law_ladrc(self, gap: float, enc: float, target: float, prev_gap: float,
                   prev_enc: float) -> float:
        """LADRC: back to the PID when machining starts (unless allowed) or mode is pid."""
        if not self._use_ladrc or (self._machining and not self._ladrc_machining):
            # back to the PID, starting from the applied command (bumpless)
            self._pid.reset(prev_gap, target, self._u, prev_enc)
            self._pid_kalman_state = _PID_KALMAN_RESET
            self.enter(PID)
            return self._pid_tick(gap, enc, target)
        return self._ladrc_tick(gap, enc, target)

    # ------------------------------------------------------------------ the laws
    def _pid_modes(self) -> None:
        # seed FS_PID_CONTROL: feed-forward (after its delay) and suppression once followed
        # or when not machining; suppression while machining, off otherwise
        if self._followed or not self._machining:
            self._pid.set_suppress(self._machining)
            self._pid.enable_feed_forward(True)

    def _pid_gap(self, gap: float, enc: float) -> float:
        """Return the PID's gap: the reading, or its gated Kalman fusion (``kalman.on_pid``)."""
        if not self._pid_kalman:
            return gap
        x, p, n, enc_prev = self._pid_kalman_state
        q, r, p0, gate_mm, confirm = self._pid_kalman_consts
        if math.isnan(x):  # (re)start on the reading, as the LADRC's filter does at its reset
            self._pid_kalman_state = (gap, p0, 0, enc)
            return gap
        x, p, _, n = kalman_gated_step(SCALAR, x, p, n, gap, enc - enc_prev,
                                       self._input_gate.fresh, q, r, p0, gate_mm, confirm)
        self._pid_kalman_state = (x, p, n, enc)
        return x

    def _overridden(self, u_c: float, source: int) -> float:
        """Apply the edge guard's override to the law's command ``u_c``, then the limits."""
        ov = self._override
        self._source = source
        if not math.isnan(ov):
            if ov == -math.inf:
                u_c = u_c if u_c > 0.0 else 0.0  # hold: upward only
            else:
                u_c = ov  # a verification's move
            self._source = SOURCE_NONE
        return self._limit(u_c)

    def _pid_tick(self, gap: float, enc: float, target: float) -> float:
        self._pid_modes()
        pid = self._pid
        u = self._overridden(pid.step(self._pid_gap(gap, enc), enc, target), SOURCE_PID)
        if u != pid.u:
            pid.set_pre_out(u)
        return u

    def _ladrc_tick(self, gap: float, enc: float, target: float) -> float:
        u_c = self._ladrc_step(gap, enc, target, self._input_gate.fresh)
        u = self._overridden(u_c, SOURCE_LADRC)
        if u != u_c:
            self._ladrc.u = u  # the ESO must see the applied command
        return u

    def _approach(self, gap: float, enc: float) -> float:
        """PREINTERPOLATE: the interpolated approach, the PID alongside, the seed's hand-over."""
        self._last_gap, self._last_enc = gap, enc
        target = self._target_eff
        it = self._interp
        move = target - gap - it.cached_length_mm  # seed Interp_GoDistance
        if self._lag_comp:
            # the axis still owes the planned travel the encoder has not seen yet
            move -= it.position_mm - (enc - self._enc0)
        it.go_distance(move)
        v = it.step()
        pid = self._pid
        pid.set_pre_out(v)
        u_pid = pid.step(gap, enc, target)
        nxt = u_pid - v
        err = gap - target
        u = self._limit(v)
        self._source = SOURCE_INTERP
        if u != v:
            it.velocity_mm_s = u  # keep the plan on the applied command
        if abs(err) <= self._window and (
                (self._dir * nxt < 0.0 and abs(nxt) <= self._pid_du + 1e-9)
                or it.is_finished()):
            # seed hand-over: the PID restarts from the interpolator's velocity
            pid.set_pre_out(u)
            self.enter(PID)
            self._guard.surface_ref_mm = enc - gap  # the far drop's reference starts here
        else:
            self._approach_ticks += 1
            if self._approach_ticks >= self._timeout_ticks:
                return self._fault(self._timeout_reason(err))
        return u

    def _move_up(self, v_mm_s: float, enc: float) -> float:
        """Command ``v_mm_s`` >= 0 (ramped), the law not stepped; it resumes bumplessly.

        In PREINTERPOLATE the plan restarts from here (the verification before an approach).
        """
        u = self._limit(max(v_mm_s, 0.0))  # a_max-ramped: no evidence of danger yet
        self._source = SOURCE_NONE
        st = self._state
        if st == LADRC_STATE:
            self._ladrc.u = u
        elif st == PID:
            self._pid.set_pre_out(u)
        elif st == PREINTERPOLATE:
            self._interp.reset(u)
            self._enc0 = enc
            self._pid.set_pre_out(u)
        return u

    def _hold_up_only(self) -> float:
        """No usable reading this tick: hold an upward command, stop motion toward the sheet.

        PID/LADRC are not stepped; in PREINTERPOLATE the plan continues only away from the
        sheet (it needs no reading to brake, but it only closes in on valid data).
        """
        if self._u < 0.0:
            self._u = 0.0
        st = self._state
        if st == PREINTERPOLATE:
            self._source = SOURCE_INTERP
            v = self._interp.step()
            if v < 0.0:
                v = self._interp.velocity_mm_s = 0.0
            return self._limit(v)
        # the law resumes from the command actually applied (ESO input, PID's previous output)
        if st == LADRC_STATE:
            self._ladrc.u = self._u
        elif st == PID:
            self._pid.set_pre_out(self._u)
        self._flags = 0
        return self._u

    def _timeout_reason(self, err: float) -> str:
        f = self.follow_params
        return (f'not followed within {f.followed_timeout_s:g} s: error {err:+.3f} mm did not '
                f'stay within {self._wide_tol:g} mm for {self.params.pid.followed_hold_s:g} s '
                f'(tolerance widened from {self._tol:g} mm after {f.followed_widen_s:g} s)')

    # ------------------------------------------------------------------ status
    def internals(self) -> dict[str, float | int | bool | str]:
        """Return this tick's status; keys = ``ladrc_msgs/FollowStatus`` fields.

        Called every tick (the node's status, the replay's comparison): one dict, built once.
        """
        st = self._state
        lad = self._ladrc
        flags = self._flags
        source = self._source
        last_gap = self._last_gap
        if st == PID and self._use_ladrc and math.isfinite(last_gap):
            # what the seed's every-tick InitLADRC holds (reset is memoryless, see module doc)
            enc = self._last_enc if math.isfinite(self._last_enc) else None
            lad.reset(last_gap, self._u, self._target_eff, enc)
        if st == LADRC_STATE or (st == PID and self._use_ladrc):
            fused, x1, x2 = float(lad.fused_gap_mm), float(lad.td_x1), float(lad.td_x2)
            z1, z2, z3 = float(lad.z1), float(lad.z2), float(lad.z3)
            u0, dist = float(lad.u0), float(lad.disturbance_term)
        else:
            fused = last_gap if math.isfinite(last_gap) else 0.0
            x1 = x2 = z1 = z2 = z3 = u0 = dist = 0.0
        p_term = d_term = 0.0
        unlimited = self._u_unlimited
        if source == SOURCE_LADRC:
            p_term, d_term = float(lad.p_term), float(lad.d_term + lad.ff_term)
            flags |= (LIMIT_VELOCITY if lad.saturated else 0) | (
                LIMIT_ACCELERATION if lad.rate_limited else 0)
            ext = lad.z2 if lad.order == 1 else lad.z3
            if abs(ext) >= self._ext_limit:
                flags |= LIMIT_ESO_STATE
            unlimited = lad.u_unlimited
        elif source in (SOURCE_INTERP, SOURCE_PID):
            pid = self._pid
            p_term, d_term = float(pid.p_term), float(pid.d_term + pid.ff_term)
            if source == SOURCE_PID:
                flags |= (LIMIT_VELOCITY if pid.saturated else 0) | (
                    LIMIT_ACCELERATION if pid.rate_limited else 0)
                unlimited = pid.u_unlimited
        out = {'state': st, 'followed': self._followed, 'machining': self._machining,
               'fault_reason': self._fault_reason, 'target_gap_mm': self._target_eff,
               'fused_gap_mm': fused, 'td_x1_mm': x1, 'td_x2_mm_s': x2, 'eso_z1_mm': z1,
               'eso_z2': z2, 'eso_z3': z3, 'u0_mm_s': u0, 'p_term_mm_s': p_term,
               'd_term_mm_s': d_term, 'disturbance_term_mm_s': dist,
               'u_unlimited_mm_s': float(unlimited), 'velocity_mm_s': self._u,
               'limit_flags': int(flags)}
        out.update(self._partner.answers(st, self._followed, self._retracting))
        return out


TICK: dict[int, Callable[[FollowController, tuple], float]] = {
    IDLE: FollowController._tick_idle,
    LOCKING: FollowController._tick_locking,
    PREINTERPOLATE: FollowController._tick_following,
    PID: FollowController._tick_following,
    LADRC_STATE: FollowController._tick_following,
    FAULT: FollowController._tick_fault,
}
"""State -> the function that runs its tick. The following states share the input gate, a due
gradient follow and the edge guard (:meth:`FollowController._tick_following`); their own step
is :data:`LAW` (PREINTERPOLATE: the approach)."""

LAW: dict[int, Callable[..., float]] = {
    PID: FollowController._law_pid,
    LADRC_STATE: FollowController._law_ladrc,
}
"""PID and LADRC: the step after the input gate and the edge guard."""

assert set(TICK) == set(FollowState)
assert all((s, FAULT) in TRANSITIONS for s in FollowState)  # fail() may never raise
