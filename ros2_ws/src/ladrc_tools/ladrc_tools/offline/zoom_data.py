"""The zoomable report's data, gathered on the report's one pass (bounded memory).

What is kept of each curve of the report's plots (one sample per ``follow/status`` tick):

* **every sample** (``raw``): the time, the measured gap, the true gap (``sim/truth``
  interpolated on the ticks, as the report does) and the velocity command sent;
* **change points** (``steps``): the target, the state and ``followed``; every change is kept,
  so these are exact too;
* **min/max pyramid** (``aux``): the TD reference, the unlimited command, the ESO states and
  the true gap rate, from buckets of ``4 ** aux_level`` samples up (:mod:`.pyramid`), where
  ``aux_level`` is the finest level whose buckets hold at most :data:`AUX_VALUES_MAX` values
  (every sample up to 400 000 ticks, 200 s at 2 kHz; 32 ms buckets on an hour).

Everything is encoded as it arrives (:mod:`.codec`: quantised to the curve's resolution,
delta-coded, zlib), so what is held is the compressed bytes and the pyramids' buckets, not
the samples. The page rebuilds the min/max levels of the raw curves from their samples
(the same rule, :func:`ladrc_tools.offline.pyramid.pyramid` with ``base_level=1``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Mapping

import numpy as np

from .codec import QuantEncoder, StepEncoder
from .pyramid import FACTOR, Pyramid

TIME_RES_S = 1e-6
"""The time axis is stored in microseconds (relative to the first tick, as the PNGs)."""
AUX_VALUES_MAX = 400_000
"""A pyramid-only curve keeps its finest level whose min/max values fit in this many."""


@dataclass(frozen=True)
class Curve:
    """One curve of the zoomable report: the report series' key, how it is stored."""

    key: str
    label: str
    unit: str
    res: float  # the resolution it is stored at, in its unit
    kind: str  # 'raw' (every sample), 'steps' (change points) or 'aux' (min/max pyramid)


CURVES = (
    Curve('gap_mm', 'measured gap', 'mm', 1e-4, 'raw'),  # 0.1 µm
    Curve('true_gap_mm', 'true gap', 'mm', 1e-4, 'raw'),
    Curve('velocity_mm_s', 'velocity sent', 'mm/s', 1e-3, 'raw'),  # 1 µm/s: the drive's unit
    Curve('target_mm', 'target', 'mm', 1e-4, 'steps'),
    Curve('state', 'state', '', 1.0, 'steps'),
    Curve('followed', 'followed', '', 1.0, 'steps'),
    Curve('td_x1_mm', 'TD reference x1', 'mm', 1e-4, 'aux'),
    Curve('u_unlimited_mm_s', 'unlimited command', 'mm/s', 1e-3, 'aux'),
    Curve('eso_z1_mm', 'ESO z1', 'mm', 1e-4, 'aux'),
    Curve('true_gap_rate', 'true gap rate', 'mm/s', 1e-3, 'aux'),
    Curve('eso_z2', 'ESO z2', 'mm/s', 1e-3, 'aux'),
    Curve('eso_z3', 'ESO z3', 'mm/s²', 1e-2, 'aux'),
)
CURVE = {c.key: c for c in CURVES}


def aux_level(n: int, values_max: int | None = None, factor: int = FACTOR) -> int:
    """Return the finest level a pyramid-only curve of ``n`` samples keeps (0: every sample).

    ``values_max``: default :data:`AUX_VALUES_MAX`.
    """
    values_max = AUX_VALUES_MAX if values_max is None else values_max
    if n <= values_max:
        return 0
    level = 1
    while 2 * math.ceil(n / factor ** level) > values_max:
        level += 1
    return level


@dataclass
class StoredCurve:
    """One curve as the page gets it: its streams (zlib bytes) and how to read them."""

    curve: Curve
    # raw: 'raw'; steps: 'index', 'value'; aux: 'raw', or 'levels' (one per level, finest first)
    streams: dict[str, bytes | list[bytes]]
    base_level: int = 0  # aux with levels: the finest level stored
    changes: int = 0  # steps: change points


@dataclass
class ZoomData:
    """Everything the page needs: the sample count, the time stream and the curves."""

    n: int
    time: bytes
    curves: dict[str, StoredCurve] = field(default_factory=dict)
    aux_level: int = 0
    factor: int = FACTOR


class ZoomRecorder:
    """Feed it the report's plot series a slice at a time (:meth:`add`); :meth:`finish`.

    ``n_expected``: the bag's tick count (``follow/status`` messages), which sets the
    pyramid-only curves' finest level; more or fewer samples only change the sizes.
    """

    def __init__(self, n_expected: int) -> None:
        self.aux_level = aux_level(max(0, int(n_expected)))
        self.n = 0
        self.time = QuantEncoder(TIME_RES_S)
        self.enc: dict[str, QuantEncoder | StepEncoder] = {}
        self.pyr: dict[str, Pyramid] = {}

    def _start(self, series: Mapping[str, np.ndarray]) -> None:
        for c in CURVES:
            if c.key not in series:
                continue
            if c.kind == 'steps':
                self.enc[c.key] = StepEncoder(c.res)
            elif c.kind == 'raw' or self.aux_level == 0:
                self.enc[c.key] = QuantEncoder(c.res)
            else:
                self.pyr[c.key] = Pyramid(self.aux_level)

    def add(self, series: Mapping[str, np.ndarray]) -> None:
        """Feed the next samples of the series (``t_s`` and the keys of :data:`CURVES`)."""
        t = np.asarray(series['t_s'], dtype=float)
        if t.size == 0:
            return
        if self.n == 0:
            self._start(series)
        self.time.add(t)
        for key, enc in self.enc.items():
            enc.add(np.asarray(series[key], dtype=float))
        for key, pyr in self.pyr.items():
            pyr.add(np.asarray(series[key], dtype=float))
        self.n += t.size

    def finish(self) -> ZoomData:
        """Return the encoded data (call once, at the end)."""
        data = ZoomData(self.n, self.time.finish(), aux_level=self.aux_level)
        for key, enc in self.enc.items():
            c = CURVE[key]
            if isinstance(enc, StepEncoder):
                index, value = enc.finish()
                data.curves[key] = StoredCurve(c, {'index': index, 'value': value},
                                               changes=enc.changes)
            else:
                data.curves[key] = StoredCurve(c, {'raw': enc.finish()})
        for key, pyr in self.pyr.items():
            c = CURVE[key]
            levels = []
            for lev in pyr.finish():
                e = QuantEncoder(c.res)
                e.add(lev.pairs())
                levels.append(e.finish())
            data.curves[key] = StoredCurve(c, {'levels': levels}, base_level=self.aux_level)
        order = [c.key for c in CURVES]
        data.curves = dict(sorted(data.curves.items(), key=lambda kv: order.index(kv[0])))
        return data
