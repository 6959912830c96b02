"""Identification of the Z axis and the capacitive sensor from a bag (issue 15, item 2).

**Axis** (notes §1.1): ``G(s) = b0 e^(−sτ) / (s (T1 s + 1))`` from the velocity command to the
encoder position. Data: ``axis/velocity_command`` (``velocity_mm_s``, ``enable``: a disabled
command is a zero command) and ``axis/feedback`` (``position_mm``; the longest stretch with the
drive enabled and not faulted). The feedback stamps give the grid (tick ``h`` from their
spacing, robust to lost samples: :func:`_tick`; positions interpolated onto ``t0 + j h``
when the stamps jitter or samples are lost); the command of grid
sample ``j`` is the last one stamped up to half a tick after it, i.e. the command computed from
that sample. So ``τ`` is the delay of the whole loop as the controller sees it, as the
stability gate's axis model (``stability.axis_dead_time_ticks``) and the headless runner's
tick order count it (a headless bag's ``dead_time_ticks`` comes out as ``τ/h`` exactly).

The model is the sim's (``ladrc_sim/models/axis.py``): the exact ZOH discretisation with
``a = exp(−h/T1)``; a dead time ``τ = (d + f) h`` (``d`` whole ticks, ``0 <= f < 1``) is exact
too: during tick ``k`` the axis sees ``u[k−d−1]`` for ``f h`` and ``u[k−d]`` for the rest, two
exact sub-steps (the modified z-transform). So τ is fitted as a continuous value, in two stages:

1. **tick grid**: for each whole ``d`` in ``0 .. max_dead_time`` the output is linear in
   ``b0``, the start position ``x0``, the start velocity ``v0`` and a velocity offset ``c``
   (a drive's offset, a ramp ``c t``): variable projection, a linear least-squares solve for
   those inside a bounded scalar search over ``log T1``. The ``d`` with the least residual wins;
2. **refinement**: ``scipy.optimize.least_squares`` on all six (``b0, T1, τ, x0, v0, c``), the
   simulated position against the measured one (output error), τ within a tick of ``d h``.

Confidence intervals (95 %): b0 from ``cov = s² (JᵀJ)⁻¹`` with ``J`` the Jacobian at the
solution and ``s² = RSS/(N − p)``, inflated by ``(1 + ρ)/(1 − ρ)`` when the residuals' lag-1
autocorrelation ``ρ`` is positive (an effective sample size: conservative for coloured
residuals), ``±1.96 σ``. T1 and τ from the profile likelihood, ``{θ: min RSS given θ <=
RSS_min + 1.96² s²}`` (:func:`_profile_interval`): the model is kinked in τ at whole ticks,
where the Jacobian's straight line misleads; τ's lower end is 0 at most. The data are
refused as unidentifiable
(:class:`IdentifyError`) when nothing was commanded, the axis did not move, or the 95 %
half-width of b0 exceeds 10 % or that of T1 50 %.

**Sensor** (readings against the axis position over a flat sheet, ``flat_window_s``): the
reading is the gap through a first-order lag plus noise (``ladrc_sim/models/sensor.py``),
with the sheet flat the gap is the position minus a constant. The position is the axis
model plus the zero-phase low-passed encoder residual (:func:`position_estimate`: the
encoder's quantization would otherwise bias the lag, errors in variables):
``s[k] = α s[k−1] + (1 − α)(g y[k] + c)``, ``α = exp(−h/τs)``, reading = ``s`` + noise. For a
given α the model is linear in the gain ``g`` (d reading / d gap) and the offset ``c``; α by a
bounded search, then ``least_squares`` on ``(g, c, α)`` for the Jacobian; τs's interval maps
from α's. The noise is the residual's standard deviation (with the reading's quantization).

:func:`suggest` turns an axis fit into controller parameters checked by the stability gate.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any, Mapping

import numpy as np
from scipy import optimize, signal

Z95 = 1.959963984540054
"""Two-sided 95 % quantile of the normal distribution."""

MIN_SAMPLES = 400
MIN_TRAVEL_MM = 0.01
"""Least encoder range that counts as motion (ten 1 µm counts)."""
MAX_B0_REL_HALFWIDTH = 0.10
MAX_T1_REL_HALFWIDTH = 0.50
T1_RANGE_S = (1e-5, 2.0)


class IdentifyError(ValueError):
    """The data cannot be identified; the message is one line saying why."""


@dataclass(frozen=True)
class Estimate:
    """A fitted value, its standard deviation and 95 % interval ``ci = (lo, hi)``."""

    value: float
    std: float
    ci: tuple[float, float]

    @classmethod
    def of(cls, value: float, std: float, lo_bound: float = -math.inf) -> Estimate:
        """Return the estimate with a ``±1.96 σ`` interval clipped below at ``lo_bound``."""
        lo, hi = value - Z95 * std, value + Z95 * std
        return cls(float(value), float(std), (float(max(lo, lo_bound)), float(hi)))

    def rel_halfwidth(self) -> float:
        """Return half the interval's width over the value's magnitude (inf at 0)."""
        v = abs(self.value)
        return 0.5 * (self.ci[1] - self.ci[0]) / v if v > 0.0 else math.inf

    def as_list(self) -> list[float]:
        """Return the interval as ``[lo, hi]``."""
        return [self.ci[0], self.ci[1]]


# ---- data ------------------------------------------------------------------------------------
@dataclass
class AxisSeries:
    """Command and encoder on a uniform grid (``t_s[j] = t0 + j h``).

    ``command_pre_mm_s``: the ``pre`` commands before ``t_s[0]`` on the same grid (for a dead
    time reaching before the window).
    """

    t_s: np.ndarray
    command_mm_s: np.ndarray
    position_mm: np.ndarray
    h_s: float
    command_pre_mm_s: np.ndarray
    notes: list[str] = field(default_factory=list)


def _sorted_unique(t: np.ndarray, *cols: np.ndarray) -> tuple[np.ndarray, ...]:
    order = np.argsort(t, kind='stable')
    t = t[order]
    keep = np.concatenate(([True], np.diff(t) > 0.0)) if t.size else np.zeros(0, bool)
    return (t[keep],) + tuple(c[order][keep] for c in cols)


def _tick(t: np.ndarray) -> float:
    """Return the sampling period of stamps ``t``, robust to lost samples and jitter.

    The median of the spacings near the median spacing (a lost sample makes a double one)
    numbers the samples (each spacing a whole number of periods), then the slope of the
    stamps against those numbers (least squares); rounded to 1 ns.
    """
    d = np.diff(t)
    h0 = float(np.median(d)) if d.size else 0.0
    if not h0 > 0.0:
        return 0.0
    near = d[(d > 0.5 * h0) & (d < 1.5 * h0)]
    h1 = float(np.median(near)) if near.size else h0
    k = np.concatenate(([0.0], np.cumsum(np.maximum(1.0, np.round(d / h1)))))
    if k[-1] < 2:
        return round(h1, 9)
    return round(float(np.polyfit(k, t - t[0], 1)[0]), 9)


def _longest_run(ok: np.ndarray) -> tuple[int, int]:
    """Return ``[i0, i1)`` of the longest run of True in ``ok`` (``(0, 0)`` if none)."""
    if not ok.any():
        return 0, 0
    d = np.diff(np.concatenate(([0], ok.astype(np.int8), [0])))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    i = int(np.argmax(ends - starts))
    return int(starts[i]), int(ends[i])


def axis_series(command: Mapping[str, np.ndarray], feedback: Mapping[str, np.ndarray],
                max_dead_ticks: int = 40) -> AxisSeries:
    """Join ``axis/velocity_command`` and ``axis/feedback`` columns on time (module doc)."""
    notes: list[str] = []
    t_f = np.asarray(feedback.get('stamp_s', np.zeros(0)), dtype=float)
    y = np.asarray(feedback.get('position_mm', np.zeros(0)), dtype=float)
    en = np.asarray(feedback.get('drive_enabled', np.ones(t_f.size)), dtype=bool)
    fault = np.asarray(feedback.get('drive_fault', np.zeros(t_f.size)), dtype=bool)
    t_c = np.asarray(command.get('stamp_s', np.zeros(0)), dtype=float)
    v_c = np.asarray(command.get('velocity_mm_s', np.zeros(0)), dtype=float)
    e_c = np.asarray(command.get('enable', np.ones(t_c.size)), dtype=bool)
    if t_f.size < MIN_SAMPLES:
        raise IdentifyError(f'too little feedback: {t_f.size} axis/feedback samples '
                            f'(at least {MIN_SAMPLES})')
    if t_c.size == 0:
        raise IdentifyError('no axis/velocity_command messages')
    t_f, y, en, fault = _sorted_unique(t_f, y, en, fault)
    t_c, v_c, e_c = _sorted_unique(t_c, v_c, e_c)
    h = _tick(t_f)
    if not h > 0.0:
        raise IdentifyError('axis/feedback stamps do not advance')
    ok = en & ~fault & np.isfinite(y) & (t_f >= t_c[0])
    i0, i1 = _longest_run(ok)
    if i0 or i1 < t_f.size:
        notes.append(f'fit window: feedback samples {i0}..{i1 - 1} of {t_f.size} (the longest '
                     'stretch with the drive enabled, no fault and commands)')
    if i1 - i0 < MIN_SAMPLES:
        raise IdentifyError(f'too little usable feedback: {i1 - i0} samples with the drive '
                            f'enabled and not faulted (at least {MIN_SAMPLES})')
    t_f, y = t_f[i0:i1], y[i0:i1]
    m = int(math.floor((t_f[-1] - t_f[0]) / h + 1e-6)) + 1
    t_g = t_f[0] + h * np.arange(m)
    dev = float(np.max(np.abs(np.diff(t_f) - h))) if t_f.size > 1 else 0.0
    if dev > 0.05 * h:
        notes.append(f'feedback spacing off the {h * 1e3:.4g} ms tick by up to '
                     f'{dev * 1e6:.0f} µs (jitter or lost samples): positions interpolated '
                     'onto a uniform grid')
    y_g = np.interp(t_g, t_f, y)
    u_eff = np.where(e_c & np.isfinite(v_c), v_c, 0.0)
    n_pre = int(max_dead_ticks) + 2
    t_all = t_f[0] + h * np.arange(-n_pre, m)
    idx = np.searchsorted(t_c, t_all + 0.5 * h, side='right') - 1
    u_all = np.where(idx >= 0, u_eff[np.maximum(idx, 0)], 0.0)
    return AxisSeries(t_s=t_g, command_mm_s=u_all[n_pre:], position_mm=y_g, h_s=h,
                      command_pre_mm_s=u_all[:n_pre], notes=notes)


# ---- the axis model ---------------------------------------------------------------------------
def axis_response(u_ext: np.ndarray, n_pre: int, h_s: float, t1_s: float,
                  tau_s: float) -> np.ndarray:
    """Return the position of ``1/(s (T1 s + 1)) e^(−sτ)`` (b0 = 1, at rest at 0) on the grid.

    ``u_ext``: ``n_pre`` commands before the window, then one per grid sample (ZOH). Exact
    discretisation (module docstring): ``x[0] = 0``, ``x[k+1]`` after tick ``k``.
    """
    m = u_ext.size - n_pre
    q = max(0.0, tau_s / h_s)
    d = min(int(math.floor(q)), n_pre - 1)
    f = min(1.0, q - d)
    ub = u_ext[n_pre - d:n_pre - d + m]
    ua = u_ext[n_pre - d - 1:n_pre - d - 1 + m]
    e1 = -math.expm1(-f * h_s / t1_s)          # 1 − a1
    e2 = -math.expm1(-(1.0 - f) * h_s / t1_s)  # 1 − a2
    a1, a2 = 1.0 - e1, 1.0 - e2
    a = a1 * a2
    w = a2 * e1 * ua + e2 * ub
    v_next = signal.lfilter([1.0], [1.0, -a], w)
    v = np.concatenate(([0.0], v_next[:-1]))
    v_mid = a1 * v + e1 * ua
    dx = (t1_s * e1 * v + (f * h_s - t1_s * e1) * ua
          + t1_s * e2 * v_mid + ((1.0 - f) * h_s - t1_s * e2) * ub)
    return np.concatenate(([0.0], np.cumsum(dx)[:-1]))


def _regressors(s: AxisSeries, t1_s: float, tau_s: float) -> np.ndarray:
    """Columns ``[response, 1, t, start-velocity response]`` (b0, x0, c, v0 are linear)."""
    u_ext = np.concatenate((s.command_pre_mm_s, s.command_mm_s))
    m = s.command_mm_s.size
    k = np.arange(m)
    resp = axis_response(u_ext, s.command_pre_mm_s.size, s.h_s, t1_s, tau_s)
    a = math.exp(-s.h_s / t1_s)
    v0_resp = t1_s * -np.expm1(k * math.log(a)) if a > 0.0 else np.full(m, t1_s)
    return np.column_stack((resp, np.ones(m), k * s.h_s, v0_resp))


def _projected(s: AxisSeries, t1_s: float, tau_s: float) -> tuple[float, np.ndarray]:
    """Return ``(RSS, [b0, x0, c, v0])`` of the linear least-squares fit at ``(T1, τ)``."""
    x = _regressors(s, t1_s, tau_s)
    y = s.position_mm
    # normal equations on unit-norm columns (4 x 4): far faster than an SVD of N x 4
    norm = np.sqrt(np.einsum('ij,ij->j', x, x))
    norm[norm == 0.0] = 1.0
    xn = x / norm
    try:
        coef = np.linalg.solve(xn.T @ xn, xn.T @ y) / norm
    except np.linalg.LinAlgError:
        coef = np.linalg.lstsq(x, y, rcond=None)[0]
    r = x @ coef - y
    return float(r @ r), coef


def simulate_axis(s: AxisSeries, b0: float, t1_s: float, tau_s: float, x0_mm: float = 0.0,
                  v0_mm_s: float = 0.0, offset_mm_s: float = 0.0) -> np.ndarray:
    """Return the model's position on the series' grid for these parameters."""
    return _regressors(s, t1_s, tau_s) @ np.array([b0, x0_mm, offset_mm_s, v0_mm_s])


def _covariance(jac: np.ndarray, resid: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Return ``(cov, s², ρ)``: ``s² (JᵀJ)⁻¹``, ``s²`` inflated for coloured residuals."""
    n, p = jac.shape
    s2 = float(resid @ resid) / max(1, n - p)
    r = resid - resid.mean()
    den = float(r @ r)
    rho = float(r[1:] @ r[:-1]) / den if den > 0.0 else 0.0
    infl = (1.0 + rho) / (1.0 - rho) if 0.0 < rho < 0.999 else (1000.0 if rho >= 0.999 else 1.0)
    jtj = jac.T @ jac
    scale = np.sqrt(np.maximum(np.diag(jtj), 1e-300))
    cov = np.linalg.pinv(jtj / np.outer(scale, scale), rcond=1e-12) / np.outer(scale, scale)
    return cov * s2 * infl, s2 * infl, rho


