"""The capacitive sensor against the encoder, from a run's own ticks: gain and noise.

What the calibration checks on a sweep (commissioning/calibration_table.py: the reading
regressed on the encoder, the residual's spread as the noise), taken from the motion a
production run makes anyway:

* gain: during each interpolated approach (``STATE_PREINTERPOLATE``, the nozzle coming down
  several mm over a sheet that hardly moves meanwhile) the reading's slope against the encoder,
  ``Σ Sxy / Σ Sxx`` over the approaches (each centred on its own means: a new sheet height per
  approach); 1 for a calibrated sensor, 0.9 for one that reads 10 % short;
* noise: while following (PID / LADRC), the reading minus ``gain ×`` encoder removes the axis'
  own motion; its change between consecutive samples is the sensor noise times √2 plus the
  sheet's motion in 0.5 ms (negligible), so ``noise = std(Δ) / √2`` over the Δ within 5
  robust sigmas (1.4826 MAD) of their median (the rare edge step left out). Only fresh
  samples (``gap_seq`` + 1) with a valid reading count.

Streaming: one slice of ``follow/status`` at a time (``add``), constant memory.
"""

from __future__ import annotations

import math
from typing import Any

from ladrc_contract.codes import FollowState
import numpy as np

APPROACH = int(FollowState.PREINTERPOLATE)
FOLLOWING = (int(FollowState.PID), int(FollowState.LADRC))
MIN_TRAVEL_MM = 1.0
"""An approach counts towards the gain when the encoder travelled at least this far."""
MAX_NOISE_SAMPLES = 200_000
"""The noise is the MAD of at most this many sample differences (a reservoir of the first)."""


class SensorCheck:
    """Accumulates the sensor gain and noise of one bag (``fields``, ``add``, ``result``)."""

    fields = {'follow/status': ('state', 'gap_mm', 'gap_valid', 'gap_seq', 'encoder_mm')}

    def __init__(self) -> None:
        self._seg: list[float] | None = None  # n, Σx, Σy, Σxx, Σxy, x_min, x_max of an approach
        self.sxx = 0.0
        self.sxy = 0.0
        self.approaches = 0
        self._prev: tuple[int, float, float, int] | None = None  # state, reading, enc, seq
        self._follow_rows: list[np.ndarray] = []  # reading, encoder of fresh following ticks
        self._n_follow = 0

    def add(self, part: dict[str, dict[str, np.ndarray]]) -> None:
        """Take one slice of the bag (``Bag.stream``)."""
        st = part.get('follow/status')
        if st is None or not st['state'].size:
            return
        state = st['state'].astype(int)
        r = st['gap_mm'].astype(float)
        z = st['encoder_mm'].astype(float)
        ok = st['gap_valid'].astype(bool) & np.isfinite(r) & np.isfinite(z)
        seq = st['gap_seq'].astype(np.int64)
        for i0, i1, s in _runs(state):
            if s == APPROACH:
                m = ok[i0:i1]
                self._approach(z[i0:i1][m], r[i0:i1][m])
            elif self._seg is not None:
                self._close()
        prev_seq = np.r_[self._prev[3] if self._prev else -2, seq[:-1]]
        fresh = ok & np.isin(state, FOLLOWING) & (seq == prev_seq + 1)
        if self._n_follow < MAX_NOISE_SAMPLES:
            # pairs: this fresh sample and the one before it (both valid, both following)
            prev_r = np.r_[self._prev[1] if self._prev else np.nan, r[:-1]]
            prev_z = np.r_[self._prev[2] if self._prev else np.nan, z[:-1]]
            prev_ok = np.r_[bool(self._prev and self._prev[0] in FOLLOWING), ok[:-1]
                            & np.isin(state[:-1], FOLLOWING)]
            pair = fresh & prev_ok & np.isfinite(prev_r)
            rows = np.c_[r[pair], z[pair], prev_r[pair], prev_z[pair]]
            self._follow_rows.append(rows[:MAX_NOISE_SAMPLES - self._n_follow])
            self._n_follow += len(self._follow_rows[-1])
        self._prev = (int(state[-1]), float(r[-1]), float(z[-1]), int(seq[-1]))

    def _approach(self, x: np.ndarray, y: np.ndarray) -> None:
        if not x.size:
            return
        seg = self._seg or [0.0, 0.0, 0.0, 0.0, 0.0, math.inf, -math.inf]
        seg[0] += x.size
        seg[1] += float(x.sum())
        seg[2] += float(y.sum())
        seg[3] += float(x @ x)
        seg[4] += float(x @ y)
        seg[5] = min(seg[5], float(x.min()))
        seg[6] = max(seg[6], float(x.max()))
        self._seg = seg

    def _close(self) -> None:
        n, sx, sy, sxx, sxy, lo, hi = self._seg
        self._seg = None
        if n < 3 or hi - lo < MIN_TRAVEL_MM:
            return
        self.sxx += sxx - sx * sx / n
        self.sxy += sxy - sx * sy / n
        self.approaches += 1

    def result(self) -> dict[str, Any]:
        """Return ``sensor_gain``, ``sensor_noise_mm`` (NaN: no data) and what they rest on."""
        if self._seg is not None:
            self._close()
        gain = self.sxy / self.sxx if self.sxx > 0.0 else math.nan
        noise = math.nan
        if self._n_follow >= 20:
            rows = np.concatenate(self._follow_rows)
            g = gain if math.isfinite(gain) else 1.0
            d = (rows[:, 0] - g * rows[:, 1]) - (rows[:, 2] - g * rows[:, 3])
            dev = np.abs(d - np.median(d))
            # the MAD only bounds the outliers out (the 1 µm steps of a quantized reading make
            # the MAD itself coarse); the noise is the spread of what is left
            sigma = max(1.4826 * float(np.median(dev)), float(np.std(d)) * 0.1, 1e-9)
            noise = float(np.std(d[dev <= 5.0 * sigma]) / math.sqrt(2.0))
        return {'sensor_gain': gain, 'sensor_noise_mm': noise,
                'gain_approaches': self.approaches, 'noise_samples': self._n_follow}


def _runs(values: np.ndarray) -> list[tuple[int, int, int]]:
    """Return ``(start, stop, value)`` of each run of equal values."""
    cut = np.flatnonzero(np.diff(values)) + 1
    starts = np.r_[0, cut]
    stops = np.r_[cut, values.size]
    return [(int(a), int(b), int(values[a])) for a, b in zip(starts, stops, strict=True)]
