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

from ladrc_contract.codes import LimitFlag
import numpy as np

TOL_MM = 0.05
HOLD_S = 0.05
_V_KEYS = ('limit_v', 'saturated', 'v_limited')
_A_KEYS = ('limit_a', 'rate_limited', 'a_limited')
LIMIT_FLAG_VELOCITY, LIMIT_FLAG_ACCELERATION = int(LimitFlag.VELOCITY), int(LimitFlag.ACCELERATION)


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


def _inside_run(inside: np.ndarray, run0: int = 0) -> np.ndarray:
    """Length of the run of consecutive True ending at each index (``run0`` carried in)."""
    idx = np.arange(inside.size)
    # distance to the last False; before the first one, the run carried in continues
    last_false = np.maximum.accumulate(np.where(~inside, idx, -1 - run0))
    return idx - last_false


def followed_index(gap: np.ndarray, target: np.ndarray, h_s: float,
                   tol_mm: float = TOL_MM, hold_s: float = HOLD_S) -> int | None:
    """Index at which ``|gap - target| <= tol`` has first held for ``hold_s``; else None."""
    acc = MetricsAccumulator(h_s, tol_mm=tol_mm, hold_s=hold_s)
    acc.add(np.arange(np.size(gap)) * h_s, gap, target)
    return acc.followed_i


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


def settling_and_overshoot(gap: np.ndarray, target: np.ndarray, h_s: float,
                           tol_mm: float = TOL_MM) -> tuple[float, float, float]:
    """Settling time (s), overshoot (mm) and overshoot (%) of the last target change."""
    acc = MetricsAccumulator(h_s, tol_mm=tol_mm)
    acc.add(np.arange(np.size(gap)) * h_s, gap, target)
    return acc.settling()


def itae(gap: np.ndarray, target: np.ndarray, h_s: float) -> float:
    """Integral of time-weighted absolute error over the target ticks (mm s^2)."""
    acc = MetricsAccumulator(h_s)
    acc.add(np.arange(np.size(gap)) * h_s, gap, target)
    return acc.itae()


def count_rising(flag: np.ndarray, before: bool = False) -> int:
    """Count False -> True transitions (``before``: the flag just before index 0)."""
    f = np.asarray(flag, dtype=bool)
    if f.size == 0:
        return 0
    return int(f[0] and not before) + int(np.count_nonzero(f[1:] & ~f[:-1]))


def limit_hits(command: np.ndarray, h_s: float, v_max_mm_s: float, a_max_mm_s2: float,
               internals: Mapping[str, np.ndarray] | None = None,
               u_before: float = 0.0) -> tuple[int, int]:
    """Ticks at the velocity and at the acceleration limit (internals flags or by value).

    ``u_before``: the command just before index 0 (for the step of the first tick).
    """
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
        du = np.abs(np.diff(u, prepend=u_before))
        na = int(np.count_nonzero(du >= a_max_mm_s2 * h_s * (1 - 1e-6)))
    return nv, na


