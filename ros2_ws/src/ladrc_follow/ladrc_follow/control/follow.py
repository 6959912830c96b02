"""The follow state machine (notes §3.5 ``Follow_OnStep``), completed where the seed is a fragment.

States (values = ``ladrc_msgs/FollowStatus`` ``STATE_*``)::

    IDLE --start_follow--> LOCKING --inputs ok--> PREINTERPOLATE --seed hand-over rule--> PID
    PID --followed (and LADRC configured, not machining)--> LADRC
    PID/LADRC --target change > retarget_threshold_mm / gradient follow--> PREINTERPOLATE
    any following state --fault--> FAULT --reset_fault--> IDLE;  stop_follow --> IDLE

* LOCKING (seed ``Locking_OnStep``, not in the notes): command 0 until the inputs are fresh and
  valid and the drive is enabled and unfaulted, then initialise and approach.
* PREINTERPOLATE (seed): every tick ``Interp_GoDistance(target − gap − cached length)``; the
  interpolator's velocity is the command; the PID runs alongside from the interpolator's
  velocity (``FollowPID_SetPreOutUnitV``) and takes over when the seed's rule holds
  (``nDir·nNextAcc < 0 && |nNextAcc| ≤ acc && |err| ≤ 1 mm``) or, so the phase cannot get
  stuck, when the interpolation has finished within the window.
* PID (seed ``FS_PID_CONTROL``): PID follow with feed-forward; "followed" = in position for the
  hold time. The seed re-initialises the LADRC every PID tick from the PID output and the
  reading (``InitLADRC(height, height, pidOut)``); :meth:`LADRC.reset` is memoryless, so this
  module re-initialises it once, at the switch, from the previous tick's reading and output —
  the identical state, without paying a reset on every PID tick.
* LADRC: ``UpdateLADRC`` once followed and (seed) not machining; ``ladrc_while_machining``
  lifts the machining restriction.

Every output passes one final limiter (±v_max, ±a_max·h against the previously applied
command, :func:`law.apply_limits`), so no hand-over steps the velocity by more than a_max·h.
Invalid or stale data never reaches PID/LADRC: the checks run before either is stepped.
See docs/follow-state-machine.md for the decisions taken where the seed is silent.
"""

from __future__ import annotations

from dataclasses import replace
from enum import IntEnum
import math
import numbers
from typing import Any, NamedTuple

from .edge import EDGE, FALLING, HOLD, VERIFY, EdgeGuard
from .follow_params import FollowParams
from .interp import Interpolator, InterpParams
from .kalman import kalman_gated_step
from .ladrc import LADRC
from .ops import SCALAR
from .params import ControllerParams, check, check_gate
from .pid import FollowPID
from .target_wave import TargetWave

__all__ = [
    'FollowState', 'FollowParams', 'FollowController', 'TickInput', 'GAP_STATUS_OK',
    'GAP_STATUS_OUT_OF_RANGE', 'GAP_STATUS_COLLISION',
    'GAP_STATUS_FAULT', 'LIMIT_VELOCITY', 'LIMIT_ACCELERATION', 'LIMIT_ESO_STATE', 'LIMIT_SOFT_Z',
    'INTERNALS_KEYS', 'COMMANDS',
]


class FollowState(IntEnum):
    """Follow states; the values are ``ladrc_msgs/FollowStatus`` ``STATE_*``."""

    IDLE = 0
    LOCKING = 1
    PREINTERPOLATE = 2
    PID = 3
    LADRC = 4
    FAULT = 5


_IDLE, _LOCKING, _PREINTERP, _PID, _LADRC, _FAULT = (int(s) for s in FollowState)

# ladrc_msgs/CapacitiveHeight STATUS_*
GAP_STATUS_OK = 0
GAP_STATUS_OUT_OF_RANGE = 1
GAP_STATUS_COLLISION = 2
GAP_STATUS_FAULT = 3

# command arguments: the longest delay of a queued command; the smallest speed / acceleration
# of a gradient move (an absurdly slow move would hold the axis for hours)
MAX_DELAY_S = 3600.0
MIN_GRADIENT = (0.1, 10.0)

# ladrc_msgs/FollowStatus LIMIT_* bits
LIMIT_VELOCITY = 1
LIMIT_ACCELERATION = 2
LIMIT_ESO_STATE = 4
LIMIT_SOFT_Z = 8

# internals() keys = these ladrc_msgs/FollowStatus fields
INTERNALS_KEYS = (
    'state', 'followed', 'machining', 'fault_reason', 'target_gap_mm', 'fused_gap_mm',
    'td_x1_mm', 'td_x2_mm_s', 'eso_z1_mm', 'eso_z2', 'eso_z3', 'u0_mm_s', 'p_term_mm_s',
    'd_term_mm_s', 'disturbance_term_mm_s', 'u_unlimited_mm_s', 'velocity_mm_s',
    'limit_flags',
)

# command name -> argument names (required first); defaults in FollowController.command
COMMANDS = {
    'start_follow': ('target_gap_mm',),
    'stop_follow': (),
    'set_target': ('target_gap_mm',),
    'machining': ('on',),
    'height_compensation': ('offset_mm', 'delay_s'),
    'gradient_follow': ('target_gap_mm', 'delay_s', 'velocity_mm_s', 'accel_mm_s2'),
    'reset_fault': (),
    'target_wave': ('kind', 'amp_mm', 'freq_hz', 'freq_end_hz', 'duration_s'),
}


class TickInput(NamedTuple):
    """Inputs of one controller tick (the sim runner's ``TickInput`` plus ``gap_status``).

    ``gap_status`` is ``CapacitiveHeight.status`` (``GAP_STATUS_*``); it is the last field
    with a default, so an 8-field tuple (the sim runner's) is accepted too: a status of 0
    with ``gap_valid`` false means "not reported" and the cause is inferred from the reading
    (at or below ``collision_gap_mm``: collision; otherwise out of range / miss-panel).
    """

    t_s: float
    gap_mm: float
    gap_valid: bool
    gap_stamp_s: float
    encoder_mm: float
    encoder_stamp_s: float
    drive_enabled: bool
    drive_fault: bool
    gap_status: int = 0


