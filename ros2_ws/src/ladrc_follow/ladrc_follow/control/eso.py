"""Extended state observers (notes §3, ``ESO.c``; paper eqs. 3-9, 17-22, 34, 38).

Plant of order n (paper eq. 2): x1' = x2, …, xn' = x_{n+1} + b0·u, x_{n+1}' = h(t), y = x1;
x_{n+1} is the "total disturbance" f. The height axis in velocity mode is used with
n = 1 (y' = f + b0·u, the firmware's ``CONTROLLER_ORDER 1``) or n = 2.

Observer (paper eq. 7): z' = A z + B u + L (y − z1), L = (β1 … β_{n+1}). Error
dynamics e' = A_e e + E h with A_e = A − L C (eq. 8). Bandwidth tuning (eq. 9, 18) puts
all n+1 poles at −ω0: β_j = C(n+1, j)·ω0^j.

Discretizations:

* ``euler`` — the firmware's explicit Euler (notes §3.2): z(k+1) = z + h(A z + B u + L e),
  e = y(k) − z1(k). The returned state is the one-step prediction z(k+1). Error matrix
  I + h·A_e, stable iff h < min over the continuous poles λ of −2·Re λ/|λ|²
  (ω0·h < 2 with bandwidth gains).
* ``zoh`` — the current estimator of Miklosovic, Radke & Gao (ACC 2006, "Discrete
  implementation and generalization of the extended state observer"): predict with the
  exact zero-order-hold model, z̄ = Φ z + Γ u, then correct with the new sample,
  z = z̄ + L_c (y − z̄1). Error matrix (I − L_c C) Φ; :func:`zoh_gains` places all its
  eigenvalues at e^(−ω0 h) (or at e^(λ h) for explicit betas). The returned state is
  z(k|k), the estimate at the sample time of y. Here ``u`` is the command held over the
  interval that just ended.

Peaking (notes §3.4): the step functions take optional ``ext_limit`` (clamp of |z_{n+1}|)
and ``ext_rate_limit`` (clamp of its change per step); ``None`` switches each off.
"""

from __future__ import annotations

from math import comb, factorial
from typing import Sequence

from ladrc_contract.ops import ARRAY, SCALAR
import numpy as np


# ---------------------------------------------------------------- gains and analysis
def bandwidth_gains(n: int, w0_rad_s: float) -> tuple[float, ...]:
    """Observer gains with all n+1 poles at −ω0: β_j = C(n+1, j)·ω0^j, j = 1..n+1 (eq. 18)."""
    check_order(n)
    if not (w0_rad_s > 0.0):
        raise ValueError(f'ESO bandwidth w0_rad_s = {w0_rad_s}: must be > 0 rad/s')
    return tuple(float(comb(n + 1, j)) * w0_rad_s ** j for j in range(1, n + 2))


def continuous_matrices(n: int, betas: Sequence[float], b0: float):
    """Paper eq. 3/7/8 matrices ``(A, B, C, L, A_e)`` of an order-n LESO (n+1 states)."""
    check_order(n)
    betas = check_betas(n, betas)
    m = n + 1
    a = np.eye(m, k=1)
    b = np.zeros(m)
    b[n - 1] = b0
    c = np.zeros(m)
    c[0] = 1.0
    ell = np.array(betas, dtype=float)
    return a, b, c, ell, a - np.outer(ell, c)


def euler_is_stable(n: int, betas: Sequence[float], h_s: float) -> bool:
    """Return True when the explicit-Euler error dynamics I + h·A_e have spectral radius < 1."""
    check_order(n)
    *_, a_e = continuous_matrices(n, betas, 1.0)
    m = np.eye(n + 1) + h_s * a_e
    return bool(max(abs(np.linalg.eigvals(m))) < 1.0)


def zoh_matrices(n: int, b0: float, h_s: float):
    """Exact ZOH model of the integrator chain: ``(Phi, Gamma)`` with Phi_ij = h^(j−i)/(j−i)!.

    A is nilpotent (a shift), so e^(Ah) = Σ_k (Ah)^k/k! ends at k = n and
    Γ = Σ_k A^k h^(k+1)/(k+1)! · B, both exactly.
    """
    check_order(n)
    m = n + 1
    a = np.eye(m, k=1)
    b = np.zeros(m)
    b[n - 1] = b0
    phi = np.zeros((m, m))
    gamma = np.zeros(m)
    a_k = np.eye(m)
    for k in range(m):
        phi += a_k * (h_s ** k / factorial(k))
        gamma += a_k @ b * (h_s ** (k + 1) / factorial(k + 1))
        a_k = a_k @ a
    return phi, gamma


