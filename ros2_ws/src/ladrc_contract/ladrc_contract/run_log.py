"""A run's faults, holds and time per follow state, read off the controller's status.

One implementation for the follow node (:meth:`RunLog.tick`, once per tick, scalars) and for
the reports of a bag's ``follow/status`` (:meth:`RunLog.add`, columns). A fault is an entry
into ``FollowState.FAULT``: its time, the state before, its ``FaultCode`` (where the controller
gives it: the node and the runners, not a bag), the reason and the ages of the two inputs at
that tick. A hold is an episode of one ``SubState`` other than NONE.
:func:`verdict` turns a summary into the one line a run ends with.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .codes import TIMING_GUARDS, FaultCode, FollowState, SubState

_FAULT = int(FollowState.FAULT)
_NAMES = [s.name for s in FollowState]
_HOLDS = {int(s): s.name.lower() for s in SubState if s != SubState.NONE}


def _ms(age_s: float) -> float | None:
    return round(age_s * 1e3, 3) if math.isfinite(age_s) else None


class RunLog:
    """Accumulates a run's faults (entries into FAULT), holds and ticks per state."""

    def __init__(self, h_s: float = math.nan) -> None:
        """``h_s``: the tick period [s] (``add`` takes it from the stamps when NaN)."""
        self.h_s = h_s
        self.faults: list[dict[str, Any]] = []
        self.state_ticks = [0] * len(_NAMES)
        self.hold_counts = dict.fromkeys(_HOLDS, 0)
        self.hold_ticks = dict.fromkeys(_HOLDS, 0)
        self.state = -1
        self.substate = 0
        self.reason = ''
        self.t0_s = math.nan
        self.t_s = math.nan

    def tick(self, t_s: float, state: int, reason: str, gap_age_s: float,
             encoder_age_s: float, substate: int = 0, code: int = 0) -> None:
        """Take one tick: time [s], state, fault reason, input ages [s], substate, FaultCode."""
        if self.t0_s != self.t0_s:  # NaN: the first tick
            self.t0_s = t_s
        self.state_ticks[state] += 1
        if state != self.state:
            if state == _FAULT:
                self._fault(t_s, self.state, reason, gap_age_s, encoder_age_s, code)
            self.state = state
        if substate:
            self.hold_ticks[substate] += 1
            if substate != self.substate:
                self.hold_counts[substate] += 1
        self.substate = substate
        self.reason = reason
        self.t_s = t_s

    def add(self, t_s: np.ndarray, state: np.ndarray, reason: np.ndarray,
            gap_age_s: np.ndarray, encoder_age_s: np.ndarray,
            substate: np.ndarray | None = None) -> None:
        """Take a slice of ticks in columns (a bag's ``follow/status``), in time order."""
        n = int(np.size(t_s))
        if n == 0:
            return
        state = np.asarray(state).astype(np.int64)
        if self.t0_s != self.t0_s:
            self.t0_s = float(t_s[0])
        if self.h_s != self.h_s and n > 1:
            self.h_s = float(np.median(np.diff(t_s)))
        self.state_ticks = (np.asarray(self.state_ticks) + np.bincount(
            state, minlength=len(_NAMES))[:len(_NAMES)]).tolist()
        before = np.r_[self.state, state[:-1]]
        for i in np.flatnonzero((state == _FAULT) & (before != _FAULT)):
            self._fault(float(t_s[i]), int(before[i]), str(reason[i]), float(gap_age_s[i]),
                        float(encoder_age_s[i]))
        if substate is not None:
            sub = np.asarray(substate).astype(np.int64)
            sub_before = np.r_[self.substate, sub[:-1]]
            for code in _HOLDS:
                now = sub == code
                self.hold_counts[code] += int(np.count_nonzero(now & (sub_before != code)))
                self.hold_ticks[code] += int(np.count_nonzero(now))
            self.substate = int(sub[-1])
        self.state = int(state[-1])
        self.reason = str(reason[-1])
        self.t_s = float(t_s[-1])

    def _fault(self, t_s: float, before: int, reason: str, gap_age_s: float,
               encoder_age_s: float, code: int = 0) -> None:
        self.faults.append({
            'code': FaultCode(code).name if code else None,  # None: not recorded (a bag)
            'timing_guard': (FaultCode(code) in TIMING_GUARDS) if code else None,
            't_s': round(t_s - self.t0_s, 4),
            'state_before': _NAMES[before] if before >= 0 else 'none',
            'reason': reason, 'gap_age_ms': _ms(gap_age_s),
            'encoder_age_ms': _ms(encoder_age_s)})

    def summary(self) -> dict[str, Any]:
        """Return the run as a JSON-friendly dict (times in s from the first tick)."""
        h = self.h_s if math.isfinite(self.h_s) else 0.0
        return {
            'run_s': round(sum(self.state_ticks) * h, 4),
            'state_s': {_NAMES[i]: round(k * h, 4) for i, k in enumerate(self.state_ticks)
                        if k},
            'faults': list(self.faults),
            'holds': {_HOLDS[c]: {'count': n, 'seconds': round(self.hold_ticks[c] * h, 4)}
                      for c, n in self.hold_counts.items() if n},
            'final_state': _NAMES[self.state] if self.state >= 0 else 'none',
            'final_reason': self.reason if self.state == _FAULT else '',
        }


def verdict(summary: dict[str, Any], expect_fault: bool = False) -> tuple[bool, str]:
    """Return ``(ok, line)``: the run's one-line outcome from a :meth:`RunLog.summary`.

    Not ok when the run ended in FAULT and ``expect_fault`` (the scenario or job declares
    its faults) is false. The line names the number of faults, the first one's time and
    reason, and the final state.
    """
    faults = summary.get('faults') or []
    final = summary.get('final_state', 'none')
    ok = not (final == FollowState.FAULT.name and not expect_fault)
    if not faults:
        text = f'0 faults, ended in {final}'
    else:
        first = faults[0]
        code = f' [{first["code"]}{", a timing guard" if first.get("timing_guard") else ""}]' \
            if first.get('code') else ''
        text = (f'{len(faults)} fault(s), the first at {first["t_s"]:g} s from '
                f'{first["state_before"]}{code}: {first["reason"]}; ended in {final}')
        last = summary.get('final_reason', '')
        if final == FollowState.FAULT.name and last and last != first['reason']:
            text += f' ({last})'
        if expect_fault:
            text += ' (faults declared by the run)'
    return ok, text
