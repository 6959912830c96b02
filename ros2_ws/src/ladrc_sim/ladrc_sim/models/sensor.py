"""Capacitive height sensor: true gap + edge coverage -> gap reading (mm), valid, collision.

Pipeline per tick (notes §5.2-5.3 effects):

1. **Edge** (边缘). ``coverage`` in 0..1 is the fraction of the nozzle over the sheet. The
   sensor is calibrated with the nozzle fully over the sheet; near an edge the capacitance is
   smaller, so the calibration table reads a larger gap. Model: the parallel-plate part of
   the capacitance scales with the covered area while the fringe field still reaches the
   sheet beyond the edge, more so at large gaps, giving an effective coverage
   ``c_eff = (g + c gf) / (g + gf)`` (``gf = edge_fringe_mm``) and an apparent gap

       r(g, c) = g / c_eff = g (g + gf) / (g + c gf)

   Its slope ``dr/dg = (g^2 + 2 c gf g + c gf^2) / (g + c gf)^2`` is exactly 1 at ``c = 1``
   and ``>= 1`` otherwise (**sign: half off the sheet the reading moves MORE than the gap**),
   growing as the gap closes (towards ``1/c`` at contact). So a follow step commanded in
   reading units moves the axis less: with ``c = 0.5`` and the default ``gf = 7 mm`` a 2->5 mm
   step moves the nozzle about 2.16 mm, as measured in notes §5.3 item 3; and the ratio
   d1/d0 of true to read travel when opening follow at the edge from 10 to 1 mm falls from
   ~1 towards ~0.7 as the gap closes. The notes' curve of that ratio is not smooth: the
   slope gets a piecewise-constant random ripple of relative size ``edge_ripple (1 - c)``
   on knots every ``edge_ripple_step_mm`` (drawn once from the seed), integrated so the map
   stays monotonic (``edge_ripple < 1``). At ``coverage < min_coverage`` there is no sheet
   under the nozzle (miss-panel): the reading saturates at the range top, ``valid = False``.
2. **Feedback gain** ``gain(t)``: the reading is multiplied by a gain schedule (events and
   the tube-ridge drop, notes §5.2 item 4) times ``1 + gain noise`` (notes' "反馈回路系数噪声",
   Gaussian, ``gain_noise_std``, optionally low-passed at ``gain_noise_cutoff_hz``).
3. **Lag**: first-order filter, time constant ``lag_s`` (exact discretisation).
4. **Noise**: white Gaussian ``noise_std_mm`` (after the filter: electronics/ADC noise).
5. **Quantization**: rounded to ``quant_mm`` steps.
6. **Range**: outside ``[range_min_mm, range_max_mm]`` the reading saturates and
   ``valid = False``.

``collision`` is reported when the true gap is ``<= 0`` (nozzle touches the sheet).

Raw value: an LC oscillator whose capacitance is a parasitic ``C_p`` plus the nozzle-sheet
capacitance ``C_s = eps0 A / r`` (``A`` = nozzle face area, ``r`` = apparent gap), so
``f = osc_f0_hz / sqrt(1 + C_s / C_p)``: the frequency falls as the capacitance rises
(as the nozzle approaches). :func:`oscillator_hz` maps readings to it.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, NamedTuple

from ladrc_contract.ops import SCALAR
from ladrc_contract.schema import param
import numpy as np
from scipy import signal

from .axis import H_S, ParamError, check_fields

EPS0_PF_PER_MM = 8.8541878128e-3  # vacuum permittivity in pF/mm


@dataclass(frozen=True)
class SensorParams:
    """Capacitive sensor parameters (defaults: an ideal sensor over a 0..20 mm range)."""

    range_min_mm: float = param(0.0)
    range_max_mm: float = param(20.0, gt=0.0)
    noise_std_mm: float = param(0.0, ge=0.0)
    quant_mm: float = param(0.0, '', '0 = no quantization', ge=0.0)
    lag_s: float = param(0.0, '', 'first-order filter time constant, 0 = none', ge=0.0)
    gain: float = param(1.0, '', 'feedback gain, 1 = calibrated', gt=0.0)
    gain_noise_std: float = param(0.0, ge=0.0, lt=0.5)
    gain_noise_cutoff_hz: float = param(0.0, '', '0 = white per tick', ge=0.0, lt=1000.0)
    edge_fringe_mm: float = param(7.0, gt=0.0)
    edge_ripple: float = param(0.1, '', '< 1 keeps the reading monotonic', ge=0.0, lt=1.0)
    edge_ripple_step_mm: float = param(0.5, gt=0.0)
    min_coverage: float = param(0.05, ge=0.0, le=1.0)
    osc_f0_hz: float = param(500e3, gt=0.0)
    parasitic_pf: float = param(10.0, gt=0.0)
    nozzle_diameter_mm: float = param(8.0, gt=0.0)

    def __post_init__(self) -> None:
        check_fields(self)
        if self.range_max_mm <= self.range_min_mm:
            raise ParamError('range_max_mm', f'{self.range_max_mm} must exceed range_min_mm '
                                             f'({self.range_min_mm})')


def edge_reading_mm(gap_mm, coverage, fringe_mm: float = 7.0):
    """Apparent gap of the smooth edge model ``r = g (g + gf) / (g + c gf)`` (no ripple).

    Works on floats or numpy arrays; ``gap_mm >= 0`` and ``0 < coverage <= 1``.
    """
    return gap_mm * (gap_mm + fringe_mm) / (gap_mm + coverage * fringe_mm)


def oscillator_hz(reading_mm, params: SensorParams):
    """Raw oscillator frequency (Hz) for an apparent gap (module docstring formula)."""
    area = math.pi * 0.25 * params.nozzle_diameter_mm ** 2
    r = np.maximum(np.asarray(reading_mm, dtype=float), 1e-3)
    c_s = EPS0_PF_PER_MM * area / r
    return params.osc_f0_hz / np.sqrt(1.0 + c_s / params.parasitic_pf)


def oscillator_hz_scalar(reading_mm: float, params: SensorParams) -> float:
    """:func:`oscillator_hz` of one reading, in plain floats (the sim node's 2 kHz path).

    The same operations in the same order, so the value equals the array form bit for bit
    (a lock-step run's samples equal the headless bag's); NaN for a reading that is not finite.
    """
    if not math.isfinite(reading_mm):
        return math.nan
    area = math.pi * 0.25 * params.nozzle_diameter_mm ** 2
    c_s = EPS0_PF_PER_MM * area / max(reading_mm, 1e-3)
    return params.osc_f0_hz / math.sqrt(1.0 + c_s / params.parasitic_pf)


def band_limited_noise(rng: np.random.Generator, n: int, std: float, cutoff_hz: float,
                       h_s: float) -> np.ndarray:
    """Gaussian noise of standard deviation ``std``, low-passed at ``cutoff_hz`` if > 0."""
    white = rng.standard_normal(n)
    if std == 0.0:
        return np.zeros(n)
    if cutoff_hz > 0.0 and n > 30:
        sos = signal.butter(2, cutoff_hz, fs=1.0 / h_s, output='sos')
        white = signal.sosfiltfilt(sos, white)
        s = float(white.std())
        white = white / s if s > 0.0 else white
    return std * white


class EdgeModel(NamedTuple):
    """The edge model's constants (module docstring): fringe and the ripple's knots."""

    fringe_mm: float
    step_mm: float       # knot spacing of the ripple
    inv_step: float      # 1 / step_mm
    k_last: int          # the last knot
    cum: Any             # the ripple integrated at the knots (a list, or an array for rows)
    eps: Any             # the ripple's slope error per knot


def edge_gap_mm(ops: Any, gap_mm: Any, coverage: float, e: EdgeModel) -> Any:
    """Edge-model reading (before gain, lag, noise) at ``coverage`` < 1, scalar or rows."""
    g = ops.where(gap_mm > 0.0, gap_mm, 0.0)
    k = ops.floor_index(g * e.inv_step, e.k_last)
    return (g * (g + e.fringe_mm) / (g + coverage * e.fringe_mm) + (1.0 - coverage)
            * (e.cum[k] + e.eps[k] * (g - k * e.step_mm)))


class Sensor:
    """Capacitive sensor over a run of ``n_ticks``; ``measure(i, gap, coverage)`` per tick.

    ``gain_schedule`` (length ``n_ticks``) multiplies the parameter ``gain``; the noise of the
    whole run is drawn up front from ``rng`` so the per-tick path only indexes lists.
    """

    def __init__(self, params: SensorParams, n_ticks: int, h_s: float = H_S,
                 rng: np.random.Generator | None = None,
                 gain_schedule: np.ndarray | None = None):
        rng = np.random.default_rng(0) if rng is None else rng
        self.params = params
        self.h_s = float(h_s)
        gain = np.full(n_ticks, params.gain)
        if gain_schedule is not None:
            gain = gain * np.asarray(gain_schedule, dtype=float)
        gain = gain * (1.0 + band_limited_noise(rng, n_ticks, params.gain_noise_std,
                                                params.gain_noise_cutoff_hz, h_s))
        self.gain = gain
        self._gain = gain.tolist()
        self._noise = (params.noise_std_mm * rng.standard_normal(n_ticks)).tolist()
        # edge ripple: piecewise-constant slope error on knots, integrated (module doc).
        n_knots = int(math.ceil(4.0 * params.range_max_mm / params.edge_ripple_step_mm)) + 2
        eps = params.edge_ripple * rng.uniform(-1.0, 1.0, n_knots)
        cum = np.concatenate(([0.0], np.cumsum(eps) * params.edge_ripple_step_mm))
        self._eps = eps.tolist()
        self._cum = cum.tolist()
        self.noise_mm = np.asarray(self._noise)  # the noise of every tick (batch rows)
        self._alpha = math.exp(-h_s / params.lag_s) if params.lag_s > 0.0 else 0.0
        self._y: float | None = None
        self._gf = params.edge_fringe_mm
        self._step = params.edge_ripple_step_mm
        self._inv_step = 1.0 / params.edge_ripple_step_mm
        self._k_last = len(self._eps) - 1
        self.edge = EdgeModel(self._gf, self._step, self._inv_step, self._k_last, self._cum,
                              self._eps)
        self.alpha = self._alpha  # the lag's filter coefficient per tick (0: no lag)
        self._min_cov = params.min_coverage
        self._rmax = params.range_max_mm
        self._rmin = params.range_min_mm
        self._q = params.quant_mm

    def apparent_gap_mm(self, gap_mm: float, coverage: float) -> float:
        """Edge-model reading (before gain, lag, noise) for a true gap and coverage."""
        if coverage >= 1.0:
            return gap_mm
        return edge_gap_mm(SCALAR, gap_mm, coverage, self.edge)

    def measure(self, i: int, gap_mm: float, coverage: float) -> tuple[float, bool, bool]:
        """Return ``(reading_mm, valid, collision)`` at tick ``i`` for the true gap."""
        collision = gap_mm <= 0.0
        if coverage >= 1.0:
            r = gap_mm * self._gain[i]
        elif coverage < self._min_cov:
            self._y = None
            return self._rmax, False, collision
        else:
            r = edge_gap_mm(SCALAR, gap_mm, coverage, self.edge) * self._gain[i]
        alpha = self._alpha
        if alpha != 0.0:
            y = self._y
            r = r if y is None else alpha * y + (1.0 - alpha) * r
            self._y = r
        r += self._noise[i]
        q = self._q
        if q > 0.0:
            r = round(r / q) * q
        if r > self._rmax:
            return self._rmax, False, collision
        if r < self._rmin:
            return self._rmin, False, collision
        return r, True, collision
