"""The stability gate's parameters (``stability.*``): its minima and the axis model it assumes.

The gate itself (``ladrc_follow.analysis.gate``) runs where a set is loaded to run: the follow
node at start-up and on a change, ``ladrc simulate --params``, ``ladrc params --check``, tune
and identify's suggested set. It analyses the loops the set will run against the axis model
declared here.
"""

from __future__ import annotations

from dataclasses import dataclass

from ladrc_contract.schema import Section, param


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
