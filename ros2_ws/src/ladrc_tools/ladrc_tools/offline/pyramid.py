"""Min/max decimation pyramid of a long series, built in one streaming pass (the HTML report).

Level ``L`` cuts the series into buckets of ``factor ** L`` consecutive samples, aligned on
sample 0 (the last bucket may be shorter), and keeps each bucket's minimum and maximum and
which of the two came first. Each level is ``factor`` (4) times coarser than the one below
it, and is built from it: a bucket's min is the min of its children's mins (NaN ignored, as
``np.nanmin``), the first child holding it is where it occurred, so the order is that of the
samples themselves. A sample that is the extreme of its bucket is therefore kept at every
level: a 2 ms spike in an hour shows at any zoom.

A viewer draws each bucket as two points, the extremes in the order they occurred
(:meth:`PyramidLevel.pairs`): with at most a few buckets per pixel that is the picture of
every sample (the M4 / min-max rule), whatever the zoom. Memory: two floats and a flag per
bucket of each level kept (``base_level`` and up); the samples themselves are not held.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import warnings

import numpy as np

FACTOR = 4
"""Each level is this many times coarser than the level below."""
TOP_BUCKETS = 1024
"""Levels are kept up to the first one with at most this many buckets (the whole view)."""
MAX_LEVELS = 24
"""Levels built above the base (4 ** 24 samples per bucket: far beyond any bag)."""


@dataclass
class PyramidLevel:
    """One level: per bucket the min, the max and whether the max came first."""

    level: int
    samples: int  # samples per bucket (the last bucket may hold fewer)
    lo: np.ndarray
    hi: np.ndarray
    max_first: np.ndarray

    @property
    def buckets(self) -> int:
        """Return the number of buckets."""
        return int(self.lo.size)

    def pairs(self) -> np.ndarray:
        """Return the two extremes of every bucket in the order they occurred, interleaved."""
        first = np.where(self.max_first, self.hi, self.lo)
        second = np.where(self.max_first, self.lo, self.hi)
        return np.column_stack([first, second]).ravel()


def bucket_extremes(y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return ``(lo, hi, max_first)`` of the rows of ``y`` (buckets x samples), NaN ignored.

    The first occurrence of the min and of the max decides the order; an all-NaN row gives
    NaN and ``False``.
    """
    a = np.where(np.isnan(y), np.inf, y)
    b = np.where(np.isnan(y), -np.inf, y)
    ilo, ihi = np.argmin(a, axis=1), np.argmax(b, axis=1)
    rows = np.arange(y.shape[0])
    lo, hi = a[rows, ilo], b[rows, ihi]
    empty = np.isnan(y).all(axis=1)
    lo[empty] = np.nan
    hi[empty] = np.nan
    return lo, hi, (ihi < ilo) & ~empty


def merge_extremes(lo: np.ndarray, hi: np.ndarray, max_first: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the extremes of groups of buckets (rows of children: groups x factor)."""
    a = np.where(np.isnan(lo), np.inf, lo)
    b = np.where(np.isnan(hi), -np.inf, hi)
    ilo, ihi = np.argmin(a, axis=1), np.argmax(b, axis=1)
    rows = np.arange(lo.shape[0])
    out_lo, out_hi = a[rows, ilo], b[rows, ihi]
    empty = np.isnan(lo).all(axis=1)
    out_lo[empty] = np.nan
    out_hi[empty] = np.nan
    mf = np.where(ilo == ihi, max_first[rows, ilo], ihi < ilo) & ~empty
    return out_lo, out_hi, mf


@dataclass
class _Builder:
    """The buckets of one level so far, and its children still waiting for their group."""

    lo: list[np.ndarray] = field(default_factory=list)
    hi: list[np.ndarray] = field(default_factory=list)
    mf: list[np.ndarray] = field(default_factory=list)
    wait: tuple[np.ndarray, np.ndarray, np.ndarray] = (np.zeros(0), np.zeros(0),
                                                       np.zeros(0, dtype=bool))
    count: int = 0


class Pyramid:
    """Min/max levels ``base_level`` .. of a series fed in slices (:meth:`add`, :meth:`finish`).

    ``base_level`` 0 keeps the samples themselves as the finest level (buckets of one).
    """

    def __init__(self, base_level: int = 1, factor: int = FACTOR,
                 top_buckets: int = TOP_BUCKETS) -> None:
        if base_level < 0 or factor < 2:
            raise ValueError('base_level >= 0 and factor >= 2')
        self.base_level, self.factor, self.top_buckets = base_level, factor, top_buckets
        self.base_samples = factor ** base_level
        self.n = 0
        self._raw = np.zeros(0)  # fewer than base_samples samples not yet in a bucket
        self._levels = [_Builder() for _ in range(MAX_LEVELS + 1)]
        self._done: list[PyramidLevel] | None = None

    def add(self, y: np.ndarray) -> None:
        """Feed the next samples."""
        y = np.asarray(y, dtype=float)
        if y.size == 0:
            return
        self.n += y.size
        buf = np.concatenate((self._raw, y)) if self._raw.size else y
        s = self.base_samples
        m = buf.size // s * s
        self._raw = buf[m:].copy()
        if m:
            with warnings.catch_warnings():
                warnings.simplefilter('ignore', RuntimeWarning)
                self._push(0, *bucket_extremes(buf[:m].reshape(-1, s)))

    def _push(self, k: int, lo: np.ndarray, hi: np.ndarray, mf: np.ndarray,
              final: bool = False) -> None:
        """Append buckets to level ``base + k`` and build the coarser ones from them."""
        lev = self._levels[k]
        lev.lo.append(lo)
        lev.hi.append(hi)
        lev.mf.append(mf)
        lev.count += lo.size
        if k == MAX_LEVELS:
            return
        wl, wh, wm = (np.concatenate((w, x)) for w, x in zip(lev.wait, (lo, hi, mf), strict=True))
        f = self.factor
        m = wl.size if final else wl.size // f * f
        full = wl.size // f * f
        lev.wait = (wl[m:], wh[m:], wm[m:])
        if full:
            self._push(k + 1, *merge_extremes(wl[:full].reshape(-1, f), wh[:full].reshape(-1, f),
                                              wm[:full].reshape(-1, f)), final=False)
        if final:
            if m > full:  # the last, shorter group
                self._push(k + 1, *merge_extremes(wl[full:m][None], wh[full:m][None],
                                                  wm[full:m][None]), final=True)
            elif k + 1 <= MAX_LEVELS:
                self._push(k + 1, np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool), final=True)

    def finish(self) -> list[PyramidLevel]:
        """Return the levels, finest first, up to the first with <= ``top_buckets`` buckets."""
        if self._done is not None:
            return self._done
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', RuntimeWarning)
            if self._raw.size:
                self._push(0, *bucket_extremes(self._raw[None]), final=True)
            else:
                self._push(0, np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool), final=True)
        self._raw = np.zeros(0)
        out = []
        for k, lev in enumerate(self._levels):
            out.append(PyramidLevel(
                self.base_level + k, self.base_samples * self.factor ** k,
                np.concatenate(lev.lo), np.concatenate(lev.hi), np.concatenate(lev.mf)))
            if lev.count <= self.top_buckets:
                break
        self._levels = []
        self._done = out
        return out


def pyramid(y: np.ndarray, base_level: int = 1, factor: int = FACTOR,
            top_buckets: int = TOP_BUCKETS) -> list[PyramidLevel]:
    """Return the levels of a series held whole (:class:`Pyramid` in one slice)."""
    p = Pyramid(base_level, factor, top_buckets)
    p.add(y)
    return p.finish()
