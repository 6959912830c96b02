"""Follow-performance metrics: pure functions of recorded series (sim, replay, report).

Conventions (all series sampled at a uniform tick ``h_s``; ``target_gap_mm`` is NaN while
not following):

* error ``e = true_gap - target`` (mm), on ticks where the target is set;
* **followed** (随动到位): ``|e| <= tol_mm`` held continuously for ``hold_s``; defaults
  0.05 mm / 50 ms (the width of a fine follow band and 100 ticks at 2 kHz). The followed
  time is the END of that first hold window; it and the time to first follow are measured
  from the first tick with a target;
* error RMS / max |e| / peak-to-peak: over target ticks from the followed time on;
* settling time and overshoot: for the LAST target change (the first target counts as a
  change from the current gap): settling = time from the change until ``|e|`` stays within
  ``tol_mm`` to the end of the target segment; overshoot = largest excursion beyond the new
  target in the direction of the step (mm, and % of the step size);
* ITAE = sum over target ticks of ``(t - t0) |e| h`` (mm s^2), ``t0`` = first target tick
  (the notes' §5.1 criterion);
* collisions: rising edges of the collision flag;
* limit hits: ticks the velocity / acceleration limit was active; taken from the
  controller's internals when it reports them: a ``limit_flags`` bitmask (bit 0 velocity,
  bit 1 acceleration, as ``ladrc_follow``'s follow status) or separate flags ``limit_v`` /
  ``limit_a`` (aliases ``saturated`` / ``rate_limited``, ``v_limited`` / ``a_limited``);
  else by value: ``|u| >= v_max`` or ``|du| >= a_max h`` (relative tolerance 1e-6).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
import math
from typing import Mapping

import numpy as np

TOL_MM = 0.05
HOLD_S = 0.05
_V_KEYS = ('limit_v', 'saturated', 'v_limited')
_A_KEYS = ('limit_a', 'rate_limited', 'a_limited')
LIMIT_FLAG_VELOCITY = 1
LIMIT_FLAG_ACCELERATION = 2


@dataclass(frozen=True)
class Metrics:
    """Summary of one run (NaN where not defined, e.g. never followed)."""

    followed_at_s: float
    time_to_follow_s: float
    error_rms_mm: float
    error_max_mm: float
    error_p2p_mm: float
    settling_time_s: float
    overshoot_mm: float
    overshoot_pct: float
    itae_mm_s2: float
    collisions: int
    limit_v_ticks: int
    limit_a_ticks: int

    def as_dict(self) -> dict[str, float]:
        """Plain dict (JSON-friendly numbers)."""
        return asdict(self)


def _first_target_index(target: np.ndarray) -> int | None:
    idx = np.flatnonzero(np.isfinite(target))
    return int(idx[0]) if idx.size else None


def followed_index(gap: np.ndarray, target: np.ndarray, h_s: float,
                   tol_mm: float = TOL_MM, hold_s: float = HOLD_S) -> int | None:
    """Index at which ``|gap - target| <= tol`` has first held for ``hold_s``; else None."""
    inside = np.isfinite(target) & (np.abs(gap - target) <= tol_mm)
    need = max(1, int(round(hold_s / h_s)))
    # run length of consecutive True ending at each index: distance to the last False.
    last_false = np.maximum.accumulate(np.where(~inside, np.arange(inside.size), -1))
    run = np.arange(inside.size) - last_false
    hit = np.flatnonzero(inside & (run > need))  # t - t_first_inside >= hold_s
    return int(hit[0]) if hit.size else None


def travel_ratio(nozzle_mm: np.ndarray, reading_mm: np.ndarray, min_travel_mm: float = 0.05
                 ) -> np.ndarray:
    """Ratio d1/d0 of true (axis) travel to read travel since the first sample (notes §5.3).

    1 with a calibrated sensor; falls below 1 at a sheet edge. NaN until the reading has
    moved ``min_travel_mm``.
    """
    d1 = np.asarray(nozzle_mm, dtype=float) - nozzle_mm[0]
    d0 = np.asarray(reading_mm, dtype=float) - reading_mm[0]
    ok = np.abs(d0) >= min_travel_mm
    return np.where(ok, d1 / np.where(ok, d0, 1.0), np.nan)


def follow_errors(gap: np.ndarray, target: np.ndarray, start: int) -> tuple[float, float, float]:
    """RMS, max |e| and peak-to-peak of ``gap - target`` from ``start`` on (target ticks)."""
    e = (gap - target)[start:]
    e = e[np.isfinite(e)]
    if e.size == 0:
        return math.nan, math.nan, math.nan
    return (float(np.sqrt(np.mean(e * e))), float(np.max(np.abs(e))),
            float(np.max(e) - np.min(e)))


def last_step(gap: np.ndarray, target: np.ndarray) -> tuple[int, int, float] | None:
    """``(start, end, step_mm)`` of the last target segment; None without a target."""
    fin = np.isfinite(target)
    if not fin.any():
        return None
    tt = np.where(fin, target, np.inf)
    change = np.flatnonzero((tt[1:] != tt[:-1]) & fin[1:]) + 1
    starts = ([0] if fin[0] else []) + change.tolist()
    start = starts[-1]
    end = start
    while end < target.size and fin[end]:
        end += 1
    before = gap[start] if start == 0 or not fin[start - 1] else target[start - 1]
    return start, end, float(target[start] - before)


def settling_and_overshoot(gap: np.ndarray, target: np.ndarray, h_s: float,
                           tol_mm: float = TOL_MM) -> tuple[float, float, float]:
    """Settling time (s), overshoot (mm) and overshoot (%) of the last target change."""
    seg = last_step(gap, target)
    if seg is None:
        return math.nan, math.nan, math.nan
    start, end, step = seg
    e = gap[start:end] - target[start:end]
    out = np.flatnonzero(np.abs(e) > tol_mm)
    if out.size == 0:
        settle = 0.0
    elif out[-1] == e.size - 1:
        settle = math.nan  # still outside the band at the end of the segment
    else:
        settle = (out[-1] + 1) * h_s
    if step == 0.0:
        return settle, 0.0, 0.0
    over = max(0.0, float(np.max(np.sign(step) * e)))
    return settle, over, 100.0 * over / abs(step)


def itae(gap: np.ndarray, target: np.ndarray, h_s: float) -> float:
    """Integral of time-weighted absolute error over the target ticks (mm s^2)."""
    i0 = _first_target_index(target)
    if i0 is None:
        return math.nan
    e = gap[i0:] - target[i0:]
    t = np.arange(e.size) * h_s
    ok = np.isfinite(e)
    return float(np.sum(t[ok] * np.abs(e[ok])) * h_s)


def count_rising(flag: np.ndarray) -> int:
    """Count False -> True transitions (a flag already True at index 0 counts once)."""
    f = np.asarray(flag, dtype=bool)
    if f.size == 0:
        return 0
    return int(f[0]) + int(np.count_nonzero(f[1:] & ~f[:-1]))


def limit_hits(command: np.ndarray, h_s: float, v_max_mm_s: float, a_max_mm_s2: float,
               internals: Mapping[str, np.ndarray] | None = None) -> tuple[int, int]:
    """Ticks at the velocity and at the acceleration limit (internals flags or by value)."""
    internals = internals or {}
    if 'limit_flags' in internals:
        f = np.nan_to_num(np.asarray(internals['limit_flags'], dtype=float)).astype(np.int64)
        return (int(np.count_nonzero(f & LIMIT_FLAG_VELOCITY)),
                int(np.count_nonzero(f & LIMIT_FLAG_ACCELERATION)))
    v_key = next((k for k in _V_KEYS if k in internals), None)
    a_key = next((k for k in _A_KEYS if k in internals), None)
    u = np.asarray(command, dtype=float)
    if v_key is not None:
        nv = int(np.count_nonzero(np.nan_to_num(internals[v_key])))
    else:
        nv = int(np.count_nonzero(np.abs(u) >= v_max_mm_s * (1 - 1e-6)))
    if a_key is not None:
        na = int(np.count_nonzero(np.nan_to_num(internals[a_key])))
    else:
        du = np.abs(np.diff(u, prepend=0.0))
        na = int(np.count_nonzero(du >= a_max_mm_s2 * h_s * (1 - 1e-6)))
    return nv, na


def compute_metrics(t_s: np.ndarray, true_gap_mm: np.ndarray, target_gap_mm: np.ndarray,
                    collision: np.ndarray, command_mm_s: np.ndarray, *, h_s: float,
                    v_max_mm_s: float, a_max_mm_s2: float,
                    internals: Mapping[str, np.ndarray] | None = None,
                    tol_mm: float = TOL_MM, hold_s: float = HOLD_S) -> Metrics:
    """All metrics of one run from its series (see the module docstring)."""
    gap = np.asarray(true_gap_mm, dtype=float)
    target = np.asarray(target_gap_mm, dtype=float)
    i0 = _first_target_index(target)
    fi = followed_index(gap, target, h_s, tol_mm, hold_s)
    if fi is None or i0 is None:
        followed_at = ttf = math.nan
        rms = emax = p2p = math.nan
    else:
        followed_at = float(t_s[fi])
        ttf = float(t_s[fi] - t_s[i0])
        rms, emax, p2p = follow_errors(gap, target, fi)
    settle, over, over_pct = settling_and_overshoot(gap, target, h_s, tol_mm)
    nv, na = limit_hits(command_mm_s, h_s, v_max_mm_s, a_max_mm_s2, internals)
    return Metrics(followed_at_s=followed_at, time_to_follow_s=ttf, error_rms_mm=rms,
                   error_max_mm=emax, error_p2p_mm=p2p, settling_time_s=settle,
                   overshoot_mm=over, overshoot_pct=over_pct,
                   itae_mm_s2=itae(gap, target, h_s), collisions=count_rising(collision),
                   limit_v_ticks=nv, limit_a_ticks=na)