def zoh_gains_from_poles(n: int, poles_z: Sequence[complex], h_s: float) -> tuple[float, ...]:
    """Current-estimator gains L_c placing eig((I − L_c C)Φ) at ``poles_z`` (Ackermann).

    Worked in time-scaled coordinates x̃_i = h^(i−1) x_i, where Φ has the entries
    1/(j−i)! independent of h, so the solve is well conditioned at any h; then
    L_i = L̃_i / h^(i−1).
    """
    check_order(n)
    m = n + 1
    if len(poles_z) != m:
        raise ValueError(f'need {m} discrete poles for an order-{n} ESO, got {len(poles_z)}')
    phi1, _ = zoh_matrices(n, 0.0, 1.0)
    c = np.zeros(m)
    c[0] = 1.0
    cp = c @ phi1                       # the pair (Phi, C·Phi) of the current estimator
    obs = np.array([cp @ np.linalg.matrix_power(phi1, i) for i in range(m)])
    coeffs = np.real(np.poly(np.asarray(poles_z)))
    p_phi = sum(cf * np.linalg.matrix_power(phi1, m - i) for i, cf in enumerate(coeffs))
    e_last = np.zeros(m)
    e_last[-1] = 1.0
    l_scaled = p_phi @ np.linalg.solve(obs, e_last)
    return tuple(float(l_scaled[i] / h_s ** i) for i in range(m))


def zoh_gains(n: int, w0_rad_s: float, h_s: float) -> tuple[float, ...]:
    """Current-estimator gains with all error eigenvalues at β = e^(−ω0 h) (Miklosovic 2006).

    Closed forms (checked in the tests): n = 1: (1 − β², (1 − β)²/h);
    n = 2: (1 − β³, 3(1 − β)²(1 + β)/(2h), (1 − β)³/h²).
    """
    if not (w0_rad_s > 0.0 and h_s > 0.0):
        raise ValueError(f'zoh_gains: need w0_rad_s > 0 and h_s > 0, got {w0_rad_s}, {h_s}')
    beta = float(np.exp(-w0_rad_s * h_s))
    return zoh_gains_from_poles(n, [beta] * (n + 1), h_s)


def zoh_gains_from_betas(n: int, betas: Sequence[float], h_s: float) -> tuple[float, ...]:
    """ZOH gains for explicit continuous betas: each continuous pole λ maps to e^(λh)."""
    betas = check_betas(n, betas)
    lam = np.roots([1.0, *betas])
    return zoh_gains_from_poles(n, np.exp(lam * h_s), h_s)


# ---------------------------------------------------------------- fast ops-generic steps
def _limit_ext(ops, old, new, ext_limit, ext_rate_limit):
    """Peaking guard on the extended state (notes §3.4): rate limit, then magnitude."""
    if ext_rate_limit is not None:
        new = old + ops.clip(new - old, -ext_rate_limit, ext_rate_limit)
    if ext_limit is not None:
        new = ops.clip(new, -ext_limit, ext_limit)
    return new


def eso1_euler_step(ops, z1, z2, y, u, b1, b2, b0, h_s, ext_limit=None, ext_rate_limit=None):
    """Order-1 ESO, explicit Euler, exactly the firmware's ``EsoUpdate`` (CONTROLLER_ORDER 1).

    ε = y − z1; z1 += h(z2 + β1 ε + b0 u); z2 += h β2 ε. Returns ``(z1, z2)`` at k+1.
    """
    eps = y - z1
    nz1 = z1 + h_s * (z2 + b1 * eps + b0 * u)
    nz2 = z2 + h_s * b2 * eps
    if ext_limit is not None or ext_rate_limit is not None:
        nz2 = _limit_ext(ops, z2, nz2, ext_limit, ext_rate_limit)
    return nz1, nz2


def eso2_euler_step(ops, z1, z2, z3, y, u, b1, b2, b3, b0, h_s, ext_limit=None,
                    ext_rate_limit=None):
    """Order-2 ESO, explicit Euler (the firmware's order-2 ``EsoUpdate``, with ε = y − z1).

    z1 += h(z2 + β1 ε); z2 += h(z3 + β2 ε + b0 u); z3 += h β3 ε. Returns ``(z1, z2, z3)``.
    """
    eps = y - z1
    nz1 = z1 + h_s * (z2 + b1 * eps)
    nz2 = z2 + h_s * (z3 + b2 * eps + b0 * u)
    nz3 = z3 + h_s * b3 * eps
    if ext_limit is not None or ext_rate_limit is not None:
        nz3 = _limit_ext(ops, z3, nz3, ext_limit, ext_rate_limit)
    return nz1, nz2, nz3


def eso1_zoh_step(ops, z1, z2, y, u, l1, l2, b0, h_s, ext_limit=None, ext_rate_limit=None):
    """Order-1 current-estimator ESO (ZOH prediction, then correction with y(k)).

    ``l1, l2`` from :func:`zoh_gains`; ``u`` is the command held since the last sample.
    Returns ``(z1, z2)`` = z(k|k).
    """
    p1 = z1 + h_s * (z2 + b0 * u)
    eps = y - p1
    nz2 = z2 + l2 * eps
    if ext_limit is not None or ext_rate_limit is not None:
        nz2 = _limit_ext(ops, z2, nz2, ext_limit, ext_rate_limit)
    return p1 + l1 * eps, nz2


