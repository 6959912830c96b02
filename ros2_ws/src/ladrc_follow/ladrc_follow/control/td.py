"""Equivalent-linear and compound tracking differentiators (notes §2, ``ELDT.c``).

Continuous form (notes §2.1, "General-Forward-Form")::

    x1' = x2
    x2' = R²·(−k1·(x1 − v) − k2·x2/R) + α·v'

so x1/v = (α s + k1 R²) / (s² + k2 R s + k1 R²): natural frequency ωn = R·√k1,
damping ξ = k2 / (2√k1); with α = k2·R a ramp is tracked without lag.

Mapping of the firmware's integers (``ELDTrackerCalc``, ``SAMPLE_PERIOD 2000``), line by line:

* ``nTracker = (nTracker*2000 + nDiff)/2000`` → x1 += h·x2 with h = 1/2000 s = 0.5 ms, so
  ``nDiff`` is x2 in UnitP **per second**.
* ``-k1*err_1/10`` → the float k1 is ``k1_int / 10``.
* ``k2*nDiff/10/R`` → k2·x2/R with the float k2 ``k2_int / 10`` and R = ``R_int`` in 1/s.
* ``(…)*R*R/2000`` → h·R²·(…).
* ``+ a*(nFowardIn_ − nForwardIn)`` is **commented out**: the firmware's Fc is unused, so its
  "compound" TD is just TDB. In the notes' MATLAB sets the fourth number is α itself
  (``TDA: 2.2,1.3,30,15`` for the C ints 22,13,30,15): α = ``Fc_int`` in 1/s, not Fc/10
  (α = 1.5 would be negligible next to k2·R = 39; α = 15 removes 38 % of the ramp lag).

The TD is linear and homogeneous, so the size of UnitP does not enter: x1 in mm and
x2 in mm/s once the reference is in mm.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

from ladrc_contract.schema import Section, field_problems, param
import numpy as np

SAMPLE_PERIOD_S = 1.0 / 2000.0
"""The firmware's ``SAMPLE_PERIOD 2000`` (ticks per second): h = 0.5 ms."""


@dataclass(frozen=True)
class TDParams(Section):
    """Parameters of one equivalent-linear TD (notes §2.1).

    ``k1`` and ``k2`` are dimensionless, ``r_per_s`` is the speed factor R in 1/s and
    ``alpha`` the feed-forward coefficient α in 1/s (α·Δv is added to x2 each step).
    """

    k1: float = param(unit='1', description='position stiffness k1 (firmware int / 10)',
                      gt=0.0, le=1000.0, seed='notes §2.1')
    k2: float = param(unit='1', description='damping coefficient k2 (firmware int / 10)',
                      gt=0.0, le=1000.0, seed='notes §2.1')
    r_per_s: float = param(unit='1/s', description='speed factor R; ωn = R·√k1',
                           gt=0.0, le=2000.0, seed='notes §2.1')
    alpha: float = param(0.0, '1/s', 'feed-forward coefficient α of the reference increment',
                         ge=0.0, le=1000.0, seed='notes §2.1')

    @property
    def natural_frequency_rad_s(self) -> float:
        """ωn = R·√k1 of x1/v (notes §2.1)."""
        return self.r_per_s * math.sqrt(self.k1)

    @property
    def damping(self) -> float:
        """ξ = k2 / (2√k1) of x1/v (notes §2.1)."""
        return self.k2 / (2.0 * math.sqrt(self.k1))

    def problems(self, h_s: float | None = None, prefix: str = 'td.') -> list[str]:
        """Readable reasons why these parameters cannot run; empty when valid.

        With ``h_s`` the discrete (firmware-order) step is also checked for stability.
        """
        out = field_problems(self, prefix)
        if not out and h_s is not None:
            if not (h_s > 0.0):
                out.append(f'h_s = {h_s}: the sample period must be > 0')
            else:
                rho = max(abs(np.linalg.eigvals(td_discrete_matrix(self, h_s))))
                if rho >= 1.0:
                    out.append(f'{prefix.rstrip(".")}: ωn = {self.natural_frequency_rad_s:.4g}'
                               f' rad/s is unstable at h = {h_s} s (spectral radius '
                               f'{rho:.4f} >= 1); lower R')
        return out


def td_step_firmware(ops, x1, x2, v, dv, k1, k2, r, alpha, h_s):
    """One step in ``ELDTrackerCalc``'s order: x1 first, then x2 from the **new** x1.

    This is semi-implicit (symplectic) Euler. It is the default of the compound TD
    because (1) it is what ran on the machine and was measured, and (2) it is the
    better discretization: the discrete determinant is 1 − h·k2·R, independent of
    k1, so it stays stable for larger ωn·h than explicit Euler (whose determinant
    1 − h·k2·R + h²·k1·R² exceeds 1 when lightly damped). Both agree to O(h).
    The firmware's α term is commented out; here it is applied as the notes write it.
    """
    x1n = x1 + h_s * x2
    f = -k1 * (x1n - v) - k2 * x2 / r
    return x1n, x2 + h_s * r * r * f + alpha * dv


def td_discrete_matrix(p: TDParams, h_s: float, firmware_order: bool = True) -> np.ndarray:
    """State matrix of one step (v = 0), for stability checks."""
    a = h_s * p.r_per_s ** 2 * p.k1
    b = h_s * p.r_per_s * p.k2
    if firmware_order:
        return np.array([[1.0, h_s], [-a, 1.0 - b - a * h_s]])
    return np.array([[1.0, h_s], [-a, 1.0 - b]])


# Seed defaults (CompELDTInit): ints (k1, k2, R, Fc) = (22, 13, 30, 15) and (12, 40, 100, 0).
TDA_FIRMWARE = TDParams(k1=2.2, k2=1.3, r_per_s=30.0, alpha=15.0)
TDB_FIRMWARE = TDParams(k1=1.2, k2=4.0, r_per_s=100.0, alpha=0.0)


