"""Nonlinear gain functions of ADRC (notes §6, paper eq. 6) and their lookup tables.

Every function takes an ``ops`` backend first (``SCALAR`` or ``ARRAY``) so one
implementation serves the 2 kHz scalar path and numpy batches. All functions are
odd (f(-e) = -f(e)) and pass through 0 with a finite slope, the property the ESO
convergence argument needs (paper §1: e·g(e) > 0 for e != 0, g(0) = 0).

The notes name the family (Fal, Sat, Sigmoid, Atan, Asinh, Sinh) but give a formula
only for fal; the others are the usual textbook forms, each with one shape gain
``a`` (slope at 0 is ``a`` except for ``sigmoid``, whose slope is ``a/2``).

The firmware evaluated these by table lookup to save cycles (notes §1, last paragraph);
:class:`LookupTable` reproduces that choice and reports its interpolation error.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Callable

from ladrc_contract.ops import ARRAY, SCALAR
import numpy as np


def fal(ops, e, alpha, delta):
    """Han's fal function (paper eq. 6, notes §6.2).

    ``|e|**alpha * sign(e)`` for ``|e| > delta``, ``e / delta**(1 - alpha)`` inside the
    linear zone ``|e| <= delta`` (continuous at ``|e| = delta``). ``alpha`` in (0, 1]
    sets the nonlinearity ("large error, small gain; small error, large gain"),
    ``delta > 0`` the half-width of the linear zone that avoids chattering at 0.
    """
    mag = ops.abs(e)
    outer = ops.power(mag, alpha) * ops.sign(e)
    inner = e / ops.power(delta, 1.0 - alpha)
    return ops.where(mag > delta, outer, inner)


def sat(ops, e, delta):
    """Saturation: ``e / delta`` clipped to [-1, 1] (notes §6.2 ``sat(x, δ)``)."""
    return ops.clip(e / delta, -1.0, 1.0)


def sigmoid(ops, e, a=1.0):
    """Improved sigmoid, the odd form centred at 0: ``2 / (1 + exp(-a e)) - 1``.

    Range (-1, 1), slope ``a/2`` at 0; equal to ``tanh(a e / 2)``. Evaluated as
    ``sign(e) (1 - E) / (1 + E)`` with ``E = exp(-a |e|)`` so it never overflows.
    """
    big = ops.exp(-a * ops.abs(e))
    return ops.sign(e) * (1.0 - big) / (1.0 + big)


def tanh_fn(ops, e, a=1.0):
    """``tanh(a e)``, built from ``exp`` so scalar and batch agree bit for bit."""
    big = ops.exp(-2.0 * a * ops.abs(e))
    return ops.sign(e) * (1.0 - big) / (1.0 + big)


def atan_fn(ops, e, a=1.0):
    """``atan(a e)``: range (-π/2, π/2), slope ``a`` at 0."""
    return ops.arctan(a * e)


def asinh_fn(ops, e, a=1.0):
    """``asinh(a e)``: unbounded but only logarithmic growth, slope ``a`` at 0."""
    return ops.arcsinh(a * e)


def sinh_fn(ops, e, a=1.0):
    """``sinh(a e)``: gain grows with the error (the opposite of fal), slope ``a`` at 0."""
    return ops.sinh(a * e)


_EXTRAPOLATE = ('clamp', 'linear')


@dataclass
class LookupTable:
    """A function tabulated on a uniform grid over ``[lo, hi]``, linearly interpolated.

    The firmware's way to evaluate the nonlinear functions (notes §1). With
    ``odd=True`` only ``[0, hi]`` is tabulated (``lo`` must be ``-hi``) and
    ``f(-x) = -f(x)`` is applied, which halves the grid spacing for the same
    number of entries. Outside the range: ``'clamp'`` holds the end value (right
    for saturating functions: sat, sigmoid, tanh, atan), ``'linear'`` continues the
    last segment's slope (for unbounded ones: fal, asinh, sinh).
    """

    fn: Callable[[np.ndarray], np.ndarray]
    lo: float
    hi: float
    size: int = 257
    odd: bool = False
    extrapolate: str = 'clamp'
    _x0: float = field(init=False, repr=False)
    _dx: float = field(init=False, repr=False)
    _table: np.ndarray = field(init=False, repr=False)
    _list: list = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lo) and math.isfinite(self.hi) and self.hi > self.lo):
            raise ValueError(f'LookupTable range [{self.lo}, {self.hi}] must be finite with'
                             ' hi > lo')
        if self.size < 2:
            raise ValueError(f'LookupTable size = {self.size}: need at least 2 entries to'
                             ' interpolate')
        if self.extrapolate not in _EXTRAPOLATE:
            raise ValueError(f'LookupTable extrapolate = {self.extrapolate!r}: use one of'
                             f' {_EXTRAPOLATE}')
        if self.odd and not math.isclose(self.lo, -self.hi):
            raise ValueError(f'odd LookupTable needs a symmetric range, got [{self.lo},'
                             f' {self.hi}]')
        self._x0 = 0.0 if self.odd else float(self.lo)
        self._dx = (float(self.hi) - self._x0) / (self.size - 1)
        grid = self._x0 + self._dx * np.arange(self.size)
        self._table = np.asarray(self.fn(grid), dtype=float)
        if self.odd:
            self._table[0] = 0.0
        self._list = self._table.tolist()

    def _eval_scalar(self, x: float) -> float:
        neg = self.odd and x < 0.0
        if neg:
            x = -x
        pos = (x - self._x0) / self._dx
        last = self.size - 1
        if pos <= 0.0 or pos >= last:
            if self.extrapolate == 'clamp':
                y = self._list[0] if pos <= 0.0 else self._list[last]
            else:
                i = 0 if pos <= 0.0 else last - 1
                y = self._list[i] + (pos - i) * (self._list[i + 1] - self._list[i])
        else:
            i = int(pos)
            y = self._list[i] + (pos - i) * (self._list[i + 1] - self._list[i])
        return -y if neg else y

    def _eval_array(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        sgn = np.where(x < 0.0, -1.0, 1.0) if self.odd else 1.0
        ax = np.abs(x) if self.odd else x
        pos = (ax - self._x0) / self._dx
        last = self.size - 1
        if self.extrapolate == 'clamp':
            pos = np.clip(pos, 0.0, last)
        i = np.clip(np.floor(pos), 0, last - 1).astype(int)
        t = self._table
        return sgn * (t[i] + (pos - i) * (t[i + 1] - t[i]))

    def __call__(self, x):
        """Interpolate at ``x`` (a float or a numpy array)."""
        if isinstance(x, np.ndarray):
            return self._eval_array(x)
        return self._eval_scalar(float(x))

    def max_error(self, exact: Callable | None = None, points_per_cell: int = 64) -> float:
        """Largest ``|table(x) - exact(x)|`` on a dense grid over ``[lo, hi]``.

        ``exact`` defaults to the tabulated function. The grid has
        ``points_per_cell`` points per table cell (so it hits between the nodes,
        where linear interpolation is worst).
        """
        exact = self.fn if exact is None else exact
        n = (self.size - 1) * points_per_cell * (2 if self.odd else 1) + 1
        x = np.linspace(self.lo, self.hi, n)
        return float(np.max(np.abs(self._eval_array(x) - np.asarray(exact(x)))))


DEFAULT_TABLE_SIZE = 257
"""Entries per table (2^8 + 1: a power-of-two number of cells, as a firmware would use)."""


__all__ = [
    'ARRAY', 'DEFAULT_TABLE_SIZE', 'LookupTable', 'SCALAR', 'asinh_fn', 'atan_fn',
    'fal', 'sat', 'sigmoid', 'sinh_fn', 'tanh_fn',
]
