"""1-D Kalman filter: capacitive gap fused with encoder increments (notes §4, ``Kalman_Int.c``).

Model (``Kalman_Int.c`` header comment): gap(k) = gap(k−1) + Δenc(k) + w(k), reading
z(k) = gap(k) + δ(k); Var w = Q, Var δ = R. Δenc is the nozzle's encoder increment this
tick, Z positive up, so moving up by Δenc increases the gap by Δenc (a fixed sheet;
sheet motion is what Q stands for).

The firmware keeps the gain in 1/1000 (``_nKg = 1000*P/(P+R)``) and everything in int
UnitP / UnitP²; here all is float mm / mm². It starts with P = 0 although its own comment
says it should not (a zero P with small Q makes the filter ignore the sensor for a long
time); :class:`HeightKalman` starts with P = p0.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from .ops import SCALAR
from .schema import Section, param


@dataclass(frozen=True)
class KalmanParams(Section):
    """The gap filter (``ControllerParams.kalman``): switch and noise variances in mm².

    ``q_mm2``: per-tick process variance (sheet motion, encoder/structure error);
    ``r_mm2``: capacitive reading variance; ``p0_mm2``: variance assumed at (re)start.
    Off by default, as in the seed's ``UpdateLADRC`` (the filter was tried for tube-ridge
    chatter, not wired into the LADRC path).
    """

    PREFIX = 'kalman.'

    enabled: bool = param(False, '', 'fuse the gap reading with encoder increments in the '
                          'LADRC tick', seed='notes §4')
    q_mm2: float = param(1e-6, 'mm²', 'process variance per tick (sheet motion)',
                         gt=0.0, le=100.0, seed='notes §4')
    r_mm2: float = param(1e-4, 'mm²', 'variance of the capacitive reading',
                         gt=0.0, le=100.0, seed='notes §4')
    p0_mm2: float = param(1e-4, 'mm²', 'variance assumed at (re)start',
                          ge=0.0, le=100.0, seed='notes §4')
    gate_mm: float = param(0.0, 'mm', 'a reading wider than the prediction by more than this '
                           'is an outlier: the estimate coasts on the encoder (one-sided: a '
                           'closer reading is always taken; 0 = no gate, as the firmware)',
                           ge=0.0, le=20.0, seed='docs/estimators.md')
    gate_confirm_ticks: int = param(10, 'ticks', 'this many outliers in a row are a real '
                                    'change (an edge, a ridge): the filter restarts on the '
                                    'reading', ge=1, le=1000, seed='docs/estimators.md')
    on_pid: bool = param(False, '', 'feed the PID the fused gap too (the same filter, run by '
                         'the follow controller while the PID runs)', seed='notes §4')


def kalman_step(ops, x, p, z, dz_enc, q, r):
    """One predict/update step; returns ``(x, p, k)`` (notes §4 eqs. (1)-(5)).

    Predict x⁻ = x + Δenc, P⁻ = P + Q; gain K = P⁻/(P⁻ + R); update
    x = x⁻ + K(z − x⁻), P = (1 − K)P⁻.
    """
    xp = x + dz_enc
    pp = p + q
    k = pp / (pp + r)
    return xp + k * (z - xp), (1.0 - k) * pp, k


def kalman_gated_step(ops, x, p, n_out, z, dz_enc, fresh, q, r, p0, gate, confirm):
    """One step with the gate and coast rules; returns ``(x, p, k, n_out)``.

    * No new sample (``fresh`` false: a dropout, or a tick between samples): predict only,
      x = x + Δenc, P = P + Q (the estimate coasts on the encoder).
    * ``gate`` > 0 and z − x⁻ > gate: an outlier; the estimate coasts and ``n_out``
      counts it. ``confirm`` outliers in a row are a real change: restart on the reading
      (x = z, P = p0). One-sided on purpose: only a reading *wider* than the prediction is
      held back (trusting it would pull the nozzle down).
    * ``gate`` > 0 and x⁻ − z > gate: a reading *closer* than predicted by more than the gate
      restarts the filter on it at once: it can only send the nozzle up, and a slow
      convergence through a small gain would keep the estimate wider than the data.
    * Otherwise :func:`kalman_step`.

    ``ops`` is ``SCALAR`` (floats) or ``ARRAY`` (numpy rows; ``fresh`` a bool or bool rows).
    """
    xp = x + dz_enc  # predict (notes §4 eq. 1)
    pp = p + q
    k = pp / (pp + r)
    x_upd = xp + k * (z - xp)
    p_upd = (1.0 - k) * pp
    if ops is SCALAR:
        if not fresh:
            return xp, pp, 0.0, n_out
        if gate > 0.0 and z - xp > gate:
            if n_out + 1 >= confirm:
                return z, p0, 1.0, 0
            return xp, pp, 0.0, n_out + 1
        if gate > 0.0 and xp - z > gate:
            return z, p0, 1.0, 0
        return x_upd, p_upd, k, 0
    fresh = np.asarray(fresh, dtype=bool)
    outlier = fresh & (gate > 0.0) & (z - xp > gate)
    closer = fresh & (gate > 0.0) & (xp - z > gate)
    n_new = ops.where(outlier, n_out + 1, ops.where(fresh, 0, n_out))
    restart = (outlier & (n_new >= confirm)) | closer
    coast = ~fresh | (outlier & ~restart)
    return (ops.where(restart, z, ops.where(coast, xp, x_upd)),
            ops.where(restart, p0, ops.where(coast, pp, p_upd)),
            ops.where(restart, 1.0, ops.where(coast, 0.0, k)),
            ops.where(restart, 0, n_new))


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

    def __init__(self, params: KalmanParams = KalmanParams(), gate_mm: float = 0.5,
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