def eso2_zoh_step(ops, z1, z2, z3, y, u, l1, l2, l3, b0, h_s, ext_limit=None,
                  ext_rate_limit=None):
    """Order-2 current-estimator ESO (ZOH prediction, then correction). Returns z(k|k)."""
    hh = 0.5 * h_s * h_s
    p1 = z1 + h_s * z2 + hh * (z3 + b0 * u)
    p2 = z2 + h_s * (z3 + b0 * u)
    eps = y - p1
    nz3 = z3 + l3 * eps
    if ext_limit is not None or ext_rate_limit is not None:
        nz3 = _limit_ext(ops, z3, nz3, ext_limit, ext_rate_limit)
    return p1 + l1 * eps, p2 + l2 * eps, nz3


def fal_alphas(n: int, mode: str, alpha: float) -> tuple[float, ...]:
    """Exponents α_1..α_{n+1} of the fal-ESO's corrections (1 = linear).

    'all': α^i on state i (paper eq. 38: 0.5, 0.25, 0.125, 0.0625 for α = 0.5); 'disturbance':
    α on the extended state only (notes §5.2 fix 3); 'off': all linear.
    """
    if mode == 'all':
        return tuple(alpha ** (i + 1) for i in range(n + 1))
    if mode == 'disturbance':
        return (1.0,) * n + (alpha,)
    return (1.0,) * (n + 1)


def eso1_fal_step(ops, z1, z2, y, u, b1, b2, b0, h_s, g, ext_limit=None, ext_rate_limit=None):
    """Order-1 fal-ESO, explicit Euler (paper eq. 4).

    ε = y − z1, (g1, g2) = g(ε); z1 += h(z2 + β1 g1 + b0 u); z2 += h β2 g2. With
    g(ε) = (ε, ε) it is :func:`eso1_euler_step`.
    """
    g1, g2 = g(y - z1)
    nz1 = z1 + h_s * (z2 + b1 * g1 + b0 * u)
    nz2 = z2 + h_s * b2 * g2
    if ext_limit is not None or ext_rate_limit is not None:
        nz2 = _limit_ext(ops, z2, nz2, ext_limit, ext_rate_limit)
    return nz1, nz2


def eso2_fal_step(ops, z1, z2, z3, y, u, b1, b2, b3, b0, h_s, g, ext_limit=None,
                  ext_rate_limit=None):
    """Order-2 fal-ESO, explicit Euler (paper eq. 4).

    (g1, g2, g3) = g(y − z1); z1 += h(z2 + β1 g1); z2 += h(z3 + β2 g2 + b0 u); z3 += h β3 g3.
    """
    g1, g2, g3 = g(y - z1)
    nz1 = z1 + h_s * (z2 + b1 * g1)
    nz2 = z2 + h_s * (z3 + b2 * g2 + b0 * u)
    nz3 = z3 + h_s * b3 * g3
    if ext_limit is not None or ext_rate_limit is not None:
        nz3 = _limit_ext(ops, z3, nz3, ext_limit, ext_rate_limit)
    return nz1, nz2, nz3


def compensate1(ops, z1, z2, e1, b1):
    """Paper eq. 22 for order 1: z' = z + (e1, β1·e1), e1 = y − z1 at the same instant."""
    return z1 + e1, z2 + b1 * e1


def compensate2(ops, z1, z2, z3, e1, b1, b2):
    """Paper eq. 22 for order 2: z' = z + (e1, β1·e1, β2·e1)."""
    return z1 + e1, z2 + b1 * e1, z3 + b2 * e1


def check_order(n: int) -> None:
    """Raise ValueError unless the observer order ``n`` is an integer >= 1."""
    if not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f'ESO order n = {n!r}: must be an integer >= 1 (plant order)')


def check_betas(n: int, betas: Sequence[float]) -> tuple[float, ...]:
    """Return ``betas`` as n+1 positive floats; raise ValueError otherwise."""
    betas = tuple(float(b) for b in betas)
    if len(betas) != n + 1:
        raise ValueError(f'an order-{n} ESO needs {n + 1} gains beta_1..beta_{n + 1}, got'
                         f' {len(betas)}: {betas}')
    if not all(np.isfinite(b) and b > 0.0 for b in betas):
        raise ValueError(f'ESO gains {betas}: each must be a finite number > 0')
    return betas


__all__ = [
    'ARRAY', 'SCALAR', 'bandwidth_gains', 'check_betas', 'check_order', 'compensate1',
    'compensate2', 'continuous_matrices',
    'eso1_euler_step', 'eso1_fal_step', 'eso1_zoh_step', 'eso2_euler_step', 'eso2_fal_step',
    'eso2_zoh_step', 'euler_is_stable', 'fal_alphas', 'zoh_gains', 'zoh_gains_from_betas',
    'zoh_gains_from_poles', 'zoh_matrices',
]
