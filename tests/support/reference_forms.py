"""Reference forms of the core's algorithms, for the tests only (not on the tick path).

Written as the notes and the paper state them (classes with state, matrix forms, the
notes' explicit-Euler TD, the plain Kalman step), so that the tests can hold the tick's fused
step functions (``ladrc_follow.control``) against an independent statement of the same
algorithm. They moved here from the controller package: the package is what ticks.
"""

from __future__ import annotations

import math
from math import comb
from typing import Sequence

from ladrc_contract.ops import ARRAY, SCALAR
from ladrc_follow.control.eso import (
    check_betas,
    check_order,
    continuous_matrices,
)
from ladrc_follow.control.kalman import KalmanParams, kalman_gated_step
from ladrc_follow.control.nonlinear import (
    DEFAULT_TABLE_SIZE,
    LookupTable,
    asinh_fn,
    atan_fn,
    fal,
    sat,
    sigmoid,
    sinh_fn,
    tanh_fn,
)
from ladrc_follow.control.td import (
    SAMPLE_PERIOD_S,
    TDA_FIRMWARE,
    TDB_FIRMWARE,
    TDParams,
    td_step_firmware,
)
import numpy as np


def seed_gains_order1(w0_rad_s: float) -> tuple[float, float]:
    """Return the firmware's order-1 gains (3ω, 3ω²): (270, 24300) at ω = 90, (180, 10800) at 60.

    These are the first two terms of the order-2 formula (``GetLADRCParam``), not the
    order-1 bandwidth gains (2ω, ω²). The error poles are the roots of
    s² + 3ω s + 3ω²: s = ω(−1.5 ± j·0.866), |s| = √3·ω, damping √3/2 = 0.866. At ω = 90
    they sit at |s| = 155.9 rad/s (24.8 Hz), not at the notes' "14.6 Hz" label
    (≈ ω/2π = 14.3 Hz); at ω = 60, |s| = 103.9 rad/s (16.5 Hz), not "9.8 Hz".
    """
    if not (w0_rad_s > 0.0):
        raise ValueError(f'w0_rad_s = {w0_rad_s}: must be > 0 rad/s')
    return 3.0 * w0_rad_s, 3.0 * w0_rad_s ** 2


def static_error(n: int, w0_rad_s: float, h0: float) -> tuple[float, ...]:
    """Return the static errors (e1 … e_{n+1}) under a constant disturbance rate h0 (eq. 19).

    e_{i+1} = C(n+1, i)·h0 / ω0^(n+1−i), i = 0..n, for bandwidth gains (e = x − z).
    """
    check_order(n)
    return tuple(comb(n + 1, i) * h0 / w0_rad_s ** (n + 1 - i) for i in range(n + 1))


def euler_stability_limit(n: int, betas: Sequence[float] | None = None) -> float:
    """Largest step for which the explicit-Euler ESO is stable.

    Without ``betas`` (bandwidth gains): the bound on ω0·h, which is exactly 2 for every n
    (all poles at −ω0 map to 1 − ω0 h). With ``betas``: the bound on h in seconds,
    min over the continuous poles λ of −2·Re λ / |λ|² (|1 + hλ| < 1).
    """
    check_order(n)
    if betas is None:
        return 2.0
    betas = check_betas(n, betas)
    lam = np.roots([1.0, *betas])
    if np.any(lam.real >= 0.0):
        raise ValueError(f'ESO betas {betas} give a continuous observer that is not stable'
                         ' (a pole with Re >= 0); no step size helps')
    return float(np.min(-2.0 * lam.real / np.abs(lam) ** 2))