class MetricsAccumulator:
    """The metrics of one run, fed in consecutive slices (:meth:`add`); memory is constant.

    The one implementation behind :func:`compute_metrics` (one slice) and the report of an
    hours-long bag (many slices): every quantity is a running sum, extreme or the state of
    the current target segment, carried from slice to slice.
    """

    def __init__(self, h_s: float, *, v_max_mm_s: float = math.inf,
                 a_max_mm_s2: float = math.inf, tol_mm: float = TOL_MM,
                 hold_s: float = HOLD_S) -> None:
        self.h_s, self.tol_mm = h_s, tol_mm
        self.v_max_mm_s, self.a_max_mm_s2 = v_max_mm_s, a_max_mm_s2
        self.need = max(1, int(round(hold_s / h_s)))
        self.n = 0                          # ticks seen
        self.first_i: int | None = None     # first target tick
        self.first_t = math.nan
        self.followed_i: int | None = None
        self.followed_t = math.nan
        self._run = 0                       # inside-band run at the end of the last slice
        self._sq, self._count = 0.0, 0      # error sums from the followed tick on
        self._emax = self._ehi = self._elo = -math.inf
        self._itae = 0.0
        self._prev_tt = math.inf            # target of the last tick (inf: none)
        self._seg: dict | None = None       # the last target segment (settling, overshoot)
        self._collision_before = False
        self._collisions = 0
        self._nv = self._na = 0
        self._u_before = 0.0

    @property
    def error_ticks(self) -> int:
        """Ticks the error metrics are taken over: with a target, from the followed tick on."""
        return self._count

    def add(self, t_s: np.ndarray, gap: np.ndarray, target: np.ndarray,
            collision: np.ndarray | None = None, command_mm_s: np.ndarray | None = None,
            internals: Mapping[str, np.ndarray] | None = None) -> None:
        """Feed the next slice of the run's series (the arguments of compute_metrics)."""
        gap = np.asarray(gap, dtype=float)
        target = np.asarray(target, dtype=float)
        base, n = self.n, gap.size
        if n == 0:
            return
        fin = np.isfinite(target)
        if self.first_i is None and fin.any():
            i = int(np.argmax(fin))
            self.first_i, self.first_t = base + i, float(t_s[i])
        # followed: |e| <= tol held for hold_s (a run of more than `need` ticks)
        inside = fin & (np.abs(gap - target) <= self.tol_mm)
        run = _inside_run(inside, self._run)
        self._run = int(run[-1])
        start = None
        if self.followed_i is None:
            hit = np.flatnonzero(inside & (run > self.need))
            if hit.size:
                start = int(hit[0])
                self.followed_i, self.followed_t = base + start, float(t_s[start])
        else:
            start = 0
        if start is not None:  # error figures from the followed tick on
            e = (gap - target)[start:]
            e = e[np.isfinite(e)]
            if e.size:
                self._sq += float(np.sum(e * e))
                self._count += e.size
                self._emax = max(self._emax, float(np.max(np.abs(e))))
                self._ehi = max(self._ehi, float(np.max(e)))
                self._elo = max(self._elo, float(-np.min(e)))
        if self.first_i is not None:  # ITAE from the first target tick
            i0 = max(0, self.first_i - base)
            e = gap[i0:] - target[i0:]
            t = (np.arange(e.size) + (base + i0 - self.first_i)) * self.h_s
            ok = np.isfinite(e)
            self._itae += float(np.sum(t[ok] * np.abs(e[ok])))
        self._segments(gap, target, fin)
        if collision is not None:
            self._collisions += count_rising(collision, self._collision_before)
            self._collision_before = bool(np.asarray(collision)[-1])
        if command_mm_s is not None:
            nv, na = limit_hits(command_mm_s, self.h_s, self.v_max_mm_s, self.a_max_mm_s2,
                                internals, self._u_before)
            self._nv += nv
            self._na += na
            self._u_before = float(np.asarray(command_mm_s, dtype=float)[-1])
        self.n += n

    def _segments(self, gap: np.ndarray, target: np.ndarray, fin: np.ndarray) -> None:
        """Track the last target segment: a new target value, or a target after none."""
        tt = np.where(fin, target, np.inf)
        prev = np.concatenate(([self._prev_tt], tt[:-1]))
        starts = np.flatnonzero((tt != prev) & fin)
        a = 0
        if starts.size:
            a = int(starts[-1])
            before = gap[a] if prev[a] == np.inf else prev[a]
            self._seg = {'step': float(target[a] - before), 'len': 0, 'last_out': -1,
                         'over': -math.inf, 'open': True}
        self._prev_tt = float(tt[-1])
        seg = self._seg
        if seg is None or not seg['open']:
            return
        gone = np.flatnonzero(~fin[a:])
        b = a + int(gone[0]) if gone.size else gap.size
        if gone.size:
            seg['open'] = False
        e = gap[a:b] - target[a:b]
        out = np.flatnonzero(np.abs(e) > self.tol_mm)
        if out.size:
            seg['last_out'] = seg['len'] + int(out[-1])
        seg['len'] += e.size
        if e.size:
            seg['over'] = float(np.maximum(seg['over'], np.max(np.sign(seg['step']) * e)))

    def settling(self) -> tuple[float, float, float]:
        """Settling time (s), overshoot (mm, %) of the last target change (module doc)."""
        seg = self._seg
        if seg is None:
            return math.nan, math.nan, math.nan
        if seg['last_out'] < 0:
            settle = 0.0
        elif seg['last_out'] == seg['len'] - 1:
            settle = math.nan  # still outside the band at the end of the segment
        else:
            settle = (seg['last_out'] + 1) * self.h_s
        step = seg['step']
        if step == 0.0:
            return settle, 0.0, 0.0
        over = max(0.0, seg['over'])
        return settle, over, 100.0 * over / abs(step)

    def itae(self) -> float:
        """ITAE so far (mm s^2); NaN before the first target tick."""
        return math.nan if self.first_i is None else self._itae * self.h_s

    def result(self) -> Metrics:
        """Return the metrics of everything fed so far."""
        if self.followed_i is None or self.first_i is None or self._count == 0:
            followed_at = ttf = rms = emax = p2p = math.nan
            if self.followed_i is not None and self.first_i is not None:
                followed_at = self.followed_t
                ttf = self.followed_t - self.first_t
        else:
            followed_at = self.followed_t
            ttf = self.followed_t - self.first_t
            rms = math.sqrt(self._sq / self._count)
            emax, p2p = self._emax, self._ehi + self._elo
        settle, over, over_pct = self.settling()
        return Metrics(followed_at_s=followed_at, time_to_follow_s=ttf, error_rms_mm=rms,
                       error_max_mm=emax, error_p2p_mm=p2p, settling_time_s=settle,
                       overshoot_mm=over, overshoot_pct=over_pct, itae_mm_s2=self.itae(),
                       collisions=self._collisions, limit_v_ticks=self._nv,
                       limit_a_ticks=self._na)


def compute_metrics(t_s: np.ndarray, true_gap_mm: np.ndarray, target_gap_mm: np.ndarray,
                    collision: np.ndarray, command_mm_s: np.ndarray, *, h_s: float,
                    v_max_mm_s: float, a_max_mm_s2: float,
                    internals: Mapping[str, np.ndarray] | None = None,
                    tol_mm: float = TOL_MM, hold_s: float = HOLD_S) -> Metrics:
    """All metrics of one run from its series (see the module docstring)."""
    acc = MetricsAccumulator(h_s, v_max_mm_s=v_max_mm_s, a_max_mm_s2=a_max_mm_s2,
                             tol_mm=tol_mm, hold_s=hold_s)
    acc.add(t_s, true_gap_mm, target_gap_mm, collision, command_mm_s, internals)
    return acc.result()
