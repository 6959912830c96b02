"""A separate CNC: the simulated CNC with its own model of the sheet, as the CNC node runs it.

A CNC computes the distance to the first void ahead (``CncMotion.edge_ahead_mm``) from its job:
the sheet's outline, the holes and what it has cut so far. With the CNC in the world's loop it
reads the world's sheet; a separate CNC (the CNC node, ``ladrc job --separate-cnc``) keeps its
own: the same plate, its kerfs laid along its own XY, and every contour cut to its end dropped
(a CNC does not know that a part tipped up). :class:`CncStation` is that CNC, stepped once per
controller tick by the CNC node and by the headless runner alike.
"""

from __future__ import annotations

from typing import Any, Callable

from ladrc_contract.tick import CncInput

from ..models.sheet_xy import SheetXY
from .cnc import CUT, Cnc
from .world import KerfLayer


class CncStation:
    """The CNC of ``job`` and its own sheet; ``command(name, **kw) -> (accepted, message)``."""

    def __init__(self, job: Any, program: Any, command: Callable[..., Any], h_s: float) -> None:
        self.program = program
        self.sheet = SheetXY(job.plate(), job.surface,
                             nozzle_diameter_mm=job.sensor.nozzle_diameter_mm)
        self.sheet.prepare([c.region for c in program.contours])
        self.cnc = Cnc(program, job.cnc, command, h_s, job.start_xy, self.sheet.void_ahead_mm)
        self._kerf = KerfLayer(self.sheet, job.kerf_mm)

    def step(self, answers: dict) -> CncInput | None:
        """One controller tick of the CNC; return its motion sample (None between cycles)."""
        cnc = self.cnc
        sample = cnc.step(answers)
        for k in cnc.cut_done:
            self.sheet.drop(self.program.contours[k].region)
        self._kerf.step(cnc.x, cnc.y, cnc.beam and cnc.segment == CUT)
        return sample

    def refused(self, name: str, message: str) -> None:
        """Abort the job: a command was refused after it was sent (live)."""
        self.cnc.refused(name, message)

    @property
    def xy(self) -> tuple[float, float]:
        """The CNC's XY now (that of the sample :meth:`step` returned)."""
        return self.cnc.x, self.cnc.y

    @property
    def log(self) -> Any:
        """What the CNC did (``CncLog``)."""
        return self.cnc.log
