"""A minimal closed loop around FollowController for headless tests (axis model, ideal sensor)."""

from __future__ import annotations

from ladrc_follow.control.follow import FollowController, TickInput
from ladrc_sim.models.axis import Axis, AxisParams

H = 0.0005


class Loop:
    """A minimal closed loop (sim axis model, ideal sensor) whose inputs a hook can corrupt."""

    def __init__(self, ctrl: FollowController, gap0_mm: float = 1.0, sheet=None,
                 cnc=None) -> None:
        self.c = ctrl
        self.sheet = sheet or (lambda t: 0.0)
        self.cnc = cnc  # cnc(i, t) -> the CNC's motion sample of tick i (CncInput) or None
        self.axis = Axis(AxisParams(), self.sheet(0.0) + gap0_mm, H)
        self.i = 0
        self.u: list[float] = []
        self.states: list[int] = []
        self.gap: list[float] = []
        self.enable: list[bool] = []

    def run(self, n: int, hook=None) -> None:
        for _ in range(n):
            t = self.i * H
            pos = self.axis.position_mm
            gap = pos - self.sheet(t)
            d = dict(t_s=t, gap_mm=gap, gap_valid=True, gap_stamp_s=t, encoder_mm=pos,
                     encoder_stamp_s=t, drive_enabled=True, drive_fault=False, gap_status=0)
            if hook is not None:
                hook(self.i, d)
            u = self.c.step(TickInput(**d), None if self.cnc is None else self.cnc(self.i, t))
            self.u.append(u)
            self.states.append(int(self.c.state))
            self.gap.append(gap)
            self.enable.append(self.c.enable)
            self.axis.step(u, d['drive_enabled'], d['drive_fault'])
            self.i += 1

    def run_until(self, pred, max_ticks: int, hook=None) -> int:
        for k in range(max_ticks):
            if pred():
                return k
            self.run(1, hook)
        raise AssertionError(f'condition not reached within {max_ticks} ticks '
                             f'(state {self.c.state.name}, reason {self.c.fault_reason!r})')