def _min_scalar(fun: Any, lo: float, hi: float, xatol: float) -> float:
    """Return the least value of ``fun`` on ``[lo, hi]`` (bounded Brent, the ends included)."""
    if not hi > lo:
        return float(fun(lo))
    r = optimize.minimize_scalar(fun, bounds=(lo, hi), method='bounded',
                                 options={'xatol': xatol})
    return float(min(r.fun, fun(lo), fun(hi)))


def _profile_interval(cost: Any, est: float, sd: float, limit: float, lo_bound: float,
                      hi_bound: float) -> tuple[float, float]:
    """Return ``{θ: cost(θ) <= limit}`` around ``est``: bracket outward, then Brent's root.

    ``cost`` is the profile (the residual sum of squares minimised over the other
    parameters); ``limit`` = RSS_min + 1.96² s²: the 95 % likelihood-ratio interval.
    """
    step0 = 2.0 * sd if math.isfinite(sd) and sd > 0.0 else max(abs(est) * 1e-3, 1e-9)
    xtol = max(step0 * 1e-4, 1e-15)
    if cost(est) > limit:  # noise-free data: the profile's own tolerance exceeds the limit
        return est, est
    out = []
    for sign, bound in ((-1.0, lo_bound), (1.0, hi_bound)):
        inner, step, edge = est, step0, bound
        while True:
            probe = est + sign * step
            at_bound = (probe <= bound) if sign < 0 else (probe >= bound)
            probe = bound if at_bound else probe
            if cost(probe) > limit:
                edge = optimize.brentq(lambda th: cost(th) - limit, *sorted((inner, probe)),
                                       xtol=xtol)
                break
            if at_bound or step > 1e6 * step0:
                edge = probe
                break
            inner, step = probe, step * 2.0
        out.append(float(edge))
    return out[0], out[1]


