"""Leapfrog (Beckhoff TF5290): lift as the rapid starts, arrive at the pierce height as it ends.

A position plan in machine Z (the encoder's coordinate) over the rapid's duration
``T = rapid_length / rapid_feed`` (its lower bound: a rapid with acceleration phases takes
longer, so the plan arrives early, never late, and the rapid never waits for it). Each move is
the minimum-jerk quintic ``z(τ) = z0 + Δ(10τ³ − 15τ⁴ + 6τ⁵)``: zero velocity and acceleration
at both ends, peak velocity ``1.875 Δ/T_m`` and acceleration ``5.774 Δ/T_m²``, so the shortest
move within the axis limits takes ``T_m = max(1.875 Δ/v, sqrt(5.774 Δ/a))``. Up to the peak
(``lift_mm`` above the sheet level measured at the start), held, then down so as to reach
``arrive_height_mm`` above that level at ``T``; a rapid too short for the peak gets a lower
one (bisection), one too short for even the direct move arrives late, by the time reported.

The command is the plan's velocity plus a position correction on the encoder (``K_POS_1_S``),
and it holds the arrival level once there. Toward the sheet it is bounded: never faster than
the distance left over ``settle_s`` (an exponential approach that a velocity loop lagging by a
quarter of it follows without undershoot: the drive's lag would otherwise carry the axis below
the plan), the distance to the arrival level and, by a valid reading, to the arrival height
(a sheet higher there than at the start); a reading below the arrival height moves it up
(:meth:`Leapfrog.velocity`). The plan ends ``settle_s`` before the rapid for that approach.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

QUINTIC_V = 1.875
"""Peak velocity of the minimum-jerk quintic, in units of Δ/T."""
QUINTIC_A = 5.7735
"""Peak acceleration of the minimum-jerk quintic (10/√3), in units of Δ/T²."""
K_POS_1_S = 50.0
"""Position correction gain of the plan's tracking [1/s] (20 ms): well below the axis' band."""


def move_time_s(distance_mm: float, v_mm_s: float, a_mm_s2: float) -> float:
    """Shortest quintic move of ``distance_mm`` within the velocity and acceleration limits."""
    d = abs(distance_mm)
    return max(QUINTIC_V * d / v_mm_s, math.sqrt(QUINTIC_A * d / a_mm_s2))


def quintic(distance_mm: float, duration_s: float, t_s: float) -> tuple[float, float]:
    """Return (position, velocity) of the quintic move at ``t_s`` from its start."""
    if duration_s <= 0.0 or t_s >= duration_s:
        return distance_mm, 0.0
    if t_s <= 0.0:
        return 0.0, 0.0
    x = t_s / duration_s
    pos = distance_mm * x * x * x * (10.0 + x * (-15.0 + 6.0 * x))
    vel = distance_mm / duration_s * 30.0 * x * x * (1.0 - x) * (1.0 - x)
    return pos, vel


@dataclass(frozen=True)
class LeapfrogPlan:
    """The planned Z moves of one leapfrog, in machine Z (encoder) coordinates."""

    z0_mm: float        # start position
    peak_mm: float      # peak position
    end_mm: float       # arrival position (arrive_height_mm above the start's sheet level)
    up_s: float         # duration of the move up
    down_start_s: float  # when the move down starts
    down_s: float       # duration of the move down
    late_s: float       # how much after the rapid's estimated end the plan arrives (0: on time)

    @property
    def end_s(self) -> float:
        """When the plan arrives."""
        return self.down_start_s + self.down_s

    def at(self, t_s: float) -> tuple[float, float]:
        """Return the planned (position, velocity) at ``t_s`` from the start."""
        if t_s < self.down_start_s:
            p, v = quintic(self.peak_mm - self.z0_mm, self.up_s, t_s)
            return self.z0_mm + p, v
        p, v = quintic(self.end_mm - self.peak_mm, self.down_s, t_s - self.down_start_s)
        return self.peak_mm + p, v


def plan(z0_mm: float, sheet_mm: float, lift_mm: float, arrive_mm: float, rapid_s: float,
         v_mm_s: float, a_mm_s2: float) -> LeapfrogPlan:
    """Plan a leapfrog from ``z0_mm`` over a sheet at ``sheet_mm`` within ``rapid_s``."""
    end = sheet_mm + arrive_mm
    low = max(z0_mm, end)  # the lowest peak: the higher of start and arrival

    def total(peak: float) -> float:
        return move_time_s(peak - z0_mm, v_mm_s, a_mm_s2) + move_time_s(peak - end, v_mm_s,
                                                                        a_mm_s2)

    peak = max(sheet_mm + lift_mm, low)
    if total(peak) > rapid_s:
        if total(low) >= rapid_s:
            peak = low
        else:  # the highest peak that still arrives in time
            lo, hi = low, peak
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if total(mid) <= rapid_s else (lo, mid)
            peak = lo
    up = move_time_s(peak - z0_mm, v_mm_s, a_mm_s2)
    down = move_time_s(peak - end, v_mm_s, a_mm_s2)
    start_down = max(up, rapid_s - down)
    return LeapfrogPlan(z0_mm, peak, end, up, start_down, down,
                        max(0.0, start_down + down - rapid_s))


class Leapfrog:
    """A running leapfrog: the plan, its clock, and the command that tracks it."""

    def __init__(self, p: LeapfrogPlan, arrive_mm: float, h_s: float, settle_s: float) -> None:
        self.plan = p
        self.arrive_mm = arrive_mm
        self._h = h_s
        self._settle_s = settle_s
        self._k = 0
        self.done = False

    def velocity(self, enc_mm: float, gap_mm: float) -> float:
        """Return this tick's command; ``gap_mm``: a valid reading, else NaN."""
        t = self._k * self._h
        self._k += 1
        z, v = self.plan.at(t)
        if t >= self.plan.end_s:
            self.done = True
        u = v + K_POS_1_S * (z - enc_mm)
        # toward the sheet at most the distance left over settle_s: to the arrival level, and
        # to the arrival height by a valid reading (a sheet higher there than at the start);
        # a reading below the arrival height moves the axis up
        left = enc_mm - self.plan.end_mm
        if gap_mm - self.arrive_mm < left:  # (False for NaN: no reading)
            left = gap_mm - self.arrive_mm
        floor = -left / self._settle_s
        return u if u > floor else floor
