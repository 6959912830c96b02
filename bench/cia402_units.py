"""What the CiA 402 bus's integer units cost the follow: each part alone, headless.

    scripts/in-env python bench/cia402_units.py [--scenarios showcase,step]

The CiA 402 path (docs/cia402.md) differs from the simulator's own drive only in what crosses
the bus as integers and in the drive's power-up; this bench puts each difference alone into the
headless closed loop (the same runner, models and controller) and prints the error RMS against
the true gap:

* ``baseline``: the simulator's drive (what the sim node in lock step equals bit for bit);
* ``gap_counts``: the gap reading through the analog input, 1000 counts per mm (nearest count,
  ``AnalogScale``);
* ``position_increments``: the encoder through 0x6064 at 1000 increments per mm (nearest);
* ``velocity_units``: the command through 0x60FF at 1000 units per mm/s, rounded toward zero
  (``DriveUnits.velocity_command``);
* ``power_up``: the drive needs 3 SYNCs from Switch on disabled to Operation enabled (one
  transition per period): the follow node sees ``drive_enabled`` false in samples 0-2;
* ``all``: everything at once, what ``bringup --drive cia402 --lockstep`` runs.

Last line: one JSON object, ``scenarios`` with per scenario each variant's ``error_rms_mm``
and ``relative`` (to the baseline), and ``max_relative_all`` (the largest |all / baseline - 1|).
"""

from __future__ import annotations

import argparse
import json

from ladrc_cia402.units import AnalogScale, DriveUnits
from ladrc_contract.tick import TickInput
from ladrc_follow.control.follow import FollowController
from ladrc_follow.control.params import ControllerParams
from ladrc_sim.headless.runner import run

VARIANTS = ('baseline', 'gap_counts', 'position_increments', 'velocity_units', 'power_up', 'all')


class BusUnits:
    """The controller behind the bus's integer units (one or all of them)."""

    def __init__(self, variant: str) -> None:
        self.ctrl = FollowController(ControllerParams())
        self.v = variant
        self.units, self.analog = DriveUnits(), AnalogScale()
        self.k = 0

    def _on(self, name: str) -> bool:
        return self.v in (name, 'all')

    def step(self, tick: TickInput) -> float:
        """One tick through the bus's units (the runner's controller interface)."""
        gap, enc, enabled = tick.gap_mm, tick.encoder_mm, tick.drive_enabled
        if self._on('gap_counts') and tick.gap_valid:
            gap, _ = self.analog.mm(self.analog.counts(gap))
        if self._on('position_increments'):
            enc = self.units.position_mm(self.units.position_increments(enc))
        if self._on('power_up') and self.k < 3:
            enabled = False  # samples 0..2: Switch on disabled -> ... -> Operation enabled
        self.k += 1
        u = self.ctrl.step(tick._replace(gap_mm=gap, encoder_mm=enc, drive_enabled=enabled))
        if self._on('velocity_units'):
            u = self.units.velocity_mm_s(self.units.velocity_command(u))
        if self._on('power_up') and self.k <= 3:
            u = 0.0  # not driven before Operation enabled
        return u

    def command(self, name: str, **kwargs) -> None:
        """Pass a follow command of the scenario to the controller."""
        self.ctrl.command(name, **kwargs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--scenarios', default='showcase,step')
    a = ap.parse_args()
    out: dict = {}
    worst = 0.0
    for name in a.scenarios.split(','):
        rows = {}
        for v in VARIANTS:
            rms = run(name, BusUnits(v)).metrics.error_rms_mm
            rows[v] = {'error_rms_mm': rms}
        base = rows['baseline']['error_rms_mm']
        for v in VARIANTS:
            rows[v]['relative'] = rows[v]['error_rms_mm'] / base - 1.0
        worst = max(worst, abs(rows['all']['relative']))
        out[name] = rows
        print(name, {v: round(r['relative'] * 100, 3) for v, r in rows.items()}, flush=True)
    print(json.dumps({'scenarios': out, 'max_relative_all': worst}))


if __name__ == '__main__':
    main()