@dataclass
class AxisFit:
    """Identified axis: b0, T1, dead time (estimates), the fit's residual and series."""

    b0: Estimate
    t1_s: Estimate
    dead_time_s: Estimate
    offset_mm_s: Estimate
    x0_mm: float
    v0_mm_s: float
    residual_rms_mm: float
    residual_rho: float
    h_s: float
    n_samples: int
    travel_mm: float
    dead_time_grid: list[tuple[int, float]]
    series: AxisSeries
    model_mm: np.ndarray
    notes: list[str] = field(default_factory=list)

    @property
    def dead_time_ticks(self) -> float:
        """Dead time in ticks of ``h_s`` (continuous)."""
        return self.dead_time_s.value / self.h_s


def fit_axis(s: AxisSeries, max_dead_time_s: float = 0.02) -> AxisFit:
    """Fit ``b0, T1, τ`` (and ``x0, v0``, a velocity offset) to the series (module doc)."""
    h = s.h_s
    u, y = s.command_mm_s, s.position_mm
    notes = list(s.notes)
    if u.size < MIN_SAMPLES:
        raise IdentifyError(f'too few samples to identify: {u.size} (at least {MIN_SAMPLES})')
    moving = np.abs(u) > 1e-9
    if moving.sum() < 20:
        raise IdentifyError('no motion commanded: the (enabled) velocity command is zero in '
                            'the whole window, nothing to identify; play an excitation '
                            '(ladrc excite, docs/identification.md)')
    travel = float(np.ptp(y))
    if travel < MIN_TRAVEL_MM:
        raise IdentifyError(f'the axis did not move: encoder range {travel * 1e3:.1f} µm < '
                            f'{MIN_TRAVEL_MM * 1e3:g} µm although commanded; unidentifiable '
                            '(drive disabled or not following its command?)')
    d_max = max(0, min(s.command_pre_mm_s.size - 2, int(round(max_dead_time_s / h))))
    lo, hi = math.log(T1_RANGE_S[0]), math.log(T1_RANGE_S[1])

    def best_t1(d: int) -> tuple[float, float]:
        fun = lambda lt: _projected(s, math.exp(lt), d * h)[0]  # noqa: E731
        # a coarse log grid first (the cost can have more than one dip), then Brent around
        grid = np.linspace(lo, hi, 12)
        costs = [fun(g) for g in grid]
        i = int(np.argmin(costs))
        a, b = grid[max(0, i - 1)], grid[min(grid.size - 1, i + 1)]
        r = optimize.minimize_scalar(fun, bounds=(a, b), method='bounded',
                                     options={'xatol': 1e-3})
        return (float(r.fun), math.exp(float(r.x))) if r.fun <= costs[i] else (
            costs[i], math.exp(grid[i]))

    grid_rss: list[tuple[int, float]] = []
    best = (math.inf, 0, 0.01)
    for d in range(d_max + 1):
        rss, t1 = best_t1(d)
        grid_rss.append((d, math.sqrt(rss / y.size)))
        if rss < best[0]:
            best = (rss, d, t1)
    _, d_best, t1_0 = best
    _, coef = _projected(s, t1_0, d_best * h)
    b0_0, x0_0, c_0, v0_0 = (float(c) for c in coef)
    if not b0_0 > 0.0:
        x = _regressors(s, t1_0, d_best * h)
        e = x @ coef - y
        cov0, _, _ = _covariance(x, e)
        sd0 = math.sqrt(max(cov0[0, 0], 0.0))
        if b0_0 + Z95 * sd0 < 0.0:
            raise IdentifyError(f'the axis moves against its command (b0 fit {b0_0:.3g} <= 0):'
                                ' check the signs of command and encoder (docs/interfaces.md)')
        raise IdentifyError(f'unidentifiable, too little excitation: b0 = {b0_0:.3g} ± '
                            f'{Z95 * sd0:.3g} (95 %) does not tell the axis gain from 0 '
                            f'(encoder travel {travel:.3g} mm)')

    tau_lo, tau_hi = max(0.0, (d_best - 1) * h), min(d_max, d_best + 1) * h
    tau_hi = max(tau_hi, tau_lo + 0.25 * h)
    tau_0 = min(max(d_best * h, tau_lo), tau_hi)

    def resid(p: np.ndarray) -> np.ndarray:
        return simulate_axis(s, p[0], p[1], p[2], p[3], p[4], p[5]) - y

    p0 = np.array([b0_0, t1_0, tau_0, x0_0, v0_0, c_0])
    lb = np.array([1e-6, T1_RANGE_S[0], tau_lo, -np.inf, -np.inf, -np.inf])
    ub = np.array([np.inf, T1_RANGE_S[1], tau_hi, np.inf, np.inf, np.inf])
    span = np.where(np.isfinite(ub - lb), ub - lb, 0.0)
    p0 = np.clip(p0, lb + 1e-9 * span, ub - 1e-9 * span)
    scale = np.array([max(abs(b0_0), 1e-3), max(t1_0, h), h, 0.01, 1.0, 0.01])
    sol = optimize.least_squares(resid, p0, bounds=(lb, ub), x_scale=scale, xtol=1e-12,
                                 ftol=1e-12, gtol=1e-12, max_nfev=200)
    p = sol.x
    r = sol.fun
    cov, s2, rho = _covariance(sol.jac, r)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    b0 = Estimate.of(p[0], sd[0], 0.0)
    # T1 and τ: profile-likelihood intervals (module doc): the model is kinked in τ at whole
    # ticks, where the Jacobian's straight-line picture of the cost misleads
    limit = float(r @ r) + Z95 ** 2 * s2
    t1_lim = (max(T1_RANGE_S[0], p[1] / 4.0), min(T1_RANGE_S[1], p[1] * 4.0))
    tau_lim = (max(0.0, p[2] - 2.0 * h), p[2] + 2.0 * h)

    def profile_tau(tau_s: float) -> float:
        return _min_scalar(lambda lt: _projected(s, math.exp(lt), tau_s)[0],
                           math.log(t1_lim[0]), math.log(t1_lim[1]), 1e-6)

    def profile_t1(t1_s: float) -> float:
        return _min_scalar(lambda ts: _projected(s, t1_s, ts)[0], tau_lim[0], tau_lim[1],
                           1e-5 * h)

    t1 = Estimate(float(p[1]), float(sd[1]), _profile_interval(
        profile_t1, float(p[1]), float(sd[1]), limit, *t1_lim))
    tau = Estimate(float(p[2]), float(sd[2]), _profile_interval(
        profile_tau, float(p[2]), float(sd[2]), limit, 0.0, d_max * h))
    for name, est, bounds in (('T1', t1, t1_lim), ('dead time', tau, (-1.0, d_max * h))):
        if est.ci[0] <= bounds[0] * (1 + 1e-9) or est.ci[1] >= bounds[1] * (1 - 1e-9):
            notes.append(f'the {name} interval reaches the edge of its search range '
                         f'[{bounds[0]:.3g}, {bounds[1]:.3g}] s: it is wider than shown')
    if p[1] <= T1_RANGE_S[0] * 1.01:
        notes.append(f'T1 at its lower bound ({T1_RANGE_S[0] * 1e3:g} ms): the data show no '
                     'velocity-loop lag at this tick')
    fit = AxisFit(b0=b0, t1_s=t1, dead_time_s=tau, offset_mm_s=Estimate.of(p[5], sd[5]),
                  x0_mm=float(p[3]), v0_mm_s=float(p[4]),
                  residual_rms_mm=float(np.sqrt(np.mean(r * r))), residual_rho=rho, h_s=h,
                  n_samples=int(y.size), travel_mm=travel, dead_time_grid=grid_rss, series=s,
                  model_mm=r + y, notes=notes)
    problems = []
    if not b0.rel_halfwidth() <= MAX_B0_REL_HALFWIDTH:  # NaN too
        problems.append(f'b0 = {b0.value:.4g} ± {b0.rel_halfwidth() * 100:.0f} % (95 %)')
    if p[1] > T1_RANGE_S[0] * 1.01 and not t1.rel_halfwidth() <= MAX_T1_REL_HALFWIDTH:
        problems.append(f'T1 = {t1.value * 1e3:.3g} ms ± {t1.rel_halfwidth() * 100:.0f} % '
                        '(95 %)')
    if problems:
        raise IdentifyError('unidentifiable, too little excitation: ' + ', '.join(problems)
                            + f' (encoder travel {travel:.3g} mm); play a PRBS whose band '
                            'reaches past 1/(2π T1) (ladrc excite)')
    return fit


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
    t_r, r, valid = _sorted_unique(t_r, r, valid)
    t_f, y = _sorted_unique(t_f, y)
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
    h = _tick(t_r)
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
    cov, _, _ = _covariance(sol.jac, e)
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


