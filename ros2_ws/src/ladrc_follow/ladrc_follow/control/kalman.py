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

from ladrc_contract.ops import SCALAR
from ladrc_contract.schema import Section, param
import numpy as np


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