class NonlinearESO:
    """Order-n fal-ESO (paper eq. 4 with g_i = fal(·, α_i, δ), eq. 38), explicit Euler.

    With ``compensate=True`` :meth:`update` returns z' = z + D with
    D_i = β_{i−1}·g_{i−1}(e1), g_0(e) = e (paper eq. 34/39). Inside |e1| ≤ δ it equals a
    :class:`LinearESO` with gains β_i·δ^(α_i − 1). Same time convention as LinearESO/euler.
    """

    def __init__(self, n: int, b0: float, h_s: float, betas: Sequence[float],
                 alphas: Sequence[float], delta: float, compensate: bool = False):
        check_order(n)
        self.betas = check_betas(n, betas)
        if len(alphas) != n + 1 or not all(0.0 < a <= 1.0 for a in alphas):
            raise ValueError(f'NonlinearESO: need {n + 1} alphas in (0, 1], got {alphas}')
        if not (delta > 0.0):
            raise ValueError(f'NonlinearESO: delta = {delta} must be > 0 (linear-zone width)')
        if not (h_s > 0.0):
            raise ValueError(f'NonlinearESO: h_s = {h_s} must be > 0 (seconds)')
        self.n, self.b0, self.h_s = n, float(b0), float(h_s)
        self.alphas = np.array(alphas, dtype=float)
        self.delta = float(delta)
        self.compensate = compensate
        self.A, self.B, *_ = continuous_matrices(n, self.betas, b0)
        self._beta = np.array(self.betas)
        self.z = np.zeros(n + 1)

    def gains(self, e1: float) -> np.ndarray:
        """g_i(e1) = fal(e1, α_i, δ) for i = 1..n+1."""
        return fal(ARRAY, np.full(self.n + 1, float(e1)), self.alphas, self.delta)

    def reset(self, y0: float, rest: Sequence[float] | None = None) -> None:
        """Set z1 = y0 and the higher states to ``rest`` (zeros by default)."""
        self.z = np.zeros(self.n + 1)
        self.z[0] = y0
        if rest is not None:
            self.z[1:] = rest

    def update(self, y: float, u: float) -> np.ndarray:
        """Feed one sample; return the estimate at this sample time (+ D if compensating)."""
        e1 = y - self.z[0]
        g = self.gains(e1)
        out = self.z.copy()
        if self.compensate:
            out[0] += e1
            out[1:] += self._beta[:-1] * g[:-1]
        self.z = self.z + self.h_s * (self.A @ self.z + self.B * u + self._beta * g)
        return out


def kalman_step(ops, x, p, z, dz_enc, q, r):
    """One predict/update step; returns ``(x, p, k)`` (notes §4 eqs. (1)-(5)).

    Predict x⁻ = x + Δenc, P⁻ = P + Q; gain K = P⁻/(P⁻ + R); update
    x = x⁻ + K(z − x⁻), P = (1 − K)P⁻.
    """
    xp = x + dz_enc
    pp = p + q
    k = pp / (pp + r)
    return xp + k * (z - xp), (1.0 - k) * pp, k


def steady_state_gain(q: float, r: float) -> float:
    """Limit of K for a scalar random walk: P⁻ = (Q + √(Q² + 4QR))/2, K = P⁻/(P⁻ + R).

    P⁻ solves the scalar Riccati equation P⁻ = P⁻R/(P⁻ + R) + Q.
    """
    if not (q > 0.0 and r > 0.0):
        raise ValueError(f'steady_state_gain: need q > 0 and r > 0, got {q}, {r}')
    pm = 0.5 * (q + math.sqrt(q * q + 4.0 * q * r))
    return pm / (pm + r)


