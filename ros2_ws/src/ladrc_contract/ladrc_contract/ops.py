"""Scalar and array arithmetic backends, so each algorithm is written once.

Every step function of the control core, and the simulator models' steps that the batch
closed loop runs on rows, is written with plain arithmetic operators plus the few functions
below, taken from an ``ops`` argument (here, in the contract, because the simulator may not
import the controller). With
:data:`SCALAR` the same code runs on Python floats (fast for one controller per
2 kHz tick); with :data:`ARRAY` it runs on numpy arrays (N parameter sets at
once for sweeps). IEEE-754 ``+ - * /`` and ``sqrt`` are correctly rounded in
both, so a batch of one equals the scalar path bit for bit.
"""

from __future__ import annotations

import math

import numpy as np


class ScalarOps:
    """Functions on Python floats (the per-tick path)."""

    @staticmethod
    def clip(x: float, lo: float, hi: float) -> float:
        """Clamp ``x`` into ``[lo, hi]``."""
        return lo if x < lo else (hi if x > hi else x)

    @staticmethod
    def where(cond: bool, a: float, b: float) -> float:
        """Return ``a`` where ``cond`` holds, else ``b``."""
        return a if cond else b

    abs = staticmethod(abs)
    sqrt = staticmethod(math.sqrt)
    minimum = staticmethod(min)
    maximum = staticmethod(max)

    @staticmethod
    def sign(x: float) -> float:
        """Return -1.0, 0.0 or 1.0 (0 at 0, as numpy.sign); numpy scalars too."""
        return float(x > 0.0) - float(x < 0.0)

    @staticmethod
    def floor_index(x: float, last: int) -> int:
        """``int(x)`` (x >= 0: its floor) capped at ``last``: an index into a table."""
        k = int(x)
        return last if k > last else k

    @staticmethod
    def power(x: float, y: float) -> float:
        """``x ** y`` for ``x >= 0``."""
        return x ** y

    # Added for the nonlinear functions (nonlinear.py, notes §6). tanh is deliberately
    # absent: numpy's SIMD tanh differs from libm's in the last bit, so nonlinear.py
    # builds it from exp (identical in both) to keep batch == scalar bit for bit.
    exp = staticmethod(math.exp)
    arctan = staticmethod(math.atan)
    arcsinh = staticmethod(math.asinh)
    sinh = staticmethod(math.sinh)


class ArrayOps:
    """The same functions on numpy arrays (the batch path)."""

    clip = staticmethod(np.clip)
    where = staticmethod(np.where)
    abs = staticmethod(np.abs)
    sqrt = staticmethod(np.sqrt)
    minimum = staticmethod(np.minimum)
    maximum = staticmethod(np.maximum)
    sign = staticmethod(np.sign)

    @staticmethod
    def floor_index(x: np.ndarray, last: int) -> np.ndarray:
        """Return the same on rows: truncated to int64 (x >= 0: the floor), capped at ``last``."""
        return np.minimum(x.astype(np.int64), last)

    @staticmethod
    def power(x: np.ndarray, y) -> np.ndarray:
        """``x ** y`` element by element with libm's pow, as the scalar path.

        numpy's SIMD power differs from libm's in the last bit for some inputs (seen on
        AVX-512), which would break batch == scalar; fal (the only user) is off the hot path.
        """
        return np.asarray(_POW(x, y), dtype=float)
    exp = staticmethod(np.exp)
    arctan = staticmethod(np.arctan)
    arcsinh = staticmethod(np.arcsinh)
    sinh = staticmethod(np.sinh)


_POW = np.frompyfunc(math.pow, 2, 1)
SCALAR = ScalarOps()
ARRAY = ArrayOps()
