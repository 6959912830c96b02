"""XY motion along a path as a CNC's planner makes it: acceleration-limited, corners slowed.

The path is a polyline. Each vertex gets the highest speed its corner allows (GRBL's junction
deviation: a circle of deviation ``junction_mm`` inscribed in the corner, ``v² = a δ sin(θ/2) /
(1 − sin(θ/2))``); a backward and a forward pass make every vertex reachable within the
acceleration (``v² ≤ v_next² + 2 a L``), so short segments never reach the feed. Each tick then
runs at the highest speed that still brakes for the next vertex, ramping by at most ``a h``.
"""

from __future__ import annotations

import math

import numpy as np


def _brake(v_end: float, distance_mm: float, a: float, h: float) -> float:
    """Highest speed that brakes to ``v_end`` within ``distance_mm`` by ``a h`` per tick.

    Braking in ticks covers ``(v² − v_end²) / 2a + (v − v_end) h / 2`` (the trapezoids of the
    discrete ramp), solved for ``v``.
    """
    b = 0.5 * a * h
    return -b + math.sqrt(b * b + v_end * v_end + 2.0 * a * distance_mm + 2.0 * b * v_end)


class PathMotion:
    """One move along ``points_mm`` (n x 2) at ``feed_mm_s``, starting and ending at rest."""

    def __init__(self, points_mm: np.ndarray, feed_mm_s: float, accel_mm_s2: float,
                 junction_mm: float, h_s: float) -> None:
        p = np.asarray(points_mm, dtype=float)
        seg = np.diff(p, axis=0)
        length = np.hypot(seg[:, 0], seg[:, 1])
        keep = length > 1e-9
        p = np.vstack((p[:1], p[1:][keep]))
        seg, length = seg[keep], length[keep]
        self.points = p
        self.length = length
        self.cum = np.concatenate(([0.0], np.cumsum(length)))
        self.total_mm = float(self.cum[-1])
        self.feed = feed_mm_s
        self.a = accel_mm_s2
        self.h = h_s
        n = len(length)
        v = np.zeros(n + 1)  # the speed allowed at each vertex
        if n:
            unit = seg / length[:, None]
            cos_t = -np.sum(unit[:-1] * unit[1:], axis=1)  # -1: straight on, 1: reversal
            sin_half = np.sqrt(np.clip((1.0 - cos_t) / 2.0, 0.0, 1.0))
            with np.errstate(divide='ignore'):
                vj2 = accel_mm_s2 * junction_mm * sin_half / (1.0 - sin_half)
            v[1:-1] = np.sqrt(np.minimum(vj2, feed_mm_s ** 2))
            for i in range(n - 1, -1, -1):  # backward: brake in time for every vertex
                v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2.0 * accel_mm_s2 * length[i]))
            for i in range(n):  # forward: reachable from the previous vertex
                v[i + 1] = min(v[i + 1], math.sqrt(v[i] ** 2 + 2.0 * accel_mm_s2 * length[i]))
        self.v_vertex = v.tolist()
        self._cum = self.cum.tolist()
        self.s = 0.0        # distance travelled along the path
        self.v = 0.0        # path speed
        self._i = 0         # current segment
        self.done = self.total_mm <= 0.0

    def step(self, hold: bool = False, override: float = 1.0) -> tuple[float, float]:
        """Advance one tick (``hold``: brake to a stop and stay); return the position.

        ``override``: the fraction of the feed to run at (a feed override, 0..1).
        """
        if not self.done:
            a, h = self.a, self.h
            cum = self._cum
            while self._i < len(self.length) - 1 and self.s >= cum[self._i + 1]:
                self._i += 1
            i = self._i
            to_vertex = cum[i + 1] - self.s
            to_end = self.total_mm - self.s
            v_next = self.v_vertex[i + 1]
            cap = 0.0 if hold else min(self.feed * override, _brake(v_next, to_vertex, a, h),
                                       _brake(0.0, to_end, a, h))
            v_new = min(cap, self.v + a * h) if cap >= self.v else max(cap, self.v - a * h)
            ds = v_new * h  # the speed of this tick (the braking bound counts the same way)
            if ds >= to_end - 1e-9 and not hold:
                ds, v_new = to_end, 0.0
                self.done = True
            elif to_end < 1e-3 and v_new < 1e-6 and not hold:
                ds, self.done = to_end, True  # crept to the end
            elif v_new <= 1e-9 and not hold and to_end > 0.0:
                v_new = min(a * h, cap) if cap > 0.0 else a * h  # never stall before the end
            self.s += ds
            self.v = v_new
        return self.position(self.s)

    def position(self, s_mm: float) -> tuple[float, float]:
        """Return the point at path distance ``s_mm``."""
        cum = self._cum
        s_mm = min(max(s_mm, 0.0), self.total_mm)
        i = min(int(np.searchsorted(self.cum, s_mm, side='right')) - 1, len(self.length) - 1)
        i = max(i, 0)
        if not len(self.length):
            return float(self.points[0, 0]), float(self.points[0, 1])
        f = (s_mm - cum[i]) / self.length[i]
        p0, p1 = self.points[i], self.points[i + 1]
        return float(p0[0] + f * (p1[0] - p0[0])), float(p0[1] + f * (p1[1] - p0[1]))

    def ahead(self, distance_mm: float, step_mm: float) -> np.ndarray:
        """Return points every ``step_mm`` along the path ahead, up to ``distance_mm``."""
        s = self.s + np.arange(1, int(distance_mm / step_mm) + 1) * step_mm
        s = s[s <= self.total_mm]
        if s.size == 0:
            return np.zeros((0, 2))
        x = np.interp(s, self.cum, self.points[:, 0])
        y = np.interp(s, self.cum, self.points[:, 1])
        return np.c_[x, y]