class HeightKalman:
    """Gap filter with the reset rules of the follow controller (scalar).

    Rules (the notes enable the filter once followed, ``随动到位之后开启``):

    * :meth:`reset` (call when the filter is switched on, e.g. on reaching "followed"):
      x = the current reading, P = p0.
    * An invalid reading (``valid=False`` or not finite): the tick is coasted on the
      encoder alone (x += Δenc, P += Q) and the filter is marked for re-initialisation;
      the next valid reading restarts it (x = reading, P = p0). More than
      ``max_coast_ticks`` invalid ticks in a row leave it uninitialised (returns nan).
    * A jump: z − x⁻ > ``gate_mm``, a reading wider than predicted (e.g. a sheet edge under
      the nozzle, a change the random-walk model cannot explain; one-sided, see
      :func:`kalman_gated_step`), re-initialises on the reading after
      ``gate_confirm_ticks`` of them in a row (default 1: at once).

    ``resets`` counts the re-initialisations for diagnostics.
    """

    def __init__(self, params: KalmanParams = KalmanParams(), gate_mm: float = 0.5,  # noqa: B008
                 max_coast_ticks: int = 20, gate_confirm_ticks: int = 1):
        bad = params.problems()
        if not (gate_mm > 0.0):
            bad.append(f'kalman gate_mm = {gate_mm}: must be > 0 mm')
        if max_coast_ticks < 0:
            bad.append(f'kalman max_coast_ticks = {max_coast_ticks}: must be >= 0')
        if bad:
            raise ValueError('; '.join(bad))
        self.params, self.gate_mm, self.max_coast_ticks = params, gate_mm, max_coast_ticks
        self.gate_confirm_ticks = gate_confirm_ticks
        self.outliers = 0  # in a row
        self.x = math.nan
        self.p = math.nan
        self.k = math.nan
        self.initialised = False
        self.coast_ticks = 0
        self.resets = 0

    def reset(self, z_mm: float) -> None:
        """Start on reading ``z_mm`` with P = p0."""
        self.x, self.p, self.k = float(z_mm), self.params.p0_mm2, 1.0
        self.initialised = True
        self.coast_ticks = 0
        self.outliers = 0

    def update(self, z_mm: float, dz_enc_mm: float, valid: bool = True) -> float:
        """Fuse one reading with this tick's encoder increment; return the gap estimate."""
        ok = valid and math.isfinite(z_mm)
        if not ok:
            if not self.initialised or self.coast_ticks >= self.max_coast_ticks:
                self.initialised = False
                self.x = math.nan
                return self.x
            self.coast_ticks += 1
            self.x += dz_enc_mm
            self.p += self.params.q_mm2
            return self.x
        if not self.initialised or self.coast_ticks > 0:
            self.resets += 1
            self.reset(z_mm)
            return self.x
        pa = self.params
        off = z_mm - (self.x + dz_enc_mm)  # the rule of kalman_gated_step, for the count
        if off < -self.gate_mm or (off > self.gate_mm
                                   and self.outliers + 1 >= self.gate_confirm_ticks):
            self.resets += 1
        self.x, self.p, self.k, self.outliers = kalman_gated_step(
            SCALAR, self.x, self.p, self.outliers, z_mm, dz_enc_mm, True, pa.q_mm2,
            pa.r_mm2, pa.p0_mm2, self.gate_mm, self.gate_confirm_ticks)
        return self.x


def default_tables(size: int = DEFAULT_TABLE_SIZE) -> dict[str, LookupTable]:
    """Tables of each nonlinear function with unit shape gain, as documented in estimators.md.

    fal is tabulated for the paper's NESO first channel (alpha 0.5, delta 0.05) on
    [-1, 1]; the range of each table covers the region where the function is not
    yet flat (clamped ones) or where the controller's errors live (the rest).
    """
    def arr(f, *args):
        return lambda x: f(ARRAY, np.asarray(x, dtype=float), *args)

    return {
        'fal(0.5,0.05)': LookupTable(arr(fal, 0.5, 0.05), -1.0, 1.0, size, True, 'linear'),
        'sat(1)': LookupTable(arr(sat, 1.0), -2.0, 2.0, size, True, 'clamp'),
        'sigmoid(1)': LookupTable(arr(sigmoid, 1.0), -16.0, 16.0, size, True, 'clamp'),
        'tanh(1)': LookupTable(arr(tanh_fn, 1.0), -8.0, 8.0, size, True, 'clamp'),
        'atan(1)': LookupTable(arr(atan_fn, 1.0), -20.0, 20.0, size, True, 'linear'),
        'asinh(1)': LookupTable(arr(asinh_fn, 1.0), -20.0, 20.0, size, True, 'linear'),
        'sinh(1)': LookupTable(arr(sinh_fn, 1.0), -4.0, 4.0, size, True, 'linear'),
    }


