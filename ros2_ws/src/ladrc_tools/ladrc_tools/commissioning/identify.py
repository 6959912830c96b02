"""Identification of the Z axis and the capacitive sensor from a bag.

**Axis** (notes §1.1): ``G(s) = b0 e^(−sτ) / (s (T1 s + 1))`` from the velocity command to the
encoder position. Data: ``axis/velocity_command`` (``velocity_mm_s``, ``enable``: a disabled
command is a zero command) and ``axis/feedback`` (``position_mm``; the longest stretch with the
drive enabled and not faulted). The feedback stamps give the grid (tick ``h`` from their
spacing, robust to lost samples: :func:`sample_tick`; positions interpolated onto ``t0 + j h``
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

The sensor fit is :mod:`.identify_sensor`; the suggested parameters :mod:`.identify_suggest`.
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


def sorted_unique(t: np.ndarray, *cols: np.ndarray) -> tuple[np.ndarray, ...]:
    """Return ``t`` sorted with duplicates dropped (first kept), and the columns alike."""
    order = np.argsort(t, kind='stable')
    t = t[order]
    keep = np.concatenate(([True], np.diff(t) > 0.0)) if t.size else np.zeros(0, bool)
    return (t[keep],) + tuple(c[order][keep] for c in cols)


def sample_tick(t: np.ndarray) -> float:
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
    t_f, y, en, fault = sorted_unique(t_f, y, en, fault)
    t_c, v_c, e_c = sorted_unique(t_c, v_c, e_c)
    h = sample_tick(t_f)
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


def covariance(jac: np.ndarray, resid: np.ndarray) -> tuple[np.ndarray, float, float]:
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


def _check_motion(s: AxisSeries) -> float:
    """Return the encoder travel; raise when nothing was commanded or nothing moved."""
    u, y = s.command_mm_s, s.position_mm
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
    return travel


def _best_t1(s: AxisSeries, dead_ticks: int) -> tuple[float, float]:
    """Return ``(rss, T1)`` of the best T1 at a dead time of whole ticks (b0 etc. projected)."""
    lo, hi = math.log(T1_RANGE_S[0]), math.log(T1_RANGE_S[1])
    fun = lambda lt: _projected(s, math.exp(lt), dead_ticks * s.h_s)[0]  # noqa: E731
    # a coarse log grid first (the cost can have more than one dip), then Brent around
    grid = np.linspace(lo, hi, 12)
    costs = [fun(g) for g in grid]
    i = int(np.argmin(costs))
    a, b = grid[max(0, i - 1)], grid[min(grid.size - 1, i + 1)]
    r = optimize.minimize_scalar(fun, bounds=(a, b), method='bounded',
                                 options={'xatol': 1e-3})
    return (float(r.fun), math.exp(float(r.x))) if r.fun <= costs[i] else (
        costs[i], math.exp(grid[i]))


def _dead_time_grid(s: AxisSeries, d_max: int) -> tuple[list[tuple[int, float]], int, float]:
    """Return the residual RMS per whole-tick dead time, the best dead time and its T1."""
    grid_rss: list[tuple[int, float]] = []
    best = (math.inf, 0, 0.01)
    for d in range(d_max + 1):
        rss, t1 = _best_t1(s, d)
        grid_rss.append((d, math.sqrt(rss / s.position_mm.size)))
        if rss < best[0]:
            best = (rss, d, t1)
    _, d_best, t1_0 = best
    return grid_rss, d_best, t1_0


def _check_gain(s: AxisSeries, coef: np.ndarray, t1_s: float, tau_s: float,
                travel: float) -> None:
    """Raise when the projected axis gain b0 is not positive (module doc)."""
    b0 = float(coef[0])
    if b0 > 0.0:
        return
    x = _regressors(s, t1_s, tau_s)
    cov0, _, _ = covariance(x, x @ coef - s.position_mm)
    sd0 = math.sqrt(max(cov0[0, 0], 0.0))
    if b0 + Z95 * sd0 < 0.0:
        raise IdentifyError(f'the axis moves against its command (b0 fit {b0:.3g} <= 0):'
                            ' check the signs of command and encoder (docs/interfaces.md)')
    raise IdentifyError(f'unidentifiable, too little excitation: b0 = {b0:.3g} ± '
                        f'{Z95 * sd0:.3g} (95 %) does not tell the axis gain from 0 '
                        f'(encoder travel {travel:.3g} mm)')


def _refine(s: AxisSeries, p0: np.ndarray, tau_lim: tuple[float, float]) -> Any:
    """Least squares on ``b0, T1, τ, x0, v0, c`` from ``p0``, τ within ``tau_lim``."""
    h = s.h_s

    def resid(p: np.ndarray) -> np.ndarray:
        return simulate_axis(s, p[0], p[1], p[2], p[3], p[4], p[5]) - s.position_mm

    lb = np.array([1e-6, T1_RANGE_S[0], tau_lim[0], -np.inf, -np.inf, -np.inf])
    ub = np.array([np.inf, T1_RANGE_S[1], tau_lim[1], np.inf, np.inf, np.inf])
    scale = np.array([max(abs(p0[0]), 1e-3), max(p0[1], h), h, 0.01, 1.0, 0.01])
    span = np.where(np.isfinite(ub - lb), ub - lb, 0.0)
    p0 = np.clip(p0, lb + 1e-9 * span, ub - 1e-9 * span)
    return optimize.least_squares(resid, p0, bounds=(lb, ub), x_scale=scale, xtol=1e-12,
                                  ftol=1e-12, gtol=1e-12, max_nfev=200)


def _profile_intervals(s: AxisSeries, p: np.ndarray, sd: np.ndarray, limit: float,
                       d_max: int, notes: list[str]) -> tuple[Estimate, Estimate]:
    """Return T1 and τ with profile-likelihood intervals (module doc); note clipped ones.

    The model is kinked in τ at whole ticks, where the Jacobian's straight-line picture of the
    cost misleads.
    """
    h = s.h_s
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
    return t1, tau


def _check_identifiable(fit: AxisFit) -> None:
    """Raise when b0 or T1 is too uncertain to use (MAX_*_REL_HALFWIDTH)."""
    b0, t1 = fit.b0, fit.t1_s
    problems = []
    if not b0.rel_halfwidth() <= MAX_B0_REL_HALFWIDTH:  # NaN too
        problems.append(f'b0 = {b0.value:.4g} ± {b0.rel_halfwidth() * 100:.0f} % (95 %)')
    if t1.value > T1_RANGE_S[0] * 1.01 and not t1.rel_halfwidth() <= MAX_T1_REL_HALFWIDTH:
        problems.append(f'T1 = {t1.value * 1e3:.3g} ms ± {t1.rel_halfwidth() * 100:.0f} % '
                        '(95 %)')
    if problems:
        raise IdentifyError('unidentifiable, too little excitation: ' + ', '.join(problems)
                            + f' (encoder travel {fit.travel_mm:.3g} mm); play a PRBS whose '
                            'band reaches past 1/(2π T1) (ladrc excite)')


def fit_axis(s: AxisSeries, max_dead_time_s: float = 0.02) -> AxisFit:
    """Fit ``b0, T1, τ`` (and ``x0, v0``, a velocity offset) to the series (module doc).

    A grid over whole-tick dead times with T1 searched and the linear parameters projected
    gives the start; least squares refines all six; T1 and τ get profile intervals.
    """
    h = s.h_s
    y = s.position_mm
    notes = list(s.notes)
    travel = _check_motion(s)
    d_max = max(0, min(s.command_pre_mm_s.size - 2, int(round(max_dead_time_s / h))))
    grid_rss, d_best, t1_0 = _dead_time_grid(s, d_max)
    _, coef = _projected(s, t1_0, d_best * h)
    _check_gain(s, coef, t1_0, d_best * h, travel)
    b0_0, x0_0, c_0, v0_0 = (float(c) for c in coef)

    tau_lo, tau_hi = max(0.0, (d_best - 1) * h), min(d_max, d_best + 1) * h
    tau_hi = max(tau_hi, tau_lo + 0.25 * h)
    tau_0 = min(max(d_best * h, tau_lo), tau_hi)
    sol = _refine(s, np.array([b0_0, t1_0, tau_0, x0_0, v0_0, c_0]), (tau_lo, tau_hi))
    p, r = sol.x, sol.fun
    cov, s2, rho = covariance(sol.jac, r)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    t1, tau = _profile_intervals(s, p, sd, float(r @ r) + Z95 ** 2 * s2, d_max, notes)
    if p[1] <= T1_RANGE_S[0] * 1.01:
        notes.append(f'T1 at its lower bound ({T1_RANGE_S[0] * 1e3:g} ms): the data show no '
                     'velocity-loop lag at this tick')
    fit = AxisFit(b0=Estimate.of(p[0], sd[0], 0.0), t1_s=t1, dead_time_s=tau,
                  offset_mm_s=Estimate.of(p[5], sd[5]), x0_mm=float(p[3]),
                  v0_mm_s=float(p[4]), residual_rms_mm=float(np.sqrt(np.mean(r * r))),
                  residual_rho=rho, h_s=h, n_samples=int(y.size), travel_mm=travel,
                  dead_time_grid=grid_rss, series=s, model_mm=r + y, notes=notes)
    _check_identifiable(fit)
    return fit


def ci_contains(est: Estimate, truth: float) -> bool:
    """Whether ``truth`` lies in the estimate's interval (tests, the report)."""
    return est.ci[0] <= truth <= est.ci[1]
