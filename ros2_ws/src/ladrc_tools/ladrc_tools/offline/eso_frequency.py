"""Paper §4: frequency responses of the LESO's observation errors, with and without D.

Gao & Dong 2019 (seeds ``001_2eec044e7cac6310.txt``) §3.2: the error system of an order-n LESO
(eq. 8, e = x − z) driven by the total disturbance f (h = ḟ), before and after the series
compensator D_i = β_{i−1}·e1 (eq. 22, β0 = 1):

* eq. 28: E_i = q_i(s)·E1, q_i = s^(i−1) + β1 s^(i−2) + … + β_{i−1}; E1/f = s / P(s),
  P(s) = s^(n+1) + β1 s^n + … + β_{n+1}; eq. 29: E_{n+1}/f = (P(s) − β_{n+1}) / P(s);
* eq. 30: E'_1 = 0, E'_i = s^(i−1)·E1 (the compensated errors e' = e − D);
* eq. 31: G_Di(s) = E'_i / E_i = s^(i−1) / q_i(s), i = 2 … n+1;
* eq. 32: with bandwidth gains (eq. 18) and Ω = ω/ω0,
  G_Di(Ω) = [Σ_{k=0}^{i−1} C(n+1, k)·(jΩ)^(−k)]^(−1).

Here the transfer functions are not typed in from these equations: they come from the project's
observer matrices (``ladrc_follow.control.eso.continuous_matrices``, eq. 8's A_e) through
``scipy.signal.ss2tf``, with the compensator as an output matrix I − d·cᵀ (d = (1, β1 … βn)),
and are then compared with eqs. 29-32; :func:`measure_gd` measures G_Di on the sampled observer
``LinearESO(compensate=True)``, the code the controller's compensator is tested against.

Finding: eq. 30 holds for i = 2 only. The paper's own eq. 26 says e'_i = ė_{i−1}, so
E'_i = s·E_{i−1} = s·q_{i−1}(s)·E1, not s^(i−1)·E1, and the compensator's true error ratio is
G_Di = s·q_{i−1}(s) / q_i(s) (:func:`gd_corrected`); it equals eq. 31 for i = 2 (q_1 = 1) and
differs for i ≥ 3, where it rises above 0 dB (the compensator amplifies the error of z3, z4 in
a band around Ω ≈ 1.4 … 3.2 for n = 3). The state-space and the sampled observer agree with
the corrected form; the paper's quoted Ω values come from eq. 32 as printed
(:func:`gd_closed_form`), so both are computed.

Fig. 2 is drawn "for a 4th-order observer": four states z1 … z4, n = 3, the observer of the
paper's own §5.1 example (eq. 36). Pure module (numpy, scipy; no rclpy).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from math import comb
from typing import Sequence

from ladrc_follow import LinearESO, bandwidth_gains, continuous_matrices
import numpy as np
from scipy import optimize, signal

N_FIG2 = 3
"""Order of the Fig. 2 observer: n + 1 = 4 states (paper §3.2, "以 4 阶观测器为例")."""

OMEGA_GRID_DECADE = 0.71
"""The paper's Ω = 5.1286 is 10^0.71 (5.12861): a point of a 0.01-decade frequency grid."""

PAPER = {
    'omega_weak': 5.1286,        # "在 Ω = 5.1286 时": compensation weak, curves nearly merged
    'a_weak': 1.43,              # A(Ω) there (unit not given)
    'phi_weak_deg': 43.5929,     # φ(Ω) there
    'omega_lost': 13.3,          # "在 Ω > 13.3 的高频区": compensation practically lost
    'a_lost_db': 0.1,            # |A(Ω)| < 0.1 there
    'phi_lost_deg': 17.52,       # φ(Ω) < 17.52° there
}


@dataclass(frozen=True)
class ErrorTFs:
    """Error transfer functions of an order-n LESO, as polynomial coefficients in s.

    ``num[i]`` / ``den``: E_{i+1}/h (uncompensated), ``num_comp[i]`` / ``den``: E'_{i+1}/h
    (compensated); multiply by s for the response to f (h = ḟ).
    """

    n: int
    w0_rad_s: float
    betas: tuple[float, ...]
    den: np.ndarray
    num: tuple[np.ndarray, ...]
    num_comp: tuple[np.ndarray, ...]


