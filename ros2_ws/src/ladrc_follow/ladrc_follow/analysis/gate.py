"""The stability gate: a parameter set whose linear loop falls below the minima does not run.

The loops a set will run (the PID always: the approach and the PID state run it; with
``follow.controller: ladrc`` also the LADRC) are analysed (:mod:`.loop`) against the axis model
of ``stability.*`` (``ladrc_follow.control.stability``). Unstable, or a phase, gain or delay
margin below its minimum, or a sensitivity peak Ms above its maximum: rejected with the
numbers. Who gates: the follow node at start-up and on a change (in a worker process,
``node/gate_process.py``), ``ladrc simulate --params``, ``ladrc params --check``, tune and
identify's suggested set. Replay and the suite's study variants do not: they reproduce sets as
they ran.
"""

from __future__ import annotations

import math
from typing import Any

from ..control.params import ControllerParams, ParameterError
from ..control.stability import StabilityParams
from .loop import AxisModel, analyse_params, frequency_grid

GATE_FREQUENCIES = 1000
"""Frequencies of the gate's grid: margins within 0.01 of the 4000-point analysis, 2 ms each."""


def stability_reasons(p: Any) -> list[str]:
    """Return why ``p`` (a valid ControllerParams) fails the gate; empty when it passes."""
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


def check_gate(p: ControllerParams) -> ControllerParams:
    """Return ``p``; raise :class:`ParameterError` with the numbers if it fails the gate.

    No-op when ``stability.gate`` is off. A set the analysis cannot take fails too.
    """
    try:
        reasons = stability_reasons(p)
    except Exception as exc:  # noqa: BLE001 - a set the analysis cannot take
        reasons = [f'stability gate: the loop could not be analysed: '
                   f'{type(exc).__name__}: {exc}']
    if reasons:
        raise ParameterError(reasons)
    return p
