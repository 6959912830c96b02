"""The identified plant of notes §1.2 in the linear loop and at the ends of its intervals.

Notes §1.2 (a MATLAB ``present`` print-out of a 2-pole, 1-zero ``tfest`` model; the ± are one
standard deviation)::

            16.75 (+/- 0.2556) s - 0.2331 (+/- 1.816)
    G(s) = --------------------------------------------------
           s^2 + 0.3274 (+/- 0.1804) s + 0.06028 (+/- 0.3627)

The simulator runs it as ``axis.model: identified`` (``ladrc_sim.models.axis``): the command,
clipped to ±v_max, times ``identified_gain``, drives G; the position is G's output. Here the same
plant, ZOH-discretized at the tick exactly as the simulator does, is written in the layout of
``ladrc_follow.analysis.loop.axis_ss`` (inputs command and sheet; outputs reading, encoder,
nozzle) so that ``loop.analyse`` — the machinery of ``ladrc analyze`` — closes the shipped
controller around it. Pure module (numpy, scipy; no rclpy). docs/identification.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ladrc_follow import StateSpace, analyse, controller_ss
import numpy as np
from scipy import signal

# notes §1.2: value, ± one standard deviation, and the AxisParams field that holds it
INTERVALS: dict[str, tuple[float, float]] = {
    'identified_n1': (16.75, 0.2556),
    'identified_n0': (-0.2331, 1.816),
    'identified_d1': (0.3274, 0.1804),
    'identified_d0': (0.06028, 0.3627),
}
GAIN_B0_1 = 1.0 / 16.75
"""``identified_gain`` that makes the high-frequency gain 16.75/s equal b0 = 1 (sim default)."""
GAIN_PROJECT_UNITS = 0.01
"""``identified_gain`` if G maps UnitV → UnitP with the project's mapping (UnitP = 1 µm,
UnitV = 0.1 mm/s, docs/control-law.md): 0.001 mm / 0.1 mm/s; b = 0.1675."""


@dataclass(frozen=True)
class Coeffs:
    """(n1 s + n0) / (s² + d1 s + d0), the §1.2 model's four coefficients."""

    n1: float = INTERVALS['identified_n1'][0]
    n0: float = INTERVALS['identified_n0'][0]
    d1: float = INTERVALS['identified_d1'][0]
    d0: float = INTERVALS['identified_d0'][0]

    def axis_kwargs(self) -> dict[str, float]:
        """Return the ``AxisParams`` fields for these coefficients."""
        return {'identified_n1': self.n1, 'identified_n0': self.n0,
                'identified_d1': self.d1, 'identified_d0': self.d0}

    def zero_rad_s(self) -> float:
        """Return the model's zero, −n0/n1 (positive: right half plane)."""
        return -self.n0 / self.n1

    def poles_rad_s(self) -> np.ndarray:
        """Return the model's poles."""
        return np.roots([1.0, self.d1, self.d0])


def interval_cases() -> list[tuple[str, Coeffs]]:
    """Nominal, each coefficient at each end of its ±1σ interval, and the two corners."""
    cases = [('nominal', Coeffs())]
    short = {'identified_n1': 'n1', 'identified_n0': 'n0', 'identified_d1': 'd1',
             'identified_d0': 'd0'}
    for key, (v, sd) in INTERVALS.items():
        for sign, tag in ((-1.0, '-'), (1.0, '+')):
            cases.append((f'{short[key]}{tag}', Coeffs(**{short[key]: v + sign * sd})))
    for sign, tag in ((-1.0, 'all-'), (1.0, 'all+')):
        cases.append((tag, Coeffs(*(v + sign * sd for v, sd in INTERVALS.values()))))
    return cases


def identified_axis_ss(coeffs: Coeffs, gain: float, h_s: float) -> StateSpace:
    """Return the §1.2 plant times ``gain`` as a ``loop.axis_ss``-layout system (no lag).

    tf2ss + ZOH cont2discrete as ``ladrc_sim.models.axis``; the reading is position − sheet,
    taken at the tick before the command acts (the runner's order), so D's command column is 0.
    """
    a, b, c, d = signal.tf2ss((coeffs.n1, coeffs.n0), (1.0, coeffs.d1, coeffs.d0))
    ad, bd, cd, dd, _ = signal.cont2discrete((a, b, c, d), h_s, method='zoh')
    n = ad.shape[0]
    bb = np.zeros((n, 2))
    bb[:, 0] = np.ravel(bd) * gain
    cc = np.vstack([np.ravel(cd)] * 3)
    dd3 = np.zeros((3, 2))
    dd3[0, 1] = -1.0
    return StateSpace(np.asarray(ad), bb, cc, dd3, h_s)


def closed_loop_poles(params: Any, plant: StateSpace, mode: str) -> np.ndarray:
    """Poles (z) of the controller's feedback part closed around ``plant`` (as ``analyse``)."""
    fb = controller_ss(params, mode).inputs((0, 1))
    full = plant.with_delay_states()
    cpy, bpu = full.c[:2], full.b[:, 0:1]
    a_cl = np.block([[full.a + bpu @ fb.d @ cpy, bpu @ fb.c], [fb.b @ cpy, fb.a]])
    return np.linalg.eigvals(a_cl)


def loop_figures(params: Any, coeffs: Coeffs, gain: float, mode: str = 'ladrc'
                 ) -> dict[str, Any]:
    """``loop.analyse`` figures of the controller on the §1.2 plant, plus its slowest pole.

    ``slow_pole_rad_s``: the closed-loop pole of largest |z| mapped to s = ln(z)/h; with
    integral action in the loop it sits at the plant's zero (−n0/n1).
    """
    plant = identified_axis_ss(coeffs, gain, params.h_s)
    out = dict(analyse(controller_ss(params, mode), plant).figures())
    z = closed_loop_poles(params, plant, mode)
    k = int(np.argmax(np.abs(z)))
    out['slow_pole_rad_s'] = float((np.log(z[k] + 0j) / params.h_s).real)
    return out


__all__ = ['Coeffs', 'GAIN_B0_1', 'GAIN_PROJECT_UNITS', 'INTERVALS', 'closed_loop_poles',
           'identified_axis_ss', 'interval_cases', 'loop_figures']
