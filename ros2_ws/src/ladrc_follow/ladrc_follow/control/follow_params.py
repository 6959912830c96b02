"""Parameters of the follow state machine (the ``follow`` section of ControllerParams).

Kept apart from :mod:`.follow` so that :mod:`.params` can type its ``follow`` section with
:class:`FollowParams` (and validate it with the rest of the set) without an import cycle.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
import math
import numbers
import typing
from typing import Any


@dataclass(frozen=True)
class FollowParams:
    """Parameters of the follow state machine (``ControllerParams.follow``).

    The approach move uses ``ControllerParams.interp`` (v, a); "followed" uses
    ``pid.followed_tol_mm`` / ``pid.followed_hold_s`` (the seed's ``FollowPID_HasFollowed``);
    the output limits are ``ControllerParams.limits``.
    """

    controller: str = 'ladrc'            # 'ladrc': LADRC once followed; 'pid': PID only
    ladrc_while_machining: bool = False  # seed: LADRC only when not machining
    min_target_gap_mm: float = 0.3       # accepted follow gaps (incl. compensation)
    max_target_gap_mm: float = 20.0
    max_compensation_mm: float = 5.0     # |height compensation offset|
    retarget_threshold_mm: float = 1.0   # target change above this re-interpolates
    handover_window_mm: float = 1.0      # seed: |err| <= 1 mm for PREINTERPOLATE -> PID
    approach_lag_compensation: bool = True  # subtract planned travel the encoder lags behind
    followed_widen_s: float = 3.0        # not followed after this: tolerance widens ...
    followed_wide_tol_mm: float = 0.2    # ... to this
    followed_timeout_s: float = 5.0      # not followed after this: FAULT (alarm)
    locking_timeout_s: float = 1.0       # LOCKING waits this long for usable inputs
    stale_timeout_s: float = 0.01        # input age limit (20 ticks at 2 kHz; see docs)
    invalid_timeout_s: float = 0.005     # invalid reading (not miss-panel) tolerated this long
    miss_panel_s: float = 0.005          # out-of-range reading this long -> miss-panel FAULT
    collision_gap_mm: float = 0.2        # reading at or below -> collision
    retract_distance_mm: float = 2.0     # collision retract: distance up ...
    retract_velocity_mm_s: float = 50.0  # ... at this speed (<= limits.v_max; a = limits.a_max)
    edge_drop_mm: float = 2.0            # apparent surface drop -> out of panel edge; 0 = off
    edge_ref_tau_s: float = 0.2          # time constant of the surface reference

    def problems(self) -> list[str]:
        """Return readable reasons why these values cannot work (empty if valid)."""
        out = []
        if self.controller not in ('ladrc', 'pid'):
            out.append(f"follow.controller must be 'ladrc' or 'pid', got {self.controller!r}")
        for name in ('ladrc_while_machining', 'approach_lag_compensation'):
            if not isinstance(getattr(self, name), bool):
                out.append(f'follow.{name} must be true or false, got {getattr(self, name)!r}')
        for f in fields(self):
            if f.name in ('controller', 'ladrc_while_machining', 'approach_lag_compensation'):
                continue
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
                out.append(f'follow.{f.name} must be a finite number, got {v!r}')
                continue
            zero_ok = f.name in ('edge_drop_mm',)
            if not (v >= 0.0 if zero_ok else v > 0.0):
                out.append(f"follow.{f.name} must be {'>= 0' if zero_ok else '> 0'}, got {v!r}")
        if out:
            return out
        if not self.min_target_gap_mm < self.max_target_gap_mm:
            out.append(f'follow.min_target_gap_mm ({self.min_target_gap_mm:g}) must be below '
                       f'max_target_gap_mm ({self.max_target_gap_mm:g})')
        if not self.collision_gap_mm < self.min_target_gap_mm:
            out.append(f'follow.collision_gap_mm ({self.collision_gap_mm:g}) must be below '
                       f'min_target_gap_mm ({self.min_target_gap_mm:g}): following at the '
                       'collision limit would fault at once')
        if not self.followed_widen_s < self.followed_timeout_s:
            out.append(f'follow.followed_widen_s ({self.followed_widen_s:g}) must be below '
                       f'followed_timeout_s ({self.followed_timeout_s:g}): the tolerance widens '
                       'before the alarm')
        return out

    @classmethod
    def from_dict(cls, d: dict | None) -> FollowParams:
        """Build from a mapping (``ControllerParams.follow``); ValueError names every problem."""
        if d is None:
            d = {}
        if isinstance(d, FollowParams):
            return d
        if not isinstance(d, dict):
            raise ValueError(f'follow parameters must be a mapping, got {type(d).__name__}')
        hints = typing.get_type_hints(cls)
        errors = []
        kwargs = {}
        for k, v in d.items():
            if k not in hints:
                errors.append(f"unknown key 'follow.{k}' (known: "
                              f"{', '.join(f.name for f in fields(cls))})")
                continue
            tp = hints[k]
            if tp is float:
                if isinstance(v, bool) or not isinstance(v, numbers.Real):
                    errors.append(f'follow.{k} must be a number, got {v!r}')
                    continue
                v = float(v)
            elif tp is bool and not isinstance(v, bool):
                errors.append(f'follow.{k} must be true or false, got {v!r}')
                continue
            elif tp is str and not isinstance(v, str):
                errors.append(f'follow.{k} must be a string, got {v!r}')
                continue
            kwargs[k] = v
        if errors:
            raise ValueError('invalid follow parameters: ' + '; '.join(errors))
        p = cls(**kwargs)
        problems = p.problems()
        if problems:
            raise ValueError('invalid follow parameters: ' + '; '.join(problems))
        return p

    def to_dict(self) -> dict:
        """Plain mapping (for ``ControllerParams(follow=...)`` and YAML)."""
        return asdict(self)


def follow_params_of(params: Any) -> FollowParams:
    """FollowParams of a parameter set (``params.follow`` mapping); ValueError if invalid."""
    return FollowParams.from_dict(params.follow)


def follow_problems(params: Any) -> list[str]:
    """Whole-set checks of the follow section against the rest (called by ``params.validate``)."""
    try:
        fp = follow_params_of(params)
    except ValueError as exc:
        return [str(exc)]
    out = []
    if fp.followed_wide_tol_mm < params.pid.followed_tol_mm:
        out.append(f'follow.followed_wide_tol_mm ({fp.followed_wide_tol_mm:g}) below '
                   f'pid.followed_tol_mm ({params.pid.followed_tol_mm:g}): widening would '
                   'narrow the tolerance')
    if params.h_s > 0.0 and fp.stale_timeout_s < params.h_s:
        out.append(f'follow.stale_timeout_s ({fp.stale_timeout_s:g}) below one tick '
                   f'({params.h_s:g} s): every input would be stale')
    return out
