"""Plot decimation of long series: the min/max envelope of time buckets, fed in slices.

A figure 11 inches wide at 110 dpi has about 1 200 pixel columns, so an hour at 2 kHz
(7.2 M points) and its envelope of 2 x 5 000 points draw the same picture; matplotlib's time
and memory then no longer grow with the bag's length, and neither does the envelope's: it
holds two numbers per bucket and series, whatever the length fed.
"""

from __future__ import annotations

from typing import Mapping
import warnings

import numpy as np

PLOT_BUCKETS = 5000
"""A longer run is drawn as the min/max envelope of this many time buckets."""


class Envelope:
    """Min and max of each of ``buckets`` equal index ranges of ``n`` samples, fed in slices.

    Every series fed must have the same length per :meth:`add`; ``time_key`` (``t_s``) keeps
    each bucket's first and last sample instead. Up to ``2 * buckets`` samples are kept as
    they are. Fewer samples than ``n`` leave the untouched buckets out; more land in the
    last bucket.
    """

    def __init__(self, n: int, buckets: int = PLOT_BUCKETS, time_key: str = 't_s') -> None:
        self.n, self.time_key = n, time_key
        self.exact = n <= 2 * buckets
        self.starts = np.linspace(0, n, buckets + 1).astype(np.int64)[:-1]
        self.pos = 0
        self.lo: dict[str, np.ndarray] = {}
        self.hi: dict[str, np.ndarray] = {}
        self.kept: dict[str, list[np.ndarray]] = {}
        self.touched = np.zeros(buckets, dtype=bool)

    def add(self, series: Mapping[str, np.ndarray]) -> None:
        """Feed the next samples of every series."""
        m = len(next(iter(series.values()))) if series else 0
        if m == 0:
            return
        a = self.pos
        self.pos += m
        if self.exact:
            for key, y in series.items():
                self.kept.setdefault(key, []).append(np.asarray(y))
            return
        k0 = int(np.searchsorted(self.starts, a, 'right')) - 1
        k1 = int(np.searchsorted(self.starts, a + m - 1, 'right')) - 1
        local = np.maximum(self.starts[k0:k1 + 1], a) - a  # bucket starts in this slice
        last = np.r_[local[1:] - 1, m - 1]
        first_here = self.starts[k0:k1 + 1] >= a
        self.touched[k0:k1 + 1] = True
        nb = self.starts.size
        with np.errstate(invalid='ignore'), warnings.catch_warnings():
            warnings.simplefilter('ignore', RuntimeWarning)  # all-NaN buckets stay NaN
            for key, y in series.items():
                y = np.asarray(y, dtype=float)
                lo = self.lo.setdefault(key, np.full(nb, np.nan))
                hi = self.hi.setdefault(key, np.full(nb, np.nan))
                if key == self.time_key:  # first and last sample of each bucket
                    lo[k0:k1 + 1][first_here] = y[local[first_here]]
                    hi[k0:k1 + 1] = y[last]
                    continue
                lo[k0:k1 + 1] = np.fmin(lo[k0:k1 + 1], np.fmin.reduceat(y, local))
                hi[k0:k1 + 1] = np.fmax(hi[k0:k1 + 1], np.fmax.reduceat(y, local))

    def result(self) -> dict[str, np.ndarray]:
        """Return the series (short runs) or their envelopes: lo, hi of each bucket in turn."""
        if self.exact:
            return {k: v[0] if len(v) == 1 else np.concatenate(v) for k, v in self.kept.items()}
        keep = self.touched
        return {k: np.column_stack([self.lo[k][keep], self.hi[k][keep]]).ravel()
                for k in self.lo}


def envelope(series: dict[str, np.ndarray], buckets: int = PLOT_BUCKETS
             ) -> dict[str, np.ndarray]:
    """Decimate equal-length series held whole (:class:`Envelope` in one slice).

    Short runs (up to ``2 * buckets`` samples) are returned as they are.
    """
    n = len(series['t_s'])
    if n <= 2 * buckets:
        return series
    env = Envelope(n, buckets)
    env.add(series)
    return env.result()
