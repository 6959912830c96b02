"""Velocity/acceleration-limited move planner for the PREINTERPOLATE phase.

The seed's ``Follow_OnStep`` (notes §3.5) approaches the sheet with an
interpolator: every tick it calls ``Interp_GoDistance(target − height −
Interp_GetCachedL())``, i.e. it adds to the planned move whatever the plan does
not yet cover, and commands the interpolator's per-tick step as velocity. This
module is that interpolator in mm and mm/s.

Profile: discrete-time trapezoid (triangle for short moves) with the exact
braking distance of the sampled system. The axis moves ``v_k·h`` in tick k
(velocity held for one period) and the velocity may change by at most
Δ = a_max·h per tick. From velocity v, braking as v, v−Δ, v−2Δ, … covers
``h·((m+1)·v − Δ·m(m+1)/2)`` with m = ⌊v/Δ⌋, so the largest velocity that can
still stop inside a remaining distance d (R = d/h) is

    m = max{m : Δ·m(m+1)/2 ≤ R},   v_stop(d) = (R + Δ·m(m+1)/2)/(m + 1).

Each tick commands min(v_max, v_stop) clipped to ±Δ around the previous
velocity, in the direction of the remaining distance. Re-targeting (more or
less distance, or a reversal) simply changes the remaining distance; if the
axis is then too fast or moving away it brakes at a_max, overshoots if it must,
and comes back — never stepping the velocity by more than Δ. The last tick
covers the residual exactly and the remaining distance is set to zero.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

from ladrc_contract.schema import Section, param


@dataclass(frozen=True)
class InterpParams(Section):
    """Limits of the approach move (``ControllerParams.interp``)."""

    PREFIX = 'interp.'

    # 60, not 100: half off the sheet the reading moves up to 2x the gap (sensor edge model),
    # so the plan, made in reading units, needs ~2x the braking margin; at 100 mm/s the
    # edge_open_10_1 approach reached the 0.2 mm collision limit (docs/quality.md).
    v_max_mm_s: float = param(60.0, 'mm/s', 'speed limit of the approach move',
                              ge=0.1, le=1000.0, seed='notes §3.5 Interp_GoDistance')
    a_max_mm_s2: float = param(2000.0, 'mm/s²', 'acceleration limit of the approach move',
                               ge=10.0, le=1e6, seed='notes §3.5 Interp_GoDistance')


def stop_velocity(distance_mm: float, dv_mm_s: float, h_s: float) -> float:
    """Largest velocity (≥ 0) from which braking by ``dv`` per tick stops within ``distance``."""
    if distance_mm <= 0.0:
        return 0.0
    big_r = distance_mm / h_s
    # largest m with dv·m(m+1)/2 ≤ R: positive root of m² + m − 2R/dv, then fix rounding
    m = int((math.sqrt(1.0 + 8.0 * big_r / dv_mm_s) - 1.0) * 0.5)
    # the root is off by at most one or two in floating point: a bounded fix-up (an unbounded
    # loop would never end once m passes 2**53, e.g. for an absurdly small deceleration)
    for _ in range(4):
        if m > 0 and dv_mm_s * m * (m + 1) * 0.5 > big_r:
            m -= 1
        elif dv_mm_s * (m + 1) * (m + 2) * 0.5 <= big_r:
            m += 1
        else:
            break
    return (big_r + dv_mm_s * m * (m + 1) * 0.5) / (m + 1)


class Interpolator:
    """Seed ``Interp`` with cached length: ``go_distance`` adds, ``step`` plans one tick."""

    def __init__(self, params: InterpParams | None = None, h_s: float = 0.0005) -> None:
        self.params = params or InterpParams()
        problems = self.params.problems()
        if not h_s > 0.0:
            problems.append(f'h_s must be > 0, got {h_s!r}')
        if problems:
            raise ValueError('; '.join(problems))
        self.h_s = float(h_s)
        self.reset()

    def reset(self, velocity_mm_s: float = 0.0) -> None:
        """Clear the plan; ``velocity_mm_s`` is the axis velocity to start from."""
        self._remaining = 0.0
        self.velocity_mm_s = float(velocity_mm_s)
        self.position_mm = 0.0  # planned displacement since reset (∑ v·h)

    @property
    def cached_length_mm(self) -> float:
        """Planned distance not yet commanded (seed ``Interp_GetCachedL``), signed."""
        return self._remaining

    def go_distance(self, d_mm: float) -> None:
        """Add ``d_mm`` (signed, + = up) to the planned move (seed ``Interp_GoDistance``)."""
        if not math.isfinite(d_mm):
            raise ValueError(f'go_distance needs a finite distance in mm, got {d_mm!r}')
        self._remaining += d_mm

    def is_finished(self) -> bool:
        """Return True when the plan is fully commanded and the axis is commanded to rest."""
        return self._remaining == 0.0 and self.velocity_mm_s == 0.0

    def step(self) -> float:
        """Return this tick's velocity command (mm/s) and advance the plan by ``v·h``."""
        h = self.h_s
        dv = self.params.a_max_mm_s2 * h
        rem = self._remaining
        sgn = -1.0 if rem < 0.0 else 1.0
        dist = rem * sgn
        v_rel = self.velocity_mm_s * sgn  # velocity along the remaining distance
        v_stop = stop_velocity(dist, dv, h)
        v_des = min(self.params.v_max_mm_s, v_stop)
        v_new = min(max(v_des, v_rel - dv), v_rel + dv)
        if v_new > 0.0 and v_new * h >= dist and dist / h >= v_rel - dv:
            # the terminal (fractional) tick: land exactly, no floating residue
            v_new = dist / h
            self._remaining = 0.0
        else:
            self._remaining = rem - sgn * v_new * h
        v = sgn * v_new
        self.velocity_mm_s = v
        self.position_mm += v * h
        return v
