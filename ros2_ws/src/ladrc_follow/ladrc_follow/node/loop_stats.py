"""The follow loop's own timing: tick periods, overruns, input age, for /diagnostics.

Recorded by the loop thread at each tick (a few float stores), summarised once a second by the
housekeeping thread (percentiles over the ring of the last 4096 periods).
"""

from __future__ import annotations

import time

import numpy as np

RING = 4096


class LoopStats:
    """Periods and input ages of the ticks; :meth:`window` summarises since the last call."""

    def __init__(self, period_ns: int, lockstep: bool) -> None:
        self.period_ns = period_ns
        self.lockstep = lockstep  # periods then measure the sim's pace: no overruns
        self._ring = np.zeros(RING)
        self._last_start_ns = 0
        self.overruns = 0
        self._age_max_us = 0.0
        self._ticks_at_window = 0
        self._window_t_ns = time.monotonic_ns()

    def tick(self, index: int, start_ns: int, age_us: float) -> tuple[float, bool]:
        """Record tick ``index`` started at ``start_ns``; return (period µs, overrun)."""
        period_ns = start_ns - self._last_start_ns if self._last_start_ns else self.period_ns
        self._last_start_ns = start_ns
        period_us = period_ns * 1e-3
        self._ring[index & (RING - 1)] = period_us
        overrun = period_ns > 2 * self.period_ns and not self.lockstep
        if overrun:
            self.overruns += 1
        if age_us > self._age_max_us:
            self._age_max_us = age_us
        return period_us, overrun

    def window(self, ticks_so_far: int) -> dict[str, float]:
        """Rate, period percentiles, overruns, largest input age since the last call."""
        now = time.monotonic_ns()
        elapsed = (now - self._window_t_ns) * 1e-9
        ticks = ticks_so_far - self._ticks_at_window
        self._window_t_ns, self._ticks_at_window = now, ticks_so_far
        n = min(ticks, RING, ticks_so_far)
        periods = (self._ring[np.arange(ticks_so_far - n, ticks_so_far) & (RING - 1)] if n
                   else np.zeros(1))
        age, self._age_max_us = self._age_max_us, 0.0
        return {
            'rate_hz': ticks / elapsed if elapsed > 0 else 0.0,
            'period_p50_us': float(np.percentile(periods, 50)),
            'period_p99_us': float(np.percentile(periods, 99)),
            'period_max_us': float(periods.max()),
            'overruns': float(self.overruns),
            'input_age_max_us': age,
        }