# ---- suggestion ---------------------------------------------------------------------------
OBSERVER_LAG_PRODUCT = 0.5
"""ω0 · T_Σ: the observer's bandwidth against the lag it does not model (module suggest)."""
OBSERVER_OVER_CONTROLLER = 4.0
"""ω0 / ωc."""
TARGET_PHASE_MARGIN_DEG = 40.0
TARGET_MS = 2.0


@dataclass
class Suggestion:
    """Suggested controller parameters (a gated ControllerParams), figures and reasoning."""

    params: Any
    eso_b0: float
    w0_rad_s: float
    wc_rad_s: float
    dead_time_ticks: int
    lag_sum_s: float
    figures: dict[str, dict[str, float]]
    reasoning: list[str]


def gate_dead_ticks(tau_s: float, h_s: float) -> int:
    """Whole ticks for the gate's axis model: τ/h rounded up, a quarter tick of tolerance."""
    return max(0, int(math.ceil(tau_s / h_s - 0.25)))


def suggest(axis: AxisFit, sensor_lag_s: float = 0.0) -> Suggestion:
    """Suggest b0, ESO and controller bandwidths for the identified axis; gate-checked.

    Raises :class:`IdentifyError` when no set on the search passes the stability gate.
    """
    from ladrc_follow.analysis.gate import check_gate
    from ladrc_follow.analysis.loop import AxisModel, analyse_params, frequency_grid
    from ladrc_follow.control.params import ControllerParams, ParameterError, params_from_dict

    # the controller's tick, not the bag's sample period: the gate counts dead time in it
    h = ControllerParams().h_s
    b0 = axis.b0.value
    t1 = axis.t1_s.value
    unresolved = t1 < h  # a lag below a tick is not resolved: plan with one tick
    dead = gate_dead_ticks(axis.dead_time_s.value, h)
    lag = max(0.0, sensor_lag_s if math.isfinite(sensor_lag_s) else 0.0)
    t_sum = max(t1, h) + dead * h + lag + h
    w0 = OBSERVER_LAG_PRODUCT / t_sum
    stab = {'axis_b0': float(f'{b0:.6g}'), 'axis_t1_ms': float(f'{t1 * 1e3:.6g}'),
            'axis_dead_time_ticks': dead, 'axis_lag_ms': float(f'{lag * 1e3:.6g}')}
    model = AxisModel(stab['axis_b0'], stab['axis_t1_ms'] * 1e-3, dead,
                      stab['axis_lag_ms'] * 1e-3)
    reasoning = [
        f'The order-1 LADRC models the axis as the integrator b0/s with b0 = {b0:.4g} '
        '(eso.b0, the identified gain). What it does not model acts as a lag T_Σ = T1 + dead '
        f'time + sensor lag + one tick of hold = {max(t1, h) * 1e3:.3g} + '
        f'{dead * h * 1e3:.3g} + '
        f'{lag * 1e3:.3g} + {h * 1e3:.3g} = {t_sum * 1e3:.3g} ms, which costs about '
        'ω·T_Σ rad of phase at ω.',
        f'Observer: ω0·T_Σ = {OBSERVER_LAG_PRODUCT:g} '
        f'(≈ {math.degrees(OBSERVER_LAG_PRODUCT):.0f}° of unmodelled lag at ω0), so '
        f'ω0 = {w0:.1f} rad/s; a faster observer estimates the '
        'lag as disturbance and rings, a slower one rejects less.',
        f'Controller: ωc = ω0/{OBSERVER_OVER_CONTROLLER:g} = '
        f'{w0 / OBSERVER_OVER_CONTROLLER:.1f} rad/s (the observer settles before the law acts '
        'on its estimate; 3–10 is the usual ratio), far below 1/T_Σ = '
        f'{1.0 / t_sum:.0f} rad/s.',
    ]
    if unresolved:
        reasoning.insert(1, f'T1 = {t1 * 1e3:.3g} ms is below one tick: not resolved by the '
                            f'data, so T_Σ counts one tick ({h * 1e3:g} ms) for it.')
    grid = frequency_grid(h, 1000)
    last: list[str] = []
    for attempt in range(24):
        wc = w0 / OBSERVER_OVER_CONTROLLER
        d = {'eso': {'gains': 'bandwidth', 'w0_rad_s': round(w0, 2),
                     'b0': float(f'{b0:.6g}')},
             'law': {'gains': 'bandwidth', 'wc_rad_s': round(wc, 3)},
             'stability': stab}
        try:
            p = check_gate(params_from_dict(d))
        except ParameterError as exc:
            last = exc.reasons
            p = None
        if p is not None:
            figs = {}
            for mode in ('ladrc', 'pid'):
                an = analyse_params(p, model, mode, grid)
                figs[mode] = {k: float(v) for k, v in an.figures().items()}
            lad = figs['ladrc']
            if (lad['phase_margin_deg'] >= TARGET_PHASE_MARGIN_DEG
                    and lad['ms_peak'] <= TARGET_MS):
                if attempt:
                    reasoning.append(f'Lowered both by 0.85 per step ({attempt} steps) until '
                                     f'the phase margin reached {TARGET_PHASE_MARGIN_DEG:g}° '
                                     f'and Ms {TARGET_MS:g} at most.')
                reasoning.append(
                    f"Checked with the stability gate against the identified axis: LADRC "
                    f"phase margin {lad['phase_margin_deg']:.1f}°, gain margin "
                    f"{lad['gain_margin_db']:.1f} dB, delay margin "
                    f"{lad['delay_margin_ms']:.1f} ms, Ms {lad['ms_peak']:.2f}, bandwidth "
                    f"{lad['bandwidth_hz']:.1f} Hz; PID phase margin "
                    f"{figs['pid']['phase_margin_deg']:.1f}°, Ms "
                    f"{figs['pid']['ms_peak']:.2f} (gate minima: stability.*).")
                return Suggestion(params=p, eso_b0=float(f'{b0:.6g}'), w0_rad_s=round(w0, 2),
                                  wc_rad_s=round(wc, 3), dead_time_ticks=dead,
                                  lag_sum_s=t_sum, figures=figs, reasoning=reasoning)
        w0 *= 0.85
    raise IdentifyError('no suggested parameter set passes the stability gate for the '
                        f'identified axis: {" | ".join(last) or "margins below target"}')


def ci_contains(est: Estimate, truth: float) -> bool:
    """Whether ``truth`` lies in the estimate's interval (tests, the report)."""
    return est.ci[0] <= truth <= est.ci[1]
