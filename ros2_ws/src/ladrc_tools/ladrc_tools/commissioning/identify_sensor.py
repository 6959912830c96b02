"""Identification of the capacitive sensor from a bag: gain, lag and noise.

**Sensor** (readings against the axis position over a flat sheet, ``flat_window_s``): the
reading is the gap through a first-order lag plus noise (``ladrc_sim/models/sensor.py``),
with the sheet flat the gap is the position minus a constant. The position is the axis
model plus the zero-phase low-passed encoder residual (:func:`position_estimate`: the
encoder's quantization would otherwise bias the lag, errors in variables):
``s[k] = α s[k−1] + (1 − α)(g y[k] + c)``, ``α = exp(−h/τs)``, reading = ``s`` + noise. For a
given α the model is linear in the gain ``g`` (d reading / d gap) and the offset ``c``; α by a
bounded search, then ``least_squares`` on ``(g, c, α)`` for the Jacobian; τs's interval maps
from α's. The noise is the residual's standard deviation (with the reading's quantization).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Mapping

import numpy as np
from scipy import optimize, signal

from .identify import (
    MIN_SAMPLES,
    MIN_TRAVEL_MM,
    AxisFit,
    Estimate,
    IdentifyError,
    covariance,
    sample_tick,
    sorted_unique,
)


def position_estimate(fit: AxisFit, cutoff_hz: float = 50.0) -> np.ndarray:
    """Return the nozzle position for the sensor fit: model + low-passed encoder residual.

    The encoder's quantization in the sensor fit's regressor would bias the lag (errors in
    variables); the axis model has none. What the model misses (friction, a resonance
    below ``cutoff_hz``) is added back from the encoder through a zero-phase (forward and
    backward) second-order Butterworth low-pass, so no lag enters.
    """
    fs = 1.0 / fit.h_s
    y = fit.series.position_mm
    if y.size < 30:
        return y.copy()
    sos = signal.butter(2, min(cutoff_hz, 0.2 * fs), fs=fs, output='sos')
    return fit.model_mm + signal.sosfiltfilt(sos, y - fit.model_mm)


# ---- the sensor ---------------------------------------------------------------------------
@dataclass
class SensorFit:
    """Capacitive sensor over a flat sheet: gain, lag, noise (estimates) and the series."""

    gain: Estimate
    offset_mm: Estimate
    lag_s: Estimate
    noise_mm: float
    n_samples: int
    window_s: tuple[float, float]
    t_s: np.ndarray
    reading_mm: np.ndarray
    model_mm: np.ndarray
    valid: np.ndarray
    notes: list[str] = field(default_factory=list)


def _lag_filter(x: np.ndarray, alpha: float) -> np.ndarray:
    """``s[k] = α s[k−1] + (1 − α) x[k]`` from rest at ``x[0]`` (models/sensor.py's lag)."""
    if alpha <= 0.0:
        return x.copy()
    out, _ = signal.lfilter([1.0 - alpha], [1.0, -alpha], x, zi=[alpha * x[0]])
    return out


def sensor_series(cap: Mapping[str, np.ndarray], feedback: Mapping[str, np.ndarray],
                  window_s: tuple[float, float] | None, t_ref_s: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Return ``(t, reading, encoder at t, valid, h)`` in the window (seconds after t_ref)."""
    t_r = np.asarray(cap.get('stamp_s', np.zeros(0)), dtype=float)
    r = np.asarray(cap.get('gap_mm', np.zeros(0)), dtype=float)
    valid = np.asarray(cap.get('valid', np.ones(t_r.size)), dtype=bool)
    t_f = np.asarray(feedback['stamp_s'], dtype=float)
    y = np.asarray(feedback['position_mm'], dtype=float)
    t_r, r, valid = sorted_unique(t_r, r, valid)
    t_f, y = sorted_unique(t_f, y)
    if window_s is not None:
        keep = (t_r >= t_ref_s + window_s[0]) & (t_r <= t_ref_s + window_s[1])
        t_r, r, valid = t_r[keep], r[keep], valid[keep]
    inside = (t_r >= t_f[0]) & (t_r <= t_f[-1])
    t_r, r, valid = t_r[inside], r[inside], valid[inside]
    if t_r.size < MIN_SAMPLES:
        where = f' in the window {window_s[0]:g}..{window_s[1]:g} s' if window_s else ''
        raise IdentifyError(f'too few capacitive readings{where}: {t_r.size} (at least '
                            f'{MIN_SAMPLES})')
    valid = valid & np.isfinite(r)
    h = sample_tick(t_r)
    return t_r, r, np.interp(t_r, t_f, y), valid, h


def fit_sensor(t_s: np.ndarray, reading_mm: np.ndarray, encoder_mm: np.ndarray,
               valid: np.ndarray, h_s: float, window_s: tuple[float, float]) -> SensorFit:
    """Fit gain, offset and lag of the reading against the encoder (module docstring)."""
    notes: list[str] = []
    if valid.sum() < MIN_SAMPLES:
        raise IdentifyError(f'too few valid capacitive readings over the flat sheet: '
                            f'{int(valid.sum())} (at least {MIN_SAMPLES})')
    if valid.mean() < 0.9:
        notes.append(f'{(1 - valid.mean()) * 100:.1f} % of the readings invalid (left out)')
    travel = float(np.ptp(encoder_mm))
    if travel < MIN_TRAVEL_MM:
        raise IdentifyError(f'the axis did not move over the flat sheet (encoder range '
                            f'{travel * 1e3:.1f} µm): the sensor gain is unidentifiable')
    rv = reading_mm[valid]

    def design(alpha: float) -> np.ndarray:
        return np.column_stack((_lag_filter(encoder_mm, alpha)[valid], np.ones(rv.size)))

    def cost(alpha: float) -> float:
        x = design(alpha)
        coef, *_ = np.linalg.lstsq(x, rv, rcond=None)
        e = x @ coef - rv
        return float(e @ e)

    # α = exp(−h/τs): a log grid of τs (0.05 tick .. 0.2 s) plus τs = 0, then Brent on α
    taus = np.concatenate(([0.0], np.geomspace(0.05 * h_s, 0.2, 40)))
    alphas = np.array([0.0 if t == 0.0 else math.exp(-h_s / t) for t in taus])
    costs = [cost(a) for a in alphas]
    i = int(np.argmin(costs))
    a_lo, a_hi = alphas[max(0, i - 1)], alphas[min(alphas.size - 1, i + 1)]
    alpha0 = float(alphas[i])
    if a_hi > a_lo:
        res = optimize.minimize_scalar(cost, bounds=(a_lo, a_hi), method='bounded',
                                       options={'xatol': 1e-7})
        if res.fun < costs[i]:
            alpha0 = float(res.x)
    x = design(alpha0)
    (g0, c0), *_ = np.linalg.lstsq(x, rv, rcond=None)

    def resid(p: np.ndarray) -> np.ndarray:
        return p[0] * _lag_filter(encoder_mm, p[2])[valid] + p[1] - rv

    a_top = math.exp(-h_s / 1.0)
    sol = optimize.least_squares(resid, [g0, c0, min(max(alpha0, 0.0), a_top)],
                                 bounds=([-np.inf, -np.inf, 0.0], [np.inf, np.inf, a_top]),
                                 x_scale=[max(abs(g0), 1e-3), 0.01, 0.01], xtol=1e-12,
                                 ftol=1e-12, gtol=1e-12)
    p, e = sol.x, sol.fun
    cov, _, _ = covariance(sol.jac, e)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))

    def tau_of(alpha: float) -> float:
        return 0.0 if alpha <= 0.0 else (math.inf if alpha >= 1.0 else -h_s / math.log(alpha))

    alpha = Estimate.of(p[2], sd[2], 0.0)
    lag = Estimate(tau_of(p[2]), math.nan, (tau_of(alpha.ci[0]), tau_of(min(alpha.ci[1],
                                                                                1.0))))
    # the std of τs by the delta method (dτ/dα = h / (α ln²α)); NaN at α = 0
    if 0.0 < p[2] < 1.0:
        lag = Estimate(lag.value, h_s / (p[2] * math.log(p[2]) ** 2) * sd[2], lag.ci)
    model = p[0] * _lag_filter(encoder_mm, p[2]) + p[1]
    noise = float(np.sqrt(e @ e / max(1, e.size - 3)))
    return SensorFit(gain=Estimate.of(p[0], sd[0]), offset_mm=Estimate.of(p[1], sd[1]),
                     lag_s=lag, noise_mm=noise, n_samples=int(valid.sum()),
                     window_s=window_s, t_s=t_s, reading_mm=reading_mm, model_mm=model,
                     valid=valid, notes=notes)
