"""The job world's view of a separate CNC: what the sheet learns of the CNC from ``cnc/motion``.

With the CNC in the same loop (``ladrc job``, the sim node playing the CNC) the sheet sees the
CNC's own XY every tick. A separate CNC (the CNC node, or a bridge to a real CNC: docs/
job-world.md, "A separate CNC") is known to the world only by its motion samples, one per CNC
cycle (``CncMotion``: XY, segment, beam, contour, feeds). :class:`MotionView` is that view: the
newest sample's values, its XY extrapolated along the last two samples to the tick (at most one
cycle ahead, then held: a CNC gone silent does not move the nozzle), and a contour counted as
cut to its end when the samples' contour number leaves it. :class:`KerfLayer` is the beam on a
sheet: a kerf every ``KERF_STEP_MM`` of cut path, the rest when the beam goes off. Both serve the
world's sheet; the CNC's own model of the sheet (its edge-ahead distance) has its own
:class:`KerfLayer` on its own XY (:mod:`.cnc_station`).
"""

from __future__ import annotations

import math
from typing import Any

from ladrc_contract.codes import Segment

KERF_STEP_MM = 0.2
"""The beam lays its kerf every this much of path (finer than the raster's 0.25 mm cells)."""

CUT, NONE = int(Segment.CUT), int(Segment.NONE)


class KerfLayer:
    """The beam on ``sheet``: call :meth:`step` once per tick with the beam's XY."""

    def __init__(self, sheet: Any, kerf_mm: float) -> None:
        self.sheet = sheet
        self.kerf_mm = kerf_mm
        self._from: tuple[float, float] | None = None  # where the kerf not yet laid starts

    def step(self, x: float, y: float, cutting: bool) -> None:
        """Lay what the beam cut: it is at (x, y) now, on along a cut (True) or not."""
        start = self._from
        if cutting:
            if start is None:
                self._from = (x, y)
            elif math.hypot(x - start[0], y - start[1]) >= KERF_STEP_MM:
                self.sheet.lay_kerf(start[0], start[1], x, y, self.kerf_mm)
                self._from = (x, y)
        elif start is not None:
            self.sheet.lay_kerf(start[0], start[1], x, y, self.kerf_mm)
            self._from = None


class MotionView:
    """The CNC as the world sees it through its motion samples (module docstring).

    The attributes the job runner reads of a CNC: ``x``, ``y``, ``segment``, ``beam``,
    ``contour``, ``actual_feed_mm_s``, ``feed_mm_s`` (commanded) and ``cut_done`` (0-based
    indices of the contours cut to their end at this tick).
    """

    def __init__(self, x0_mm: float, y0_mm: float) -> None:
        self.x, self.y = x0_mm, y0_mm
        self.segment, self.beam, self.contour = NONE, False, 0
        self.actual_feed_mm_s = self.feed_mm_s = 0.0
        self.cut_done: list[int] = []
        self._last: tuple[float, float, float] | None = None  # (t, x, y) of the newest sample
        self._prev: tuple[float, float, float] | None = None

    def see(self, t_s: float, sample: Any, x_mm: float = math.nan,
            y_mm: float = math.nan) -> None:
        """Tick at ``t_s``: take ``sample`` (a ``CncInput`` taken now, its XY) or None."""
        self.cut_done = []
        if sample is not None:
            if self.contour > 0 and sample.contour != self.contour:
                self.cut_done.append(self.contour - 1)
            self.segment, self.beam, self.contour = (int(sample.segment), bool(sample.beam_on),
                                                     int(sample.contour))
            self.feed_mm_s = float(sample.commanded_feed_mm_s)
            self.actual_feed_mm_s = float(sample.actual_feed_mm_s)
            if math.isfinite(x_mm) and math.isfinite(y_mm):
                self._prev, self._last = self._last, (t_s, x_mm, y_mm)
        last, prev = self._last, self._prev
        if last is None:
            return
        t1, x1, y1 = last
        if prev is None or not t1 > prev[0]:
            self.x, self.y = x1, y1
            return
        cycle = t1 - prev[0]
        a = min(t_s - t1, cycle) / cycle  # ahead of the newest sample, one cycle at most
        self.x, self.y = x1 + a * (x1 - prev[1]), y1 + a * (y1 - prev[2])

    @property
    def cutting(self) -> bool:
        """The beam on along a cut (the kerf is laid)."""
        return self.beam and self.segment == CUT
