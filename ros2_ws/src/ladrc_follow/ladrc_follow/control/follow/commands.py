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
        elif name == 'start_follow' and s == IDLE:
            s = LOCKING
        elif name == 'reset_fault' and s == FAULT:
            s = IDLE
    return s
