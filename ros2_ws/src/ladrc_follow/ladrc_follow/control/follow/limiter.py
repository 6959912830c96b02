"""The output limiter every command passes: ±v, ±a·h, the soft travel limits, the caps.

Order (:func:`..law.apply_limits`, then the soft Z limits): the speed against ``limits.v_max``
(and, toward the sheet, the edge guard's probing cap), the step against the previously applied
command (``limits.a_max``·h, so no hand-over steps the velocity by more), then the soft travel
limits, in every state: the speed toward a limit is at most the distance left over
``limits.soft_z_tau_s`` (an exponential approach, never past it; never forces motion). A
gradient follow caps v and a·h with its own values until followed (seed
``FollowPID_SetSpeedCtrlParam``).
"""

from __future__ import annotations

import math

from .states import LIMIT_SOFT_Z


class OutputLimiter:
    """``limit(u_c, u_prev, z_mm) -> (u, flags)``; the caps persist across parameter sets."""

    def __init__(self) -> None:
        self.capped = False
        self._cap = (math.inf, math.inf)  # a gradient follow's (v, a·h)
        self.down_cap_mm_s = math.inf  # speed cap toward the sheet (the edge guard's probing)

    def configure(self, limits, h_s: float) -> None:
        """Take ``ControllerParams.limits``; a running gradient cap stays (bounded by them)."""
        self.v_max_mm_s = limits.v_max_mm_s
        self.v_down_mm_s = limits.v_down_max_mm_s  # toward the sheet (capped by v_max)
        self.du_max_mm_s = limits.a_max_mm_s2 * h_s
        self._z_min_mm, self._z_max_mm = limits.soft_z_min_mm, limits.soft_z_max_mm
        self._tau_z_s = limits.soft_z_tau_s
        self._apply_cap()

    def cap(self, v_mm_s: float, du_mm_s: float) -> None:
        """Cap the speed and the step per tick (a gradient follow) until :meth:`uncap`."""
        self.capped = True
        self._cap = (v_mm_s, du_mm_s)
        self._apply_cap()

    def uncap(self) -> None:
        """Back to the parameter set's limits."""
        self.capped = False
        self._apply_cap()

    def _apply_cap(self) -> None:
        if self.capped:
            self.v_mm_s = min(self._cap[0], self.v_max_mm_s)
            self.du_mm_s = min(self._cap[1], self.du_max_mm_s)
        else:
            self.v_mm_s, self.du_mm_s = self.v_max_mm_s, self.du_max_mm_s

    def limit(self, u_c: float, u_prev: float, z_mm: float) -> tuple[float, int]:
        """Return the limited command and its ``LIMIT_*`` flags (``u_c`` finite)."""
        v, du = self.v_mm_s, self.du_mm_s
        vd = min(v, self.v_down_mm_s, self.down_cap_mm_s)
        us = v if u_c > v else (-vd if u_c < -vd else u_c)
        lo, hi = u_prev - du, u_prev + du
        u = lo if us < lo else (hi if us > hi else us)
        flags = (us != u_c) | ((u != us) << 1)
        down = (self._z_min_mm - z_mm) / self._tau_z_s if z_mm > self._z_min_mm else 0.0
        up = (self._z_max_mm - z_mm) / self._tau_z_s if z_mm < self._z_max_mm else 0.0
        if u < down:
            u = down
            flags |= LIMIT_SOFT_Z
        elif u > up:
            u = up
            flags |= LIMIT_SOFT_Z
        return u, flags
