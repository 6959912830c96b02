"""The matrix-form observers: the paper's linear ESO, for analysis (not on the tick path).

:class:`LinearESO` is the order-n linear ESO of paper eqs. 7-9 (with the compensator of eq. 22)
in matrix form, Euler or ZOH: the frequency-domain analysis of the observer (paper §4,
``ladrc_tools.offline.eso_frequency``) and :mod:`.loop` build on it. The tick composes the
scalar step functions of ``ladrc_follow.control.eso`` instead (one implementation per
discretization; tests/core/test_eso.py checks they agree).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..control.eso import (
    bandwidth_gains,
    check_betas,
    check_order,
    continuous_matrices,
    zoh_gains,
    zoh_gains_from_betas,
    zoh_matrices,
)


class LinearESO:
    """Order-n linear ESO in the paper's matrix form (numpy; for analysis and offline use).

    Give either ``w0_rad_s`` (bandwidth gains) or explicit ``betas``. ``discretization``
    is ``'euler'`` (the firmware's) or ``'zoh'`` (current estimator, gains from the
    continuous poles mapped by e^(λh)). With ``compensate=True`` :meth:`update` returns
    z' = z + D, D_i = β_{i−1}·e1 (β0 = 1, paper eq. 22).

    :meth:`update` returns the estimate at the sample time of ``y``: for Euler that is
    the state before the step (predicted last tick, plus D if compensating), after
    which the state advances to the prediction z(k+1), kept in :attr:`z`; for ZOH it is
    z(k|k) (plus D from the a-posteriori e1). Compensation of the ZOH form uses the
    continuous betas, an approximation valid for ω0·h ≪ 1.
    """

    def __init__(self, n: int, b0: float, h_s: float, w0_rad_s: float | None = None,
                 betas: Sequence[float] | None = None, discretization: str = 'euler',
                 compensate: bool = False):
        check_order(n)
        if (w0_rad_s is None) == (betas is None):
            raise ValueError('LinearESO: give exactly one of w0_rad_s (bandwidth tuning) or'
                             ' betas (explicit gains)')
        if not (h_s > 0.0):
            raise ValueError(f'LinearESO: h_s = {h_s} must be > 0 (seconds)')
        if discretization not in ('euler', 'zoh'):
            raise ValueError(f"LinearESO: discretization = {discretization!r}; use 'euler' or"
                             " 'zoh'")
        self.n, self.b0, self.h_s = n, float(b0), float(h_s)
        self.betas = bandwidth_gains(n, w0_rad_s) if betas is None else check_betas(n, betas)
        self.discretization = discretization
        self.compensate = compensate
        self.A, self.B, self.C, self.L, self.A_e = continuous_matrices(n, self.betas, b0)
        if discretization == 'zoh':
            self.phi, self.gamma = zoh_matrices(n, b0, h_s)
            if w0_rad_s is not None:
                self.l_c = np.array(zoh_gains(n, w0_rad_s, h_s))
            else:
                self.l_c = np.array(zoh_gains_from_betas(n, self.betas, h_s))
        self._d = np.array((1.0, *self.betas[:-1]))     # compensator weights, β0 = 1
        self.z = np.zeros(n + 1)

    def discrete_error_matrix(self) -> np.ndarray:
        """Error-dynamics matrix: I + h·A_e (euler) or (I − L_c C)·Φ (zoh)."""
        if self.discretization == 'euler':
            return np.eye(self.n + 1) + self.h_s * self.A_e
        return (np.eye(self.n + 1) - np.outer(self.l_c, self.C)) @ self.phi

    def reset(self, y0: float, rest: Sequence[float] | None = None) -> None:
        """Set z1 = y0 and the higher states to ``rest`` (zeros by default, as ``ESOInit``)."""
        self.z = np.zeros(self.n + 1)
        self.z[0] = y0
        if rest is not None:
            self.z[1:] = rest

    def update(self, y: float, u: float) -> np.ndarray:
        """Feed one sample (y, u); return the estimate at this sample time (see class doc)."""
        if self.discretization == 'euler':
            e1 = y - self.z[0]
            out = self.z + self._d * e1 if self.compensate else self.z.copy()
            self.z = self.z + self.h_s * (self.A @ self.z + self.B * u + self.L * e1)
            return out
        pred = self.phi @ self.z + self.gamma * u
        self.z = pred + self.l_c * (y - pred[0])
        if self.compensate:
            return self.z + self._d * (y - self.z[0])
        return self.z.copy()


# ---------------------------------------------------------------- helpers