def td_params_from_wn_xi(wn_rad_s: float, xi: float, k1: float = 1.0,
                         alpha: float = 0.0) -> TDParams:
    """TD parameters with natural frequency ``wn_rad_s`` and damping ``xi`` (for a given k1).

    Inverts ωn = R√k1, ξ = k2/(2√k1): R = ωn/√k1, k2 = 2ξ√k1.
    """
    if not (wn_rad_s > 0.0 and xi > 0.0 and k1 > 0.0):
        raise ValueError(f'td_params_from_wn_xi: need wn_rad_s > 0, xi > 0, k1 > 0; got'
                         f' {wn_rad_s}, {xi}, {k1}')
    root = math.sqrt(k1)
    return TDParams(k1=k1, k2=2.0 * xi * root, r_per_s=wn_rad_s / root, alpha=alpha)


def td_step(ops, x1, x2, v, dv, k1, k2, r, alpha, h_s):
    """One step of the notes' discrete forward form (§2.1), both updates from step k.

    x1(k+1) = x1 + h·x2;  x2(k+1) = x2 + h·R²·(−k1(x1 − v) − k2·x2/R) + α·dv,
    ``dv`` = the feed-forward input's increment this step. This is explicit Euler;
    :func:`td_step_firmware` is the firmware's order.
    """
    f = -k1 * (x1 - v) - k2 * x2 / r
    return x1 + h_s * x2, x2 + h_s * r * r * f + alpha * dv


# The notes' MATLAB simulation set "2019-12-1" (§2.3): TDA 2.2,1.3,30,15; TDB 2.2,2.8,30,18.
TDA_SIM_2019 = TDParams(k1=2.2, k2=1.3, r_per_s=30.0, alpha=15.0)


TDB_SIM_2019 = TDParams(k1=2.2, k2=2.8, r_per_s=30.0, alpha=18.0)


def compound_td_step(ops, state, v, a_k1, a_k2, a_r, a_alpha, b_k1, b_k2, b_r, b_alpha, h_s,
                     firmware_order=True):
    """One step of the compound TD (``CompELDTUpdate``).

    ``state = (a_x1, a_x2, b_x1, b_x2, v_prev)``. TDA tracks ``v`` with its own
    increment ``v − v_prev`` as feed-forward; TDB tracks ``v`` with TDA's output
    increment as feed-forward (firmware: ``ELDTrackerCalc(B, v, A->nTracker)`` after A
    was updated). Returns the new state; TDB's ``(b_x1, b_x2)`` is the TD output.
    """
    step = td_step_firmware if firmware_order else td_step
    a_x1, a_x2, b_x1, b_x2, v_prev = state
    na_x1, na_x2 = step(ops, a_x1, a_x2, v, v - v_prev, a_k1, a_k2, a_r, a_alpha, h_s)
    nb_x1, nb_x2 = step(ops, b_x1, b_x2, v, na_x1 - a_x1, b_k1, b_k2, b_r, b_alpha, h_s)
    return na_x1, na_x2, nb_x1, nb_x2, v


class CompoundTD:
    """Convenience wrapper of :func:`compound_td_step` (scalar, or batch with ``ARRAY`` ops).

    Parameters may be :class:`TDParams` of floats, or of numpy arrays for a batch.
    """

    def __init__(self, pa: TDParams = TDA_FIRMWARE, pb: TDParams = TDB_FIRMWARE,
                 h_s: float = SAMPLE_PERIOD_S, ops=SCALAR, firmware_order: bool = True):
        if not (h_s > 0.0):
            raise ValueError(f'CompoundTD: h_s = {h_s} must be > 0 (seconds)')
        self.pa, self.pb, self.h_s, self.ops = pa, pb, h_s, ops
        self.firmware_order = firmware_order
        self._args = (pa.k1, pa.k2, pa.r_per_s, pa.alpha, pb.k1, pb.k2, pb.r_per_s, pb.alpha,
                      h_s)
        self.state = None

    def reset(self, v0) -> None:
        """Start both TDs at rest on ``v0`` (``ELDTrackerInit``: x1 = v0, x2 = 0, ff = v0)."""
        zero = v0 * 0.0
        self.state = (v0 + zero, zero, v0 + zero, zero, v0 + zero)

    def step(self, v):
        """Advance one sample with reference ``v``; return TDB's ``(x1, x2)``."""
        if self.state is None:
            self.reset(v)
        self.state = compound_td_step(self.ops, self.state, v, *self._args,
                                      firmware_order=self.firmware_order)
        return self.state[2], self.state[3]
