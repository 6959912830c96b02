"""Stability gate: a parameter set whose linear loop falls below the minima does not go live.

Where a parameter set is loaded to run (``params_from_dict``: the follow node at start-up and in
its parameter callback, ``ladrc simulate --params``, ``ladrc params --check``, the suite), the
loops it will run are analysed (:mod:`.loop`) against the axis model declared here: the PID
(the approach and the PID state run it always) and, with ``follow.controller: ladrc``, the
LADRC. Unstable, or a phase, gain or delay margin below its minimum, or a sensitivity peak Ms
above its maximum: rejected with the numbers, and the running values stay. Replay does not
gate: it reproduces the sets a bag recorded.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any

from .schema import Section, param

GATE_FREQUENCIES = 1000
"""Frequencies of the gate's grid: margins within 0.01 of the 4000-point analysis, 2 ms each."""


@dataclass(frozen=True)
class StabilityParams(Section):
    """The stability gate and the axis model it checks against (``ControllerParams.stability``)."""

    PREFIX = 'stability.'

    gate: bool = param(True, '', 'reject a parameter set whose linear loop against the axis '
                       'model below falls short of the minima (docs/loop-analysis.md)')
    min_phase_margin_deg: float = param(30.0, 'deg', 'least phase margin', ge=0.0, le=90.0)
    min_gain_margin_db: float = param(6.0, 'dB', 'least gain margin', ge=0.0, le=40.0)
    min_delay_margin_ms: float = param(2.0, 'ms', 'least delay margin: extra dead time the '
                                       'loop tolerates', ge=0.0, le=1000.0)
    max_sensitivity_peak: float = param(2.5, '1', 'largest sensitivity peak Ms = max |S|',
                                        gt=1.0, le=100.0)
    axis_b0: float = param(1.0, 'mm/s per mm/s', 'axis model: velocity gain of the drive',
                           gt=0.0, le=1e5)
    axis_t1_ms: float = param(8.0, 'ms', 'axis model: velocity-loop time constant',
                              gt=0.0, le=1e4)
    axis_dead_time_ticks: int = param(0, 'ticks', 'axis model: whole ticks of command delay',
                                      ge=0, le=1000)
    axis_lag_ms: float = param(0.0, 'ms', 'axis model: sensor first-order lag', ge=0.0,
                               le=1e4)


def stability_reasons(p: Any) -> list[str]:
    """Return why ``p`` (a valid ControllerParams) fails the gate; empty when it passes."""
    from .loop import AxisModel, analyse_params, frequency_grid

    s: StabilityParams = p.stability
    if not s.gate:
        return []
    axis = AxisModel(s.axis_b0, s.axis_t1_ms * 1e-3, s.axis_dead_time_ticks,
                     s.axis_lag_ms * 1e-3)
    grid = frequency_grid(p.h_s, GATE_FREQUENCIES)
    modes = ['pid'] + (['ladrc'] if p.follow.controller == 'ladrc' else [])
    where = (f'against the axis model (b0 {s.axis_b0:g}, T1 {s.axis_t1_ms:g} ms, dead time '
             f'{s.axis_dead_time_ticks} ticks, lag {s.axis_lag_ms:g} ms)')
    out = []
    for mode in modes:
        an = analyse_params(p, axis, mode, grid)
        if not an.stable:
            out.append(f'stability gate: the {mode} loop is unstable {where}: closed-loop '
                       f'spectral radius {an.spectral_radius:.4f} >= 1')
            continue
        checks = (
            (an.phase_margin_deg, s.min_phase_margin_deg, 'phase margin', '°',
             'stability.min_phase_margin_deg', False),
            (an.gain_margin_db, s.min_gain_margin_db, 'gain margin', ' dB',
             'stability.min_gain_margin_db', False),
            (an.delay_margin_ms, s.min_delay_margin_ms, 'delay margin', ' ms',
             'stability.min_delay_margin_ms', False),
            (an.ms_peak, s.max_sensitivity_peak, 'sensitivity peak Ms', '',
             'stability.max_sensitivity_peak', True))
        for value, bound, name, unit, key, is_max in checks:
            if math.isnan(value):
                continue  # no crossing of that kind: no such margin to fall short of
            if (value > bound) if is_max else (value < bound):
                rel = '>' if is_max else '<'
                out.append(f'stability gate: the {mode} loop has a {name} of {value:.3g}{unit} '
                           f'{rel} {bound:g}{unit} ({key}) {where}')
    return out