def _trim(p: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Zero the coefficients that are round-off (relative to the largest); drop leading zeros."""
    p = np.array(p, dtype=float)
    big = np.max(np.abs(p)) if p.size else 0.0
    p[np.abs(p) <= tol * big] = 0.0
    k = 0
    while k < p.size - 1 and abs(p[k]) <= tol * big:
        k += 1
    return p[k:]


def error_tfs(n: int = N_FIG2, w0_rad_s: float = 1.0, betas: Sequence[float] | None = None,
              compensator_sign: float = 1.0) -> ErrorTFs:
    """Build the error transfer functions from the project's LESO matrices (eq. 8, eq. 22).

    ``compensator_sign`` = −1 gives z' = z − D (a wrong compensator, for the tests).
    """
    betas = bandwidth_gains(n, w0_rad_s) if betas is None else tuple(float(b) for b in betas)
    _, _, c, _, a_e = continuous_matrices(n, betas, 1.0)
    m = n + 1
    e_in = np.zeros((m, 1))
    e_in[-1, 0] = 1.0                                    # E: h enters the extended state
    d = np.array((1.0, *betas[:-1]))                     # eq. 22 weights, β0 = 1
    outs = np.vstack([np.eye(m), np.eye(m) - compensator_sign * np.outer(d, c)])
    num, den = signal.ss2tf(a_e, e_in, outs, np.zeros((2 * m, 1)))
    rows = tuple(_trim(r) for r in num)
    return ErrorTFs(n=n, w0_rad_s=float(w0_rad_s), betas=tuple(betas), den=np.asarray(den),
                    num=rows[:m], num_comp=rows[m:])


def gd_tf(tfs: ErrorTFs, i: int) -> signal.TransferFunction:
    """G_Di = E'_i / E_i (eq. 31) as a scipy transfer function, i = 2 … n+1 (1-based)."""
    if not 2 <= i <= tfs.n + 1:
        raise ValueError(f'G_Di is defined for i = 2 .. {tfs.n + 1}, got {i}')
    return signal.TransferFunction(tfs.num_comp[i - 1], tfs.num[i - 1])


def gd_response(tfs: ErrorTFs, i: int, omega_rel: np.ndarray) -> np.ndarray:
    """Complex G_Di(jω) at ω = Ω·ω0 from the state-space-derived polynomials."""
    w = np.asarray(omega_rel, dtype=float) * tfs.w0_rad_s
    _, resp = signal.freqs(tfs.num_comp[i - 1], tfs.num[i - 1], worN=w)
    return resp


def gd_closed_form(n: int, i: int, omega_rel: np.ndarray) -> np.ndarray:
    """Eq. 32: [Σ_{k=0}^{i−1} C(n+1, k)·(jΩ)^(−k)]^(−1)."""
    s = 1j * np.asarray(omega_rel, dtype=float)
    return 1.0 / sum(comb(n + 1, k) * s ** (-k) for k in range(i))


def gd_corrected(n: int, i: int, omega_rel: np.ndarray) -> np.ndarray:
    """Return the true G_Di with bandwidth gains: s·q_{i−1}(s)/q_i(s), s = jΩ (eq. 26)."""
    s = 1j * np.asarray(omega_rel, dtype=float)

    def q(m: int) -> np.ndarray:
        return sum(comb(n + 1, k) * s ** (m - 1 - k) for k in range(m))

    return s * q(i - 1) / q(i)


def corrected_peak(n: int, i: int) -> tuple[float, float]:
    """Return (Ω, dB) of the largest |G_Di| of the corrected form (0 dB limit if none above)."""
    w = np.geomspace(0.01, 1000.0, 20001)
    db = 20.0 * np.log10(np.abs(gd_corrected(n, i, w)))
    k = int(np.argmax(db))
    if k == w.size - 1:
        return math.inf, 0.0
    res = optimize.minimize_scalar(
        lambda lw: -20.0 * np.log10(np.abs(gd_corrected(n, i, np.array([10.0 ** lw]))[0])),
        bounds=(np.log10(w[max(k - 1, 0)]), np.log10(w[k + 1])), method='bounded',
        options={'xatol': 1e-12})
    return float(10.0 ** res.x), float(-res.fun)


def gd_phase_deg(n: int, i: int, omega_rel: np.ndarray | float) -> np.ndarray:
    """Continuous (unwrapped) phase of eq. 32 in degrees: (i−1)·90° − Σ arg(jΩ − p_k).

    p_k are the roots of q_i(Ω) = Σ C(n+1, k) Ω^(i−1−k) (all in the left half plane), so the
    phase falls from (i−1)·90° at Ω → 0 to 0 at Ω → ∞ as a Bode plot draws it.
    """
    roots = np.roots([comb(n + 1, k) for k in range(i)]) if i > 1 else np.array([])
    w = np.atleast_1d(np.asarray(omega_rel, dtype=float))
    ph = (i - 1) * 90.0 - sum(np.degrees(np.angle(1j * w - p)) for p in roots)
    return np.asarray(ph, dtype=float)


def gd_db(n: int, i: int, omega_rel: np.ndarray | float) -> np.ndarray:
    """Magnitude of eq. 32 in dB."""
    return 20.0 * np.log10(np.abs(gd_closed_form(n, i, np.atleast_1d(omega_rel))))


def omega_at_db(n: int, i: int, level_db: float, lo: float = 0.05, hi: float = 1e4) -> float:
    """Ω where 20·log10|G_Di| = ``level_db`` (< 0; |G_Di| rises monotonically to 1)."""
    return float(optimize.brentq(lambda w: gd_db(n, i, w)[0] - level_db, lo, hi, xtol=1e-12))


def omega_at_phase(n: int, i: int, phase_deg: float, lo: float = 0.05, hi: float = 1e4
                   ) -> float:
    """Highest-branch Ω where the continuous phase of G_Di equals ``phase_deg``."""
    return float(optimize.brentq(lambda w: gd_phase_deg(n, i, w)[0] - phase_deg, lo, hi,
                                 xtol=1e-12))


def error_per_disturbance(tfs: ErrorTFs, omega_rel: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """|E_i/f| and |E'_i/f| (eqs. 28-30) on Ω: arrays (n+1, len(Ω)), e = x − z."""
    w = np.asarray(omega_rel, dtype=float) * tfs.w0_rad_s
    s = 1j * w
    out = []
    for rows in (tfs.num, tfs.num_comp):
        resp = []
        for r in rows:
            _, h = signal.freqs(r, tfs.den, worN=w)
            resp.append(np.abs(h * s))                    # f → e: times s (h = ḟ)
        out.append(np.array(resp))
    return out[0], out[1]


def measure_gd(omega_rel: float, n: int = N_FIG2, w0_rad_s: float = 1.0,
               w0_h: float = 1e-3, periods: int = 4, settle_w0_t: float = 40.0,
               compensator_sign: float = 1.0) -> np.ndarray:
    """Measure G_Di (i = 2 … n+1) on the sampled ``LinearESO`` (ZOH current estimator).

    The plant is the chain of eq. 2 with u = 0 and f = sin(ωt): x_{n+1} = f and x_i its
    (n+1−i)-fold integral, written in closed form so the observer sees the exact samples
    y = x1(t_k). One run gives both estimates: ``update`` returns z + D, and the observer's
    own state is z. After ``settle_w0_t``/ω0 s the errors e = x − z and e' = x − (z ± D) are
    fitted with a sine and a cosine over ``periods`` periods; the ratio of the fitted phasors
    is G_Di (array of n complex values). ``compensator_sign`` = −1 measures z − D instead.
    """
    w = omega_rel * w0_rad_s
    h = w0_h / w0_rad_s
    eso = LinearESO(n, 1.0, h, w0_rad_s=w0_rad_s, discretization='zoh', compensate=True)
    t_fit = periods * 2.0 * np.pi / w
    k_end = int(np.ceil((settle_w0_t / w0_rad_s + t_fit) / h))
    k_fit = k_end - int(round(t_fit / h))
    t = np.arange(k_end) * h

    def states(tk: np.ndarray) -> np.ndarray:
        # x_{n+1} = sin ωt; each integral shifts the phase by −90° and divides by ω
        return np.array([np.sin(w * tk - (n - j) * np.pi / 2) / w ** (n - j)
                         for j in range(n + 1)])

    x = states(t)
    eso.reset(float(x[0, 0]), [float(v) for v in x[1:, 0]])
    e = np.empty((n + 1, k_end - k_fit))
    e_c = np.empty_like(e)
    for k in range(k_end):
        out = eso.update(float(x[0, k]), 0.0)
        if k >= k_fit:
            z = eso.z
            d = out - z                                   # the compensator's D
            e[:, k - k_fit] = x[:, k] - z
            e_c[:, k - k_fit] = x[:, k] - (z + compensator_sign * d)
    tf = t[k_fit:]
    basis = np.column_stack([np.sin(w * tf), np.cos(w * tf)])
    ph = []
    for arr in (e, e_c):
        coef, *_ = np.linalg.lstsq(basis, arr.T, rcond=None)
        ph.append(coef[0] + 1j * coef[1])                 # a sin + b cos ↔ phasor a + jb
    return ph[1][1:] / ph[0][1:]


def figures(n: int = N_FIG2) -> dict[str, float]:
    """Compute the Ω values and figures behind the paper's two statements (eq. 32)."""
    out: dict[str, float] = {}
    w_weak = PAPER['omega_weak']
    w_lost = PAPER['omega_lost']
    for i in range(2, n + 2):
        out[f'a_db_at_5_1286_i{i}'] = float(gd_db(n, i, w_weak)[0])
        out[f'phi_deg_at_5_1286_i{i}'] = float(gd_phase_deg(n, i, w_weak)[0])
        out[f'a_db_at_13_3_i{i}'] = float(gd_db(n, i, w_lost)[0])
        out[f'phi_deg_at_13_3_i{i}'] = float(gd_phase_deg(n, i, w_lost)[0])
        out[f'omega_0p1db_i{i}'] = omega_at_db(n, i, -PAPER['a_lost_db'])
        out[f'omega_phi_17_52_i{i}'] = omega_at_phase(n, i, PAPER['phi_lost_deg'])
    top = n + 1
    out['omega_phi_43_5929_top'] = omega_at_phase(n, top, PAPER['phi_weak_deg'])
    out['a_db_spread_at_5_1286'] = float(
        max(out[f'a_db_at_5_1286_i{i}'] for i in range(2, n + 2))
        - min(out[f'a_db_at_5_1286_i{i}'] for i in range(2, n + 2)))
    out['omega_grid_point'] = 10.0 ** OMEGA_GRID_DECADE
    for i in range(2, n + 2):
        w_pk, db_pk = corrected_peak(n, i)
        out[f'corrected_peak_db_i{i}'] = db_pk
        out[f'corrected_peak_omega_i{i}'] = w_pk
        out[f'corrected_a_db_at_5_1286_i{i}'] = float(
            20.0 * np.log10(np.abs(gd_corrected(n, i, np.array([w_weak]))[0])))
        out[f'corrected_phi_deg_at_5_1286_i{i}'] = float(
            np.degrees(np.angle(gd_corrected(n, i, np.array([w_weak]))[0])))
    return out


__all__ = [
    'ErrorTFs', 'N_FIG2', 'OMEGA_GRID_DECADE', 'PAPER', 'corrected_peak', 'error_per_disturbance',
    'error_tfs', 'figures', 'gd_closed_form', 'gd_corrected', 'gd_db', 'gd_phase_deg',
    'gd_response', 'gd_tf',
    'measure_gd', 'omega_at_db', 'omega_at_phase',
]
