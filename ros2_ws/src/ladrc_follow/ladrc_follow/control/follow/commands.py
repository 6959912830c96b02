"""The follow commands: per command its arguments, one validator and one apply function.

``FollowController.command`` validates at once against the state the queued commands lead to
(:func:`projected_state`) and queues; the tick applies the queue at its start, so a replay that
re-issues the same commands before the same ticks reproduces them bit for bit. A validator
returns ``(why, message, arguments)``: ``why`` non-empty rejects and changes nothing. An apply
function changes the controller only through the machine (``enter``) and its queues.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import numbers
from typing import Any, Callable, NamedTuple

from ..target_wave import TargetWave
from .states import FAULT, FOLLOWING, IDLE, LADRC, LOCKING, PID, FollowState

MAX_DELAY_S = 3600.0
"""The longest delay of a queued command."""
MIN_GRADIENT = (0.1, 10.0)
"""The smallest speed / acceleration of a gradient move (a slow one would hold the axis for
hours)."""


def is_real(x: Any) -> bool:
    """Return whether ``x`` is a finite real number (not a bool)."""
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x)


class CommandView(NamedTuple):
    """What a validator may read: the controller as the queued commands leave it."""

    state: int            # projected state
    follow: Any           # FollowParams
    params: Any           # ControllerParams
    target_mm: float      # commanded target, without compensation
    offset_mm: float      # active height compensation
    fault_reason: str
    retracting: bool
    drive_bad: bool
    pending: list         # queued (name, kwargs)
    level_mm: float = math.nan  # the sheet level followed last (a locked pierce's), NaN: none


Check = Callable[[CommandView, dict], tuple[str, str, dict]]
Apply = Callable[[Any, int, dict], None]


@dataclass(frozen=True)
class Command:
    """One follow command: argument names (required first), validator, apply function."""

    args: tuple[str, ...]
    check: Check
    apply: Apply


def check_target(view: CommandView, name: str, target: Any, offset: float) -> str:
    """Why ``target + offset`` is no allowed follow target ('' if it is)."""
    f = view.follow
    if not is_real(target):
        return f'{name}: target_gap_mm must be a finite number, got {target!r}'
    eff = target + offset
    if not f.min_target_gap_mm <= eff <= f.max_target_gap_mm:
        extra = f' (target {target:g} + compensation {offset:g})' if offset else ''
        return (f'{name}: target gap {eff:g} mm{extra} outside the allowed '
                f'{f.min_target_gap_mm:g}..{f.max_target_gap_mm:g} mm')
    return ''


def _following(state: int) -> bool:
    return state in FOLLOWING


# ---- start_follow / stop_follow / set_target / reset_fault ---------------------------------
def _check_start(view: CommandView, kw: dict) -> tuple[str, str, dict]:
    if 'target_gap_mm' not in kw:
        return 'start_follow: missing target_gap_mm', '', kw
    why = check_target(view, 'start_follow', kw['target_gap_mm'], 0.0)
    if why:
        return why, '', kw
    if view.state == FAULT:
        return f'start_follow: in FAULT ({view.fault_reason}); reset_fault first', '', kw
    return '', ('follow starts (LOCKING)' if view.state == IDLE else
                'already following: treated as set_target'), kw


def _apply_start(c, st: int, kw: dict) -> None:
    if st == IDLE:
        c._target = kw['target_gap_mm']
        c._offset = 0.0
        c._target_eff = c._target
        c.enter(LOCKING)
        c._lock_ticks = 0
        c._lock_ok = False
    elif _following(st):
        c._end_lift()
        c._set_target(kw['target_gap_mm'])


def _check_stop(view: CommandView, kw: dict) -> tuple[str, str, dict]:
    return '', ('follow stops: IDLE, command ramps to 0' if view.state != FAULT else
                'not following; the FAULT stays latched until reset_fault'), kw


def _apply_stop(c, st: int, kw: dict) -> None:
    if st != FAULT:
        c._stop(IDLE)


def _check_set_target(view: CommandView, kw: dict) -> tuple[str, str, dict]:
    if 'target_gap_mm' not in kw:
        return 'set_target: missing target_gap_mm', '', kw
    if not _following(view.state):
        return (f'set_target: not following ({FollowState(view.state).name}); '
                'use start_follow'), '', kw
    why = check_target(view, 'set_target', kw['target_gap_mm'], view.offset_mm)
    if why:
        return why, '', kw
    return '', (f'target {kw["target_gap_mm"]:g} mm (a change over '
                f'{view.follow.retarget_threshold_mm:g} mm re-interpolates)'), kw


def _apply_set_target(c, st: int, kw: dict) -> None:
    if _following(st):
        c._end_lift()  # a new target ends a lift: approached from where the axis is
        c._set_target(kw['target_gap_mm'])


def _check_reset(view: CommandView, kw: dict) -> tuple[str, str, dict]:
    if view.state != FAULT:
        return (f'reset_fault: no fault to reset (state {FollowState(view.state).name})',
                '', kw)
    if view.retracting:
        return 'reset_fault: collision retract still running; retry when it ends', '', kw
    if view.drive_bad:
        return 'reset_fault: the drive still reports a fault or is disabled', '', kw
    return '', 'fault cleared: IDLE', kw


def _apply_reset(c, st: int, kw: dict) -> None:
    if st == FAULT and not c._retracting:
        c.enter(IDLE)
        c._fault_reason = ''
        c._fault_code = 0


# ---- machining / height compensation / gradient follow / target wave -----------------------
def _check_machining(view: CommandView, kw: dict) -> tuple[str, str, dict]:
    on = kw.get('on')
    if on not in (True, False):
        return f'machining: on must be true or false, got {on!r}', '', kw
    return '', f'machining {"on" if on else "off"}', {'on': bool(on)}


def _apply_machining(c, st: int, kw: dict) -> None:
    c._machining = kw['on']
    if kw['on']:
        c._wave = None  # a test wave ends when machining starts (seed SIN_GEN)


def _check_compensation(view: CommandView, kw: dict) -> tuple[str, str, dict]:
    f = view.follow
    off = kw.get('offset_mm')
    delay = kw.setdefault('delay_s', 0.0)
    if not is_real(off) or abs(off) > f.max_compensation_mm:
        return (f'height_compensation: offset_mm must be a finite number within '
                f'±{f.max_compensation_mm:g} mm, got {off!r}'), '', kw
    if not is_real(delay) or not 0.0 <= delay <= MAX_DELAY_S:
        return (f'height_compensation: delay_s must be within 0..{MAX_DELAY_S:g} s, '
                f'got {delay!r}'), '', kw
    if view.state not in (PID, LADRC):
        return ('height_compensation: only accepted while following in PID or LADRC state, '
                f'not {FollowState(view.state).name} (seed: a compensation outside '
                'PID_CONTROL is an error)'), '', kw
    why = check_target(view, 'height_compensation', view.target_mm, off)
    if why:
        return why, '', kw
    return '', f'compensation {off:g} mm queued, applies in {delay:g} s', kw


def _due_insert(queue: list, entry: tuple) -> None:
    """Insert ``entry`` (due tick first) after every entry due no later (stable order)."""
    i = len(queue)
    while i > 0 and queue[i - 1][0] > entry[0]:
        i -= 1
    queue.insert(i, entry)


def _apply_compensation(c, st: int, kw: dict) -> None:
    if st in (PID, LADRC):
        due = c._tick + int(round(kw['delay_s'] / c._h))
        _due_insert(c._comp, (due, kw['offset_mm']))


def _check_gradient(view: CommandView, kw: dict) -> tuple[str, str, dict]:
    kw.setdefault('delay_s', 0.0)
    kw.setdefault('velocity_mm_s', 0.0)
    kw.setdefault('accel_mm_s2', 0.0)
    if 'target_gap_mm' not in kw:
        return 'gradient_follow: missing target_gap_mm', '', kw
    if not _following(view.state):
        return f'gradient_follow: not following ({FollowState(view.state).name})', '', kw
    why = check_target(view, 'gradient_follow', kw['target_gap_mm'], view.offset_mm)
    if why:
        return why, '', kw
    lim = view.params.limits
    for key, low, top in (('delay_s', 0.0, MAX_DELAY_S),
                          ('velocity_mm_s', MIN_GRADIENT[0], lim.v_max_mm_s),
                          ('accel_mm_s2', MIN_GRADIENT[1], lim.a_max_mm_s2)):
        v = kw[key]
        if not (isinstance(v, numbers.Real) and not isinstance(v, bool)
                and (v == 0.0 or low <= v <= top)):
            return (f'gradient_follow: {key} must be 0 (default) or within '
                    f'{low:g}..{top:g}, got {v!r}'), '', kw
    return '', (f'gradient follow to {kw["target_gap_mm"]:g} mm in '
                f'{kw["delay_s"]:g} s'), kw


def _apply_gradient(c, st: int, kw: dict) -> None:
    if _following(st):
        due = c._tick + int(round(kw['delay_s'] / c._h))
        ip = c.params.interp
        v = kw['velocity_mm_s'] or ip.v_max_mm_s
        a = kw['accel_mm_s2'] or ip.a_max_mm_s2
        _due_insert(c._gradients, (due, kw['target_gap_mm'], v, a))


# ---- the CNC interface: pierce / lift / hold (docs/interfaces.md, "CNC interface") -------------
MAX_STAGES = 8
"""The most pierce stages a program may have."""
MAX_DWELL_S = 60.0
"""The longest dwell of one pierce stage, and the longest THC delay."""
LIFT_TO_HEIGHT, LIFT_BY_DISTANCE = 0, 1
"""``Lift.srv`` modes."""


def _check_pierce(view: CommandView, kw: dict) -> tuple[str, str, dict]:
    missing = [a for a in TABLE['pierce'].args if a not in kw and a != 'locked']
    if missing:
        return f'pierce: missing {", ".join(missing)}', '', kw
    try:
        heights = tuple(kw['heights_mm'])
        dwell = tuple(kw['dwell_s'])
    except TypeError:
        return 'pierce: heights_mm and dwell_s must be lists of numbers', '', kw
    if not 1 <= len(heights) <= MAX_STAGES or len(dwell) != len(heights):
        return (f'pierce: {len(heights)} stage heights and {len(dwell)} dwell times: give '
                f'1..{MAX_STAGES} stages, one dwell each'), '', kw
    for t in (*dwell, kw['thc_delay_s']):
        if not (is_real(t) and 0.0 <= t <= MAX_DWELL_S):
            return f'pierce: dwell / THC delay {t!r} s outside 0..{MAX_DWELL_S:g} s', '', kw
    for i, z in enumerate(heights):
        why = check_target(view, f'pierce stage {i + 1}', z, view.offset_mm)
        if why:
            return why, '', kw
    why = check_target(view, 'pierce cut gap', kw['cut_gap_mm'], view.offset_mm)
    if why:
        return why, '', kw
    if view.state == FAULT:
        return f'pierce: in FAULT ({view.fault_reason}); reset_fault first', '', kw
    locked = kw.get('locked', False)
    if locked not in (True, False):
        return f'pierce: locked must be true or false, got {locked!r}', '', kw
    if locked and (view.state not in (PID, LADRC) or view.level_mm != view.level_mm):
        return ('pierce: locked: no sheet level followed yet in this follow (a locked pierce '
                f'holds heights above it; {FollowState(view.state).name}): pierce unlocked '
                'first'), '', kw
    kw = {'heights_mm': tuple(float(z) for z in heights),
          'dwell_s': tuple(float(t) for t in dwell),
          'cut_gap_mm': float(kw['cut_gap_mm']), 'thc_delay_s': float(kw['thc_delay_s']),
          **({'locked': True} if locked else {})}
    stages = ', '.join(f'{z:g} mm {t:g} s' for z, t in zip(kw['heights_mm'], kw['dwell_s'],
                                                                strict=True))
    return '', (f'pierce: {stages}; then {kw["cut_gap_mm"]:g} mm, THC delay '
                f'{kw["thc_delay_s"]:g} s' + (' (follow starts)' if view.state == IDLE else '')
                + (' locked: heights above the sheet level followed last, by the encoder'
                   if locked else '')), kw


def _apply_pierce(c, st: int, kw: dict) -> None:
    if st == FAULT:
        return
    c._end_lift()  # (first: the approach then starts from where the axis is)
    if kw.get('locked'):
        if st in (PID, LADRC) and c._level == c._level:
            c._partner.start_locked(c._level, kw['heights_mm'], kw['dwell_s'],
                                    kw['cut_gap_mm'], kw['thc_delay_s'])
        return
    first = c._partner.start_pierce(kw['heights_mm'], kw['dwell_s'], kw['cut_gap_mm'],
                                    kw['thc_delay_s'])
    if st == IDLE:
        _apply_start(c, st, {'target_gap_mm': first})
    else:
        c._set_target(first)


def _check_lift(view: CommandView, kw: dict) -> tuple[str, str, dict]:
    mode, value = kw.get('mode', LIFT_TO_HEIGHT), kw.get('value_mm')
    v = kw.get('velocity_mm_s', 0.0)
    cnc, v_max = view.params.cnc, view.params.limits.v_max_mm_s
    if isinstance(mode, bool) or mode not in (LIFT_TO_HEIGHT, LIFT_BY_DISTANCE):
        return f'lift: mode must be 0 (to a height) or 1 (by a distance), got {mode!r}', '', kw
    if not (is_real(value) and 0.0 < value <= cnc.max_lift_mm):
        return f'lift: value_mm {value!r} outside 0 (excl.)..{cnc.max_lift_mm:g} mm', '', kw
    if not (is_real(v) and 0.0 <= v <= v_max):
        return (f'lift: velocity_mm_s {v!r} outside 0..{v_max:g} mm/s '
                '(0: cnc.lift_velocity_mm_s)'), '', kw
    if view.state not in (PID, LADRC):
        return f'lift: not following in PID / LADRC ({FollowState(view.state).name})', '', kw
    kw = {'mode': int(mode), 'value_mm': float(value), 'velocity_mm_s': float(v)}
    return '', (f'lift {"to" if mode == LIFT_TO_HEIGHT else "by"} {value:g} mm, then held '
                '(set_target or pierce resumes)'), kw


def _apply_lift(c, st: int, kw: dict) -> None:
    if st not in (PID, LADRC):
        return
    value = kw['value_mm']
    if kw['mode'] == LIFT_TO_HEIGHT:
        gap = c._last_gap
        value = value - gap if gap == gap else 0.0  # never toward the sheet
    c._partner.start_lift(max(value, 0.0), kw['velocity_mm_s'], c._u)


MAX_RAPID_MM = 100_000.0
"""The longest rapid a leapfrog plans over (100 m)."""


def _check_leapfrog(view: CommandView, kw: dict) -> tuple[str, str, dict]:
    f, cnc, lim = view.follow, view.params.cnc, view.params.limits
    vals = {k: kw.get(k) for k in TABLE['leapfrog'].args}
    bad = [k for k, v in vals.items() if not is_real(v)]
    if bad:
        return f'leapfrog: {", ".join(bad)} must be finite numbers', '', kw
    lift, length, feed, arrive = (vals[k] for k in TABLE['leapfrog'].args)
    if not 0.0 < lift <= cnc.max_lift_mm:
        return f'leapfrog: lift_mm {lift:g} outside 0 (excl.)..{cnc.max_lift_mm:g} mm', '', kw
    if not f.min_target_gap_mm <= arrive <= min(lift, f.max_target_gap_mm):
        return (f'leapfrog: arrive_height_mm {arrive:g} outside {f.min_target_gap_mm:g}..'
                f'{min(lift, f.max_target_gap_mm):g} mm (at most lift_mm)'), '', kw
    if not (0.0 < length <= MAX_RAPID_MM and 0.0 < feed <= 100.0 * lim.v_max_mm_s):
        return (f'leapfrog: rapid_length_mm {length:g} (0..{MAX_RAPID_MM:g}) and rapid_feed_mm_s '
                f'{feed:g} (0..{100.0 * lim.v_max_mm_s:g}) must be positive'), '', kw
    if view.state not in (PID, LADRC):
        return f'leapfrog: not following in PID / LADRC ({FollowState(view.state).name})', '', kw
    kw = {k: float(v) for k, v in vals.items()}
    return '', (f'leapfrog: up to {lift:g} mm over the {length:g} mm rapid, at {arrive:g} mm '
                f'in {length / feed:.3g} s'), kw


def _apply_leapfrog(c, st: int, kw: dict) -> None:
    gap, enc = c._last_gap, c._last_enc
    if st not in (PID, LADRC) or not (gap == gap and enc == enc):
        return
    c._partner.start_leapfrog(c._enc_now, enc - gap, kw['lift_mm'], kw['arrive_height_mm'],
                              kw['rapid_length_mm'] / kw['rapid_feed_mm_s'])


def _check_hold(view: CommandView, kw: dict) -> tuple[str, str, dict]:
    hold, nxt, reason = kw.get('hold'), kw.get('at_next_segment', False), kw.get('reason', '')
    if hold not in (True, False) or nxt not in (True, False) or not isinstance(reason, str):
        return (f'hold: hold and at_next_segment must be true or false, reason a string; got '
                f'{hold!r}, {nxt!r}, {reason!r}'), '', kw
    if not _following(view.state):
        return f'hold: not following ({FollowState(view.state).name})', '', kw
    kw = {'hold': bool(hold), 'at_next_segment': bool(nxt), 'reason': reason[:200]}
    return '', f'{"hold" if hold else "release"} {"at the next segment" if nxt else "now"}', kw


def _apply_hold(c, st: int, kw: dict) -> None:
    if _following(st):
        c._partner.command_hold(kw['hold'], kw['at_next_segment'], kw['reason'])


_WAVE_OFF = {'kind': 'sine', 'amp_mm': 0.0, 'freq_hz': 1.0, 'freq_end_hz': 0.0,
             'duration_s': 0.0}


def _check_wave(view: CommandView, kw: dict) -> tuple[str, str, dict]:
    if kw.get('amp_mm') == 0.0:
        return '', 'target wave off', dict(_WAVE_OFF)
    wave = TargetWave(**kw)
    why = wave.problems()
    if why:
        return 'target_wave: ' + '; '.join(why), '', kw
    if not _following(view.state):
        return f'target_wave: not following ({FollowState(view.state).name})', '', kw
    if wave.amp_mm > 0.0:
        target = next((a['target_gap_mm'] for n, a in reversed(view.pending)
                       if n in ('start_follow', 'set_target')), view.target_mm)
        for sign in (-1.0, 1.0):
            why = check_target(view, 'target_wave', target, view.offset_mm + sign * wave.amp_mm)
            if why:
                return why, '', kw
    kw = {k: getattr(wave, k) for k in TABLE['target_wave'].args}
    return '', (f'{wave.kind} of {wave.amp_mm:g} mm at {wave.freq_hz:g} Hz on the target for '
                f'{wave.length_s:g} s once followed and not machining' if wave.amp_mm > 0.0
                else 'target wave off'), kw


def _apply_wave(c, st: int, kw: dict) -> None:
    if _following(st):
        wave = TargetWave(**kw)
        c._wave = wave if wave.amp_mm > 0.0 else None
        c._wave_k = 0


TABLE: dict[str, Command] = {
    'start_follow': Command(('target_gap_mm',), _check_start, _apply_start),
    'stop_follow': Command((), _check_stop, _apply_stop),
    'set_target': Command(('target_gap_mm',), _check_set_target, _apply_set_target),
    'machining': Command(('on',), _check_machining, _apply_machining),
    'height_compensation': Command(('offset_mm', 'delay_s'), _check_compensation,
                                   _apply_compensation),
    'gradient_follow': Command(('target_gap_mm', 'delay_s', 'velocity_mm_s', 'accel_mm_s2'),
                               _check_gradient, _apply_gradient),
    'reset_fault': Command((), _check_reset, _apply_reset),
    'target_wave': Command(('kind', 'amp_mm', 'freq_hz', 'freq_end_hz', 'duration_s'),
                           _check_wave, _apply_wave),
    'pierce': Command(('heights_mm', 'dwell_s', 'cut_gap_mm', 'thc_delay_s', 'locked'),
                      _check_pierce, _apply_pierce),
    'lift': Command(('mode', 'value_mm', 'velocity_mm_s'), _check_lift, _apply_lift),
    'hold': Command(('hold', 'at_next_segment', 'reason'), _check_hold, _apply_hold),
    'leapfrog': Command(('lift_mm', 'rapid_length_mm', 'rapid_feed_mm_s', 'arrive_height_mm'),
                        _check_leapfrog, _apply_leapfrog),
}
"""Command name -> its table entry."""

COMMANDS: dict[str, tuple[str, ...]] = {name: c.args for name, c in TABLE.items()}
"""Command name -> argument names (required first); the defaults are the validators'."""


def projected_state(state: int, pending: list) -> int:
    """Return the state once the queued ``(name, kwargs)`` commands apply at the next tick."""
    s = state
    for name, _ in pending:
        if name == 'stop_follow' and s != FAULT:
            s = IDLE
        elif name in ('start_follow', 'pierce') and s == IDLE:
            s = LOCKING
        elif name == 'reset_fault' and s == FAULT:
            s = IDLE
    return s