_PK_RESET = (math.nan, 0.0, 0, 0.0)  # the PID's Kalman filter restarts on the next reading


def _real(x: Any) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x)


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
           mode: str | None = None, gate: bool = True) -> PreparedSet:
    params = params if params is not None else ControllerParams()
    if follow is not None:
        params = replace(params, follow=follow)
    if mode is not None:
        params = replace(params, follow=replace(params.follow, controller=mode))
    check(params)  # the whole set (ParameterError is a ValueError)
    if gate:
        check_gate(params)  # its loops against the configured axis (stability.*)
    fp = params.follow
    ladrc = LADRC(params)
    return PreparedSet(params, fp, ladrc, FollowPID(params.pid, params.h_s),
                  Interpolator(params.interp, params.h_s))


class FollowController:
    """Follow state machine driving PID / LADRC; ``step(tick) -> velocity_mm_s``.

    ``command(name, **kwargs) -> (accepted, message)`` queues a follow command (applied at the
    start of the next :meth:`step`), ``set_params`` queues a parameter set likewise, so a
    replay that re-issues the same commands before the same ticks reproduces the commands
    bit for bit. ``follow`` overrides ``params.follow``; ``mode`` ('ladrc' | 'pid') overrides
    ``follow.controller`` (also for later :meth:`set_params`).

    Every set, at construction and in :meth:`set_params`, passes the stability gate
    (``stability.*``, :mod:`.stability`) unless ``stability.gate`` is off in it, or ``gate``
    is False: replay and the suite's study variants reproduce sets as they were, gate or not.
    """

    def __init__(self, params: ControllerParams | None = None,
                 follow: FollowParams | None = None, *, mode: str | None = None,
                 gate: bool = True) -> None:
        self._pending: list[tuple[str, dict]] = []
        self._pending_build: PreparedSet | None = None
        self._mode = mode  # 'ladrc' | 'pid' overrides follow.controller (CLI --controller)
        self._gate = gate
        self._install(_build(params, follow, mode, gate))
        self._state = _IDLE
        self._tick = -1
        self._u = 0.0            # last applied command (mm/s)
        self._u_unlim = 0.0
        self._flags = 0
        self._src = 0            # source of the command: 0 ramp, 1 interp, 2 PID, 3 LADRC
        self._override = math.nan  # edge guard: a verification's command, -inf up only
        self._target = math.nan  # commanded target (without compensation)
        self._offset = 0.0       # active height compensation
        self._target_eff = math.nan
        self._machining = False
        self._followed = False
        self._fault_reason = ''
        self._comp: list[tuple[int, float]] = []
        self._gradients: list[tuple[int, float, float, float]] = []
        self._wave: TargetWave | None = None  # test signal on the target (seed SIN_GEN)
        self._fresh = True  # this tick's gap is a new sample (not the encoder prediction)
        self._closing = False  # a step run by the law (reinterpolate false) is closing in
        self._pk = _PK_RESET  # the PID's Kalman state: x, P, outliers, encoder
        self._wave_k = 0
        self._capped = False
        self._retracting = False
        self._retracted = False  # a retract has run since the fault latched
        self._retract: Interpolator | None = None
        self._last_gap = math.nan
        self._last_enc = math.nan
        self._drive_bad = False
        self._lock_ticks = 0
        self._lock_ok = False
        self._invalid_ticks = 0
        self._miss_ticks = 0
        self._inpos_ticks = 0
        self._approach_ticks = 0
        self._dir = 1.0
        self._enc0 = 0.0
        self._surf_ref = 0.0
        self._down_cap = math.inf  # speed cap toward the sheet (edge.py probing)
        self._enc_now = 0.0  # encoder position of this tick (soft travel limits)
        # trust no reading beyond the encoder: the sample used last, frozen-value detection
        self._used_gstamp = math.nan
        self._acc_gap = math.nan   # the last reading accepted, and the encoder then
        self._acc_enc = math.nan
        self._same_n = 0
        self._same_enc0 = math.nan
        self._jump_t0 = math.nan  # time of the first jumped reading being held
        self._invalid_rate = 0.0   # low-passed share of invalid samples
        self.counts = {'predicted': 0, 'frozen': 0, 'jump': 0, 'invalid': 0,
                       'out_of_range': 0, 'nonfinite': 0, 'fall_hold': 0, 'sink_hold': 0,
                       'verify': 0,
                       'edge_gain': 0}
        """Ticks run on the encoder-predicted gap, samples rejected per cause."""

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
        self._v_max = p.limits.v_max_mm_s
        self._zmin, self._zmax = p.limits.soft_z_min_mm, p.limits.soft_z_max_mm
        self._tau_z = p.limits.soft_z_tau_s
        self._du_max = p.limits.a_max_mm_s2 * h
        self._vlim, self._dulim = self._v_max, self._du_max
        self._pid_du = p.pid.a_max_mm_s2 * h
        self._use_ladrc = f.controller == 'ladrc'
        self._lag_comp = f.approach_lag_compensation
        self._ladrc_machining = f.ladrc_while_machining
        self._stale_s = f.stale_timeout_s
        self._coll = f.collision_gap_mm
        self._window = f.handover_window_mm
        self._retarget = f.retarget_threshold_mm if f.reinterpolate else math.inf
        self._retarget_mm = f.retarget_threshold_mm
        self._target_lim = (f.min_target_gap_mm, f.max_target_gap_mm)
        kp = p.kalman
        # the gated Kalman filter on the PID's gap too (kalman.on_pid; control/kalman.py)
        self._pid_kalman = kp.enabled and kp.on_pid
        self._pk_consts = (kp.q_mm2, kp.r_mm2, kp.p0_mm2, kp.gate_mm,
                           float(kp.gate_confirm_ticks))
        self._tol = p.pid.followed_tol_mm
        self._wide_tol = f.followed_wide_tol_mm
        self._hold_ticks = max(1, int(round(p.pid.followed_hold_s / h)))
        self._widen_ticks = _ticks(f.followed_widen_s, h)
        self._timeout_ticks = _ticks(f.followed_timeout_s, h)
        self._lock_max = _ticks(f.locking_timeout_s, h)
        self._invalid_max = _ticks(f.invalid_timeout_s, h)
        self._miss_max = _ticks(f.miss_panel_s, h)
        e = p.edge
        self._edge = e.drop_mm
        self._c_rate = h / (f.invalid_rate_tau_s + h)  # backward-Euler low-pass, as pid.py
        self._rate_max = f.invalid_rate_max
        self._jump_mm = f.jump_mm
        self._jump_confirm_s = f.jump_confirm_s
        self._frozen_n = f.frozen_ticks
        self._frozen_mm = f.frozen_travel_mm
        self._c_edge = h / (e.ref_tau_s + h)  # backward-Euler low-pass, as pid.py
        old_guard = getattr(self, '_guard', None)
        self._guard = EdgeGuard(e, h)
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
        return _build(params, follow, self._mode, self._gate)

    def set_prepared(self, prepared: PreparedSet) -> None:
        """Queue a set built by :meth:`prepare`: it takes effect at the next tick, bumplessly."""
        self._pending_build = prepared

    def _swap_params(self) -> None:
        b, self._pending_build = self._pending_build, None
        old_interp, custom = self._interp, self._interp is not self._interp_default
        self._install(b)
        self._pk = _PK_RESET  # the PID's Kalman filter restarts with the new set
        st, u = self._state, self._u
        gap, enc, target = self._last_gap, self._last_enc, self._target_eff
        if custom:
            self._interp = old_interp  # a gradient move keeps its own v/a
        elif st == _PREINTERP:
            self._interp.reset(u)
            self._interp.go_distance(old_interp.cached_length_mm)
        if st in (_PREINTERP, _PID, _LADRC) and math.isfinite(gap):
            enc_ = enc if math.isfinite(enc) else None
            self._pid.reset(gap, target, u, enc_)
            if st == _PID:
                self._pid_modes()
            self._ladrc.reset(gap, u, target, enc_)
        if self._capped:
            self._vlim, self._dulim = self._cap
            self._vlim = min(self._vlim, self._v_max)
            self._dulim = min(self._dulim, self._du_max)

    # ------------------------------------------------------------------ properties
    @property
    def state(self) -> FollowState:
        """Current state."""
        return FollowState(self._state)

    @property
    def projected_state(self) -> FollowState:
        """Return the state once the queued commands apply at the next tick."""
        return FollowState(self._projected_state())

    @property
    def followed(self) -> bool:
        """In position within tolerance for the hold time since the last approach (随动到位)."""
        return self._followed

    @property
    def fault_reason(self) -> str:
        """Why the controller is in FAULT ('' otherwise)."""
        return self._fault_reason

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
        return _PREINTERP <= self._state <= _LADRC or self._retracting or self._u != 0.0

    # ------------------------------------------------------------------ commands
    def _projected_state(self) -> int:
        s = self._state
        for name, _ in self._pending:
            if name == 'stop_follow' and s != _FAULT:
                s = _IDLE
            elif name == 'start_follow' and s == _IDLE:
                s = _LOCKING
            elif name == 'reset_fault' and s == _FAULT:
                s = _IDLE
        return s

    def _check_target(self, name: str, target: Any, offset: float) -> str:
        f = self.follow_params
        if not _real(target):
            return f'{name}: target_gap_mm must be a finite number, got {target!r}'
        eff = target + offset
        if not f.min_target_gap_mm <= eff <= f.max_target_gap_mm:
            extra = f' (target {target:g} + compensation {offset:g})' if offset else ''
            return (f'{name}: target gap {eff:g} mm{extra} outside the allowed '
                    f'{f.min_target_gap_mm:g}..{f.max_target_gap_mm:g} mm')
        return ''

    def command(self, name: str, **kwargs: Any) -> tuple[bool, str]:
        """Queue a follow command for the next tick; return ``(accepted, message)``.

        ``start_follow(target_gap_mm)``, ``stop_follow()``, ``set_target(target_gap_mm)``,
        ``machining(on)``, ``height_compensation(offset_mm, delay_s=0)``,
        ``gradient_follow(target_gap_mm, delay_s, velocity_mm_s=0, accel_mm_s2=0)``,
        ``reset_fault()``, ``target_wave(kind='sine', amp_mm, freq_hz, freq_end_hz=0,
        duration_s=0)`` (a test signal on the target once followed, :mod:`.target_wave`;
        ``amp_mm`` 0 ends a running one). A rejected command changes nothing; the message
        says why.
        """
        if name not in COMMANDS:
            return False, f'unknown command {name!r} (known: {", ".join(COMMANDS)})'
        allowed = COMMANDS[name]
        extra = sorted(set(kwargs) - set(allowed))
        if extra:
            return False, (f'{name}: unknown argument(s) {", ".join(extra)} '
                           f'(allowed: {", ".join(allowed) or "none"})')
        st = self._projected_state()
        following = _LOCKING <= st <= _LADRC
        f = self.follow_params
        if name == 'start_follow':
            if 'target_gap_mm' not in kwargs:
                return False, 'start_follow: missing target_gap_mm'
            why = self._check_target(name, kwargs['target_gap_mm'], 0.0)
            if why:
                return False, why
            if st == _FAULT:
                return False, f'start_follow: in FAULT ({self._fault_reason}); reset_fault first'
            msg = ('follow starts (LOCKING)' if st == _IDLE else
                   'already following: treated as set_target')
        elif name == 'stop_follow':
            msg = ('follow stops: IDLE, command ramps to 0' if st != _FAULT else
                   'not following; the FAULT stays latched until reset_fault')
        elif name == 'set_target':
            if 'target_gap_mm' not in kwargs:
                return False, 'set_target: missing target_gap_mm'
            if not following:
                return False, (f'set_target: not following ({FollowState(st).name}); '
                               'use start_follow')
            why = self._check_target(name, kwargs['target_gap_mm'], self._offset)
            if why:
                return False, why
            msg = (f'target {kwargs["target_gap_mm"]:g} mm (a change over '
                   f'{f.retarget_threshold_mm:g} mm re-interpolates)')
        elif name == 'machining':
            on = kwargs.get('on')
            if on not in (True, False):
                return False, f'machining: on must be true or false, got {on!r}'
            kwargs = {'on': bool(on)}
            msg = f'machining {"on" if on else "off"}'
        elif name == 'height_compensation':
            off = kwargs.get('offset_mm')
            delay = kwargs.setdefault('delay_s', 0.0)
            if not _real(off) or abs(off) > f.max_compensation_mm:
                return False, (f'height_compensation: offset_mm must be a finite number within '
                               f'±{f.max_compensation_mm:g} mm, got {off!r}')
            if not _real(delay) or not 0.0 <= delay <= MAX_DELAY_S:
                return False, (f'height_compensation: delay_s must be within 0..'
                               f'{MAX_DELAY_S:g} s, got {delay!r}')
            if st not in (_PID, _LADRC):
                return False, ('height_compensation: only accepted while following in PID or '
                               f'LADRC state, not {FollowState(st).name} (seed: a compensation '
                               'outside PID_CONTROL is an error)')
            why = self._check_target(name, self._target, off)
            if why:
                return False, why
            msg = f'compensation {off:g} mm queued, applies in {delay:g} s'
        elif name == 'gradient_follow':
            kwargs.setdefault('delay_s', 0.0)
            kwargs.setdefault('velocity_mm_s', 0.0)
            kwargs.setdefault('accel_mm_s2', 0.0)
            if 'target_gap_mm' not in kwargs:
                return False, 'gradient_follow: missing target_gap_mm'
            if not following:
                return False, f'gradient_follow: not following ({FollowState(st).name})'
            why = self._check_target(name, kwargs['target_gap_mm'], self._offset)
            if why:
                return False, why
            lim = self.params.limits
            for key, low, top in (('delay_s', 0.0, MAX_DELAY_S),
                                  ('velocity_mm_s', MIN_GRADIENT[0], lim.v_max_mm_s),
                                  ('accel_mm_s2', MIN_GRADIENT[1], lim.a_max_mm_s2)):
                v = kwargs[key]
                if not (isinstance(v, numbers.Real) and not isinstance(v, bool)
                        and (v == 0.0 or low <= v <= top)):
                    return False, (f'gradient_follow: {key} must be 0 (default) or within '
                                   f'{low:g}..{top:g}, got {v!r}')
            msg = f'gradient follow to {kwargs["target_gap_mm"]:g} mm in {kwargs["delay_s"]:g} s'
        elif name == 'target_wave' and kwargs.get('amp_mm') == 0.0:
            kwargs = {'kind': 'sine', 'amp_mm': 0.0, 'freq_hz': 1.0, 'freq_end_hz': 0.0,
                      'duration_s': 0.0}
            msg = 'target wave off'
        elif name == 'target_wave':
            wave = TargetWave(**kwargs)
            why = wave.problems()
            if why:
                return False, 'target_wave: ' + '; '.join(why)
            if not following:
                return False, f'target_wave: not following ({FollowState(st).name})'
            if wave.amp_mm > 0.0:
                target = next((a['target_gap_mm'] for n, a in reversed(self._pending)
                               if n in ('start_follow', 'set_target')), self._target)
                for sign in (-1.0, 1.0):
                    why = self._check_target(name, target, self._offset + sign * wave.amp_mm)
                    if why:
                        return False, why
            kwargs = {k: getattr(wave, k) for k in COMMANDS[name]}
            msg = (f'{wave.kind} of {wave.amp_mm:g} mm at {wave.freq_hz:g} Hz on the target for '
                   f'{wave.length_s:g} s once followed and not machining' if wave.amp_mm > 0.0
                   else 'target wave off')
        else:  # reset_fault
            if st != _FAULT:
                return False, f'reset_fault: no fault to reset (state {FollowState(st).name})'
            if self._retracting:
                return False, 'reset_fault: collision retract still running; retry when it ends'
            if self._drive_bad:
                return False, 'reset_fault: the drive still reports a fault or is disabled'
            msg = 'fault cleared: IDLE'
        self._pending.append((name, kwargs))
        return True, msg

    def _apply_commands(self) -> None:
        pending, self._pending = self._pending, []
        for name, kw in pending:
            st = self._state
            following = _LOCKING <= st <= _LADRC
            if name == 'start_follow':
                if st == _IDLE:
                    self._target = kw['target_gap_mm']
                    self._offset = 0.0
                    self._target_eff = self._target
                    self._state = _LOCKING
                    self._lock_ticks = 0
                    self._lock_ok = False
                elif following:
                    self._set_target(kw['target_gap_mm'])
            elif name == 'stop_follow':
                if st != _FAULT:
                    self._stop(_IDLE)
            elif name == 'set_target':
                if following:
                    self._set_target(kw['target_gap_mm'])
            elif name == 'machining':
                self._machining = kw['on']
                if kw['on']:
                    self._wave = None  # a test wave ends when machining starts (seed SIN_GEN)
            elif name == 'height_compensation':
                if st in (_PID, _LADRC):
                    due = self._tick + int(round(kw['delay_s'] / self._h))
                    i = len(self._comp)
                    while i > 0 and self._comp[i - 1][0] > due:
                        i -= 1
                    self._comp.insert(i, (due, kw['offset_mm']))
            elif name == 'gradient_follow':
                if following:
                    due = self._tick + int(round(kw['delay_s'] / self._h))
                    ip = self.params.interp
                    v = kw['velocity_mm_s'] or ip.v_max_mm_s
                    a = kw['accel_mm_s2'] or ip.a_max_mm_s2
                    i = len(self._gradients)
                    while i > 0 and self._gradients[i - 1][0] > due:
                        i -= 1
                    self._gradients.insert(i, (due, kw['target_gap_mm'], v, a))
            elif name == 'target_wave':
                if following:
                    wave = TargetWave(**kw)
                    self._wave = wave if wave.amp_mm > 0.0 else None
                    self._wave_k = 0
            elif name == 'reset_fault':
                if st == _FAULT and not self._retracting:
                    self._state = _IDLE
                    self._fault_reason = ''

    def _stop(self, state: int) -> None:
        """Leave following: clear target, queues and caps (the command ramps to 0)."""
        self._state = state
        self._target = self._target_eff = math.nan
        self._offset = 0.0
        self._comp = []
        self._gradients = []
        self._followed = False
        self._wave = None
        self._closing = False
        self._uncap()

    def _uncap(self) -> None:
        self._capped = False
        self._vlim, self._dulim = self._v_max, self._du_max

    def _set_target(self, target: float) -> None:
        self._target = target
        self._change_eff(target + self._offset)

    def _change_eff(self, eff: float) -> None:
        old, self._target_eff = self._target_eff, eff
        self._wave = None  # any change of the target ends a test wave (it was checked on it)
        st = self._state
        if (st == _PID or st == _LADRC) and abs(eff - old) > self._retarget:
            # seed comment in FS_PID_CONTROL: a large change is smoother interpolated
            self._enter_approach(self._last_gap, self._last_enc, None)
        elif (st == _PID or st == _LADRC) and abs(eff - old) > self._retarget_mm:
            # follow.reinterpolate false (seed): the law runs the step; the closing in is
            # measured as on an approach (edge guard) until the gap reaches the target
            self._closing = True

    # ------------------------------------------------------------------ transitions
    def _enter_approach(self, gap: float, enc: float, va: tuple[float, float] | None) -> None:
        """Enter PREINTERPOLATE from the applied command (seed ``InitPreInterpolate``)."""
        h = self._h
        if va is None:
            self._interp = self._interp_default
            self._uncap()
        else:
            self._interp = Interpolator(InterpParams(va[0], va[1]), h)
            # seed FollowPID_SetSpeedCtrlParam: the gradient's v/a bound the PID until followed
            self._capped = True
            self._cap = (va[0], va[1] * h)
            self._vlim = min(va[0], self._v_max)
            self._dulim = min(va[1] * h, self._du_max)
        self._interp.reset(self._u)
        self._enc0 = enc
        target = self._target_eff
        self._guard.reset(gap - target)
        self._pk = _PK_RESET
        self._wave = None  # a re-approach ends a test wave
        self._closing = False
        self._dir = 1.0 if target >= gap else -1.0
        pid = self._pid
        pid.reset(gap, target, self._u, enc)
        pid.set_suppress(False)
        self._state = _PREINTERP
        self._followed = False
        self._inpos_ticks = 0
        self._approach_ticks = 0

    def _enter_pid(self, gap: float, enc: float) -> None:
        self._state = _PID
        self._surf_ref = enc - gap

    def _fault(self, reason: str, retract: bool = False) -> float:
        self._stop(_FAULT)
        self._fault_reason = reason
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

    def _drive_fault(self, dfault: bool, den: bool) -> float:
        # The drive no longer executes commands (it stops on its own ramp): command 0 at once,
        # so nothing is pending when it comes back.
        self._stop(_FAULT)
        self._fault_reason = ('drive fault reported by the drive: command 0' if dfault else
                              'drive disabled during follow: command 0')
        self._retracting = False
        return self._out_zero()

    def _out_zero(self) -> float:
        self._u = self._u_unlim = 0.0
        self._flags = 0
        self._src = 0
        return 0.0

    # ------------------------------------------------------------------ output
    def _limit(self, u_c: float) -> float:
        """Limit the output: ±v, then ±a·h against the applied command (law.apply_limits)."""
        if u_c - u_c != 0.0:  # nan or ±inf from a law: no limiter may hide it
            self.counts['nonfinite'] += 1
            return self.fail(f'non-finite command ({u_c!r}) in state '
                             f'{FollowState(self._state).name}')
        v, du, u_prev = self._vlim, self._dulim, self._u
        vd = v if v < self._down_cap else self._down_cap
        us = v if u_c > v else (-vd if u_c < -vd else u_c)
        lo, hi = u_prev - du, u_prev + du
        u = lo if us < lo else (hi if us > hi else us)
        flags = (us != u_c) | ((u != us) << 1)
        # soft travel limits, in every state: the speed toward a limit is at most the distance
        # left over soft_z_tau_s (an exponential approach, never past it); never forces motion
        z = self._enc_now
        down = (self._zmin - z) / self._tau_z if z > self._zmin else 0.0
        up = (self._zmax - z) / self._tau_z if z < self._zmax else 0.0
        if u < down:
            u = down
            flags |= LIMIT_SOFT_Z
        elif u > up:
            u = up
            flags |= LIMIT_SOFT_Z
        self._flags = flags
        self._u_unlim = u_c
        self._u = u
        return u

    def _ramp0(self) -> float:
        self._src = 0
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
            self._src = 0
            return self._limit(v)
        if drive_bad:
            return self._out_zero()
        return self._ramp0()

    # ------------------------------------------------------------------ tick
    def step(self, tick: tuple) -> float:
        """One tick: return the velocity command in mm/s (+ = up, widens the gap).

        Every exception inside the tick and every non-finite command ends in FAULT with a zero
        command (:meth:`fail`): the caller always gets a finite number.
        """
        try:
            u = self._step(tick)
        except Exception as exc:  # noqa: BLE001 - any bug must end in a zero command
            return self.fail(f'exception in the controller tick: {type(exc).__name__}: {exc}')
        if u - u != 0.0:
            self.counts['nonfinite'] += 1
            return self.fail(f'non-finite command ({u!r}) in state '
                             f'{FollowState(self._state).name}')
        return u

    def fail(self, reason: str) -> float:
        """Enter FAULT with a zero command now (exceptions, non-finite values); return 0.0."""
        self._stop(_FAULT)
        self._fault_reason = reason
        self._retracting = False
        return self._out_zero()

    def _step(self, tick: tuple) -> float:
        self._tick += 1
        if self._pending_build is not None:
            self._swap_params()
        if self._pending:
            self._apply_commands()
        if len(tick) == 9:
            t, gap, valid, gstamp, enc, estamp, den, dfault, status = tick
        else:
            t, gap, valid, gstamp, enc, estamp, den, dfault = tick
            status = 0
        drive_bad = dfault or not den
        self._drive_bad = drive_bad
        if enc - enc == 0.0:
            self._enc_now = enc  # for the soft travel limits (the last finite position)
        st = self._state
        if st == _IDLE:
            if self._u < 0.0:
                self._u = 0.0  # not following: nothing moves toward the sheet
            return self._ramp0()
        if st == _FAULT:
            if not (self._retracted or drive_bad) and (
                    status == GAP_STATUS_COLLISION
                    or (gap - gap == 0.0 and gap <= self._coll and (valid or not status))):
                # collision evidence retracts in every state, FAULT included: once per fault
                # (a sensor stuck low must not walk the axis up without end)
                first = self._fault_reason.split(';')[0]
                return self._fault(f'collision while in FAULT ({first}): gap reading '
                                   f'{gap:.3f} mm, status {status}; retracting '
                                   f'{self.follow_params.retract_distance_mm:g} mm', True)
            return self._fault_out(drive_bad)
        if st == _LOCKING:
            return self._locking(t, gap, valid, gstamp, enc, estamp, den, dfault, status)

        # ---- checks before anything reaches the control law
        if drive_bad:
            return self._drive_fault(dfault, den)
        s = self._stale_s
        if not (t - gstamp <= s and t - estamp <= s):
            return self._fault(f'stale input: gap age {(t - gstamp) * 1e3:.3g} ms, encoder age '
                               f'{(t - estamp) * 1e3:.3g} ms (limit {s * 1e3:.3g} ms)')
        if not (gstamp <= t + self._h and estamp <= t + self._h):
            # a sample from the future: a clock the controller cannot trust
            return self._fault(f'input stamped in the future: gap {(gstamp - t) * 1e3:.3g} ms, '
                               f'encoder {(estamp - t) * 1e3:.3g} ms ahead of the tick')
        if not enc - enc == 0.0:
            return self._fault(f'encoder position not finite ({enc!r})')
        if status == GAP_STATUS_COLLISION:
            return self._fault('collision: the sensor reports nozzle contact; retracting '
                               f'{self.follow_params.retract_distance_mm:g} mm', True)
        if not valid or status:
            return self._invalid(gap, status)
        if not gap - gap == 0.0:
            return self._fault(f'gap reading not finite ({gap!r}) though marked valid')
        if gap <= self._coll:
            return self._fault(f'collision: gap reading {gap:.3f} mm <= limit {self._coll:g} mm; '
                               f'retracting {self.follow_params.retract_distance_mm:g} mm', True)
        self._invalid_ticks = self._miss_ticks = 0
        self._invalid_rate -= self._c_rate * self._invalid_rate
        if gstamp == self._used_gstamp and self._acc_gap == self._acc_gap:
            # no new sample since the last tick: the law never runs twice on one reading; the
            # encoder increment predicts the gap (notes §4, the Kalman predict step)
            self.counts['predicted'] += 1
            self._fresh = False  # the Kalman filters only predict on this tick
            if self._jump_t0 == self._jump_t0:
                return self._hold_up_only()  # still holding on a jumped reading
            gap = self._acc_gap + (enc - self._acc_enc)
        else:
            self._used_gstamp = gstamp
            self._fresh = True
            if gap == self._acc_gap:
                # bit-identical to the last new sample: a real reading has noise, so a run of
                # them while the encoder moves is a frozen sensor with fresh stamps
                self._same_n += 1
                moved = enc - self._same_enc0
                if self._same_n >= self._frozen_n and abs(moved) > self._frozen_mm:
                    self.counts['frozen'] += 1
                    return self._fault(f'frozen gap reading: {self._same_n + 1} identical '
                                       f'samples ({gap:.4f} mm) while the encoder moved '
                                       f'{moved:+.3f} mm')
            else:
                self._same_n, self._same_enc0 = 0, enc
            if gap - (self._acc_gap + (enc - self._acc_enc)) > self._jump_mm:
                # the reading widened by more than a sheet can fall away in one sample: do not
                # follow it down; a level that persists for jump_confirm_s is taken as real
                self.counts['jump'] += 1
                if not self._jump_t0 == self._jump_t0:
                    self._jump_t0 = t
                if t - self._jump_t0 < self._jump_confirm_s:
                    return self._hold_up_only()
            self._jump_t0 = math.nan
            self._acc_gap, self._acc_enc = gap, enc
        if self._gradients and self._gradients[0][0] <= self._tick:
            _, gt, gv, ga = self._gradients.pop(0)
            self._target = gt
            self._target_eff = gt + self._offset
            # seed: gradient -> LOCKING -> PREINTERPOLATE with the gradient's speed/acc
            self._enter_approach(gap, enc, (gv, ga))
        st = self._state
        guard = self._guard
        # closing in is measured until followed (approach, then the PID's first settling)
        verdict = guard.update(self._tick * self._h, enc, gap,
                               st == _PREINTERP or not self._followed
                               or self._closing or self._wave is not None,
                               self._target_eff, self._fresh)
        if verdict == FALLING:
            # faster than a sheet falls: not followed down; closing in afterwards is probed
            self.counts['fall_hold'] += 1
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
            if st == _PREINTERP:
                return self._hold_up_only()
            self._override = -math.inf  # up only
        elif verdict == VERIFY:
            # the apparent surface sank below its last verified level (or a follow starts
            # close to its target): a short move up measures the feedback gain
            self.counts['verify'] += 1
            if st == _PREINTERP:
                return self._move_up(guard.verify_velocity_mm_s, enc)
            self._override = guard.verify_velocity_mm_s
        if verdict == EDGE:
            self.counts['edge_gain'] += 1
            return self._fault(guard.reason)
        self._down_cap = guard.down_cap_mm_s
        if st == _PREINTERP:
            return self._preinterp(gap, enc)
        if self._comp and self._comp[0][0] <= self._tick:
            self._offset = self._comp.pop(0)[1]  # seed UpdateCompHeightQueue
            self._change_eff(self._target + self._offset)
            if self._state == _PREINTERP:
                return self._preinterp(gap, enc)
        pg, pe = self._last_gap, self._last_enc
        self._last_gap, self._last_enc = gap, enc
        if self._edge > 0.0:
            sf = enc - gap
            ref = self._surf_ref
            if sf < ref - self._edge:
                return self._fault(f'out of panel edge: apparent sheet surface fell '
                                   f'{ref - sf:.2f} mm below its reference (limit '
                                   f'{self._edge:g} mm)')
            self._surf_ref = ref + self._c_edge * (sf - ref)
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
        if st == _PID:
            if not self._followed:
                tol = self._tol if self._approach_ticks < self._widen_ticks else self._wide_tol
                if abs(gap - target) <= tol:
                    self._inpos_ticks += 1
                else:
                    self._inpos_ticks = 0
                if self._inpos_ticks >= self._hold_ticks:
                    self._followed = True
                    if self._capped:  # seed: GRADIENT_FOLLOWING -> IDLE, speed params back
                        self._uncap()
                else:
                    self._approach_ticks += 1
                    if self._approach_ticks >= self._timeout_ticks:
                        return self._fault(self._timeout_reason(gap - target))
            if (self._followed and self._use_ladrc
                    and (self._ladrc_machining or not self._machining)):
                # seed: InitLADRC(height, height, pidOut) of the previous PID tick
                self._ladrc.reset(pg, self._u, target, pe)
                self._state = _LADRC
                return self._ladrc_tick(gap, enc, target)
            return self._pid_tick(gap, enc, target)
        # LADRC
        if not self._use_ladrc or (self._machining and not self._ladrc_machining):
            # back to the PID, starting from the applied command (bumpless)
            self._pid.reset(pg, target, self._u, pe)
            self._pk = _PK_RESET
            self._state = _PID
            return self._pid_tick(gap, enc, target)
        return self._ladrc_tick(gap, enc, target)

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
        x, p, n, enc_prev = self._pk
        q, r, p0, gate, confirm = self._pk_consts
        if not x == x:  # (re)start on the reading, as the LADRC's filter does at its reset
            self._pk = (gap, p0, 0, enc)
            return gap
        x, p, _, n = kalman_gated_step(SCALAR, x, p, n, gap, enc - enc_prev, self._fresh,
                                       q, r, p0, gate, confirm)
        self._pk = (x, p, n, enc)
        return x

    def _overridden(self, u_c: float, src: int) -> float:
        """Apply the edge guard's override to the law's command ``u_c``, then the limits."""
        ov = self._override
        self._src = src
        if ov == ov:
            if ov == -math.inf:
                u_c = u_c if u_c > 0.0 else 0.0  # hold: upward only
            else:
                u_c = ov  # a verification's move
            self._src = 0
        return self._limit(u_c)

    def _pid_tick(self, gap: float, enc: float, target: float) -> float:
        self._pid_modes()
        pid = self._pid
        u = self._overridden(pid.step(self._pid_gap(gap, enc), enc, target), 2)
        if u != pid.u:
            pid.set_pre_out(u)
        return u

    def _ladrc_tick(self, gap: float, enc: float, target: float) -> float:
        u_c = self._ladrc_step(gap, enc, target, self._fresh)
        u = self._overridden(u_c, 3)
        if u != u_c:
            self._ladrc.u = u  # the ESO must see the applied command
        return u

    def _preinterp(self, gap: float, enc: float) -> float:
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
        self._src = 1
        if u != v:
            it.velocity_mm_s = u  # keep the plan on the applied command
        if abs(err) <= self._window and (
                (self._dir * nxt < 0.0 and abs(nxt) <= self._pid_du + 1e-9)
                or it.is_finished()):
            # seed hand-over: the PID restarts from the interpolator's velocity
            pid.set_pre_out(u)
            self._enter_pid(gap, enc)
        else:
            self._approach_ticks += 1
            if self._approach_ticks >= self._timeout_ticks:
                return self._fault(self._timeout_reason(err))
        return u

    def _invalid(self, gap: float, status: int) -> float:
        """Handle an unusable reading: count, hold the command, fault after the allowed time."""
        finite = gap - gap == 0.0
        # the share of invalid samples (low-passed): interleaved valid ones do not hide them
        rate = self._invalid_rate + self._c_rate * (1.0 - self._invalid_rate)
        self._invalid_rate = rate
        if rate > self._rate_max:
            return self._fault(f'gap readings invalid too often: {rate:.0%} of the samples '
                               f'over the last {self.follow_params.invalid_rate_tau_s:g} s '
                               f'(limit {self._rate_max:.0%})')
        if status == GAP_STATUS_OUT_OF_RANGE or (status == 0 and finite and gap > self._coll):
            self.counts['out_of_range'] += 1
            self._miss_ticks += 1
            if self._miss_ticks >= self._miss_max:
                return self._fault(
                    'miss-panel: no sheet under the nozzle (gap reading out of range for '
                    f'{self._miss_ticks * self._h * 1e3:.3g} ms)')
        elif status == 0 and finite:
            return self._fault(f'collision: invalid gap reading {gap:.3f} mm at or below the '
                               f'limit {self._coll:g} mm; retracting '
                               f'{self.follow_params.retract_distance_mm:g} mm', True)
        else:
            self._invalid_ticks += 1
            self.counts['invalid'] += 1
            if self._invalid_ticks >= self._invalid_max:
                what = 'sensor fault status' if status == GAP_STATUS_FAULT else (
                    f'status {status}' if status else 'not finite')
                return self._fault(f'gap reading invalid ({what}) for '
                                   f'{self._invalid_ticks * self._h * 1e3:.3g} ms')
        return self._hold_up_only()

    def _move_up(self, v_mm_s: float, enc: float) -> float:
        """Command ``v_mm_s`` >= 0 (ramped), the law not stepped; it resumes bumplessly.

        In PREINTERPOLATE the plan restarts from here (the verification before an approach).
        """
        u = self._limit(max(v_mm_s, 0.0))  # a_max-ramped: no evidence of danger yet
        self._src = 0
        st = self._state
        if st == _LADRC:
            self._ladrc.u = u
        elif st == _PID:
            self._pid.set_pre_out(u)
        elif st == _PREINTERP:
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
        if st == _PREINTERP:
            self._src = 1
            v = self._interp.step()
            if v < 0.0:
                v = self._interp.velocity_mm_s = 0.0
            return self._limit(v)
        # the law resumes from the command actually applied (ESO input, PID's previous output)
        if st == _LADRC:
            self._ladrc.u = self._u
        elif st == _PID:
            self._pid.set_pre_out(self._u)
        self._flags = 0
        return self._u

    def _timeout_reason(self, err: float) -> str:
        f = self.follow_params
        return (f'not followed within {f.followed_timeout_s:g} s: error {err:+.3f} mm did not '
                f'stay within {self._wide_tol:g} mm for {self.params.pid.followed_hold_s:g} s '
                f'(tolerance widened from {self._tol:g} mm after {f.followed_widen_s:g} s)')

    def _locking(self, t, gap, valid, gstamp, enc, estamp, den, dfault, status) -> float:
        s = self._stale_s
        if dfault:
            why = 'the drive reports a fault'
        elif not den:
            why = 'the drive is not enabled'
        elif not (t - gstamp <= s and t - estamp <= s):
            why = 'inputs are stale'
        elif not (gstamp <= t + self._h and estamp <= t + self._h):
            why = 'inputs are stamped in the future'
        elif not enc - enc == 0.0:
            why = 'the encoder position is not finite'
        elif status == GAP_STATUS_COLLISION or (
                gap - gap == 0.0 and gap <= self._coll and (valid or not status)):
            return self._fault(f'collision at start: gap reading {gap:.3f} mm (limit '
                               f'{self._coll:g} mm); retracting '
                               f'{self.follow_params.retract_distance_mm:g} mm', True)
        elif not valid or status:
            why = ('no sheet under the nozzle / reading out of range'
                   if status in (0, GAP_STATUS_OUT_OF_RANGE) else 'the gap sensor reports a fault')
        elif not gap - gap == 0.0:
            why = 'the gap reading is not finite'
        elif self._lock_ok:
            # seed Locking_IsFinished -> PREINTERPOLATE (InitPreInterpolate there)
            self._enter_approach(gap, enc, None)
            if self._guard.verifying:
                return self._move_up(0.0, enc)  # the gain is verified before closing in
            return self._preinterp(gap, enc)
        else:
            # usable inputs on two consecutive ticks: one tick to initialise, then approach
            self._lock_ok = True
            return self._ramp0()
        self._lock_ok = False
        self._lock_ticks += 1
        if self._lock_ticks >= self._lock_max:
            return self._fault(f'start_follow failed: {why} '
                               f'(LOCKING timeout {self.follow_params.locking_timeout_s:g} s)')
        return self._ramp0()

    # ------------------------------------------------------------------ status
    def internals(self) -> dict[str, float | int | bool | str]:
        """Return this tick's status; keys = ``ladrc_msgs/FollowStatus`` fields."""
        st = self._state
        lad = self._ladrc
        z = dict(fused_gap_mm=self._last_gap if math.isfinite(self._last_gap) else 0.0,
                 td_x1_mm=0.0, td_x2_mm_s=0.0, eso_z1_mm=0.0, eso_z2=0.0, eso_z3=0.0,
                 u0_mm_s=0.0, p_term_mm_s=0.0, d_term_mm_s=0.0, disturbance_term_mm_s=0.0)
        flags = self._flags
        src = self._src
        if st == _PID and self._use_ladrc and math.isfinite(self._last_gap):
            # what the seed's every-tick InitLADRC holds (reset is memoryless, see module doc)
            enc = self._last_enc if math.isfinite(self._last_enc) else None
            lad.reset(self._last_gap, self._u, self._target_eff, enc)
        if st == _LADRC or (st == _PID and self._use_ladrc):
            z.update(fused_gap_mm=float(lad.fused_gap_mm), td_x1_mm=float(lad.td_x1),
                     td_x2_mm_s=float(lad.td_x2), eso_z1_mm=float(lad.z1),
                     eso_z2=float(lad.z2), eso_z3=float(lad.z3), u0_mm_s=float(lad.u0),
                     disturbance_term_mm_s=float(lad.disturbance_term))
        if src == 3:
            z.update(p_term_mm_s=float(lad.p_term),
                     d_term_mm_s=float(lad.d_term + lad.ff_term))
            flags |= (LIMIT_VELOCITY if lad.saturated else 0) | (
                LIMIT_ACCELERATION if lad.rate_limited else 0)
            ext = lad.z2 if lad.order == 1 else lad.z3
            if abs(ext) >= self._ext_limit:
                flags |= LIMIT_ESO_STATE
        elif src in (1, 2):
            pid = self._pid
            z.update(p_term_mm_s=float(pid.p_term), d_term_mm_s=float(pid.d_term + pid.ff_term))
            if src == 2:
                flags |= (LIMIT_VELOCITY if pid.saturated else 0) | (
                    LIMIT_ACCELERATION if pid.rate_limited else 0)
        unlim = self._u_unlim
        if src == 2:
            unlim = self._pid.u_unlimited
        elif src == 3:
            unlim = lad.u_unlimited
        return dict(state=st, followed=self._followed, machining=self._machining,
                    fault_reason=self._fault_reason, target_gap_mm=self._target_eff, **z,
                    u_unlimited_mm_s=float(unlim), velocity_mm_s=self._u,
                    limit_flags=int(flags))
