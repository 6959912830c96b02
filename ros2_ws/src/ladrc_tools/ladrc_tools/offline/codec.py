"""Compact streams of long series for the HTML report: quantised, delta-coded, zlib, fed in slices.

A series of floats is stored at a fixed resolution (the gap in 0.1 µm, a velocity in 1 µm/s:
:data:`ladrc_tools.offline.zoom_data.CURVES`) as integers ``q = round(y / res)``; the
integers are written as blocks of at most :data:`BLOCK` samples, each block as varints
(LEB128) of the zigzagged differences of order 1 or 2 (whichever sums smaller in that block),
divided by their greatest common divisor (a sensor that reads in 1 µm steps stored in 0.1 µm
units costs no more than in 1 µm units), and the varints go through one zlib stream per
series. The browser inflates it with ``DecompressionStream('deflate')`` (zlib's format).

Block layout (all varints; the differences continue across blocks, carried from the last two
values of the previous block, 0 before the first)::

    count  order  gcd  runs  (start length kind) * runs  zigzag(d / gcd) * count

``runs`` lists the block's non-finite samples (``kind`` 1 NaN, 2 +inf, 3 -inf; a value beyond
:data:`LIMIT` resolution steps is stored as an infinity of its sign); such a sample is
coded as the last finite value before it (a zero difference). Decoded, a sample is
``q * res``: bit for bit ``np.round(y / res) * res`` of the value fed.

:class:`StepEncoder` stores a series that changes rarely (the target, the state) as its change
points: the sample indices (resolution 1) and the values there, two such streams.
"""

from __future__ import annotations

from dataclasses import dataclass
import zlib

import numpy as np

BLOCK = 65536
"""At most this many samples per block (the order and the divisor are chosen per block)."""
LIMIT = float(2 ** 50)
"""Values beyond this many resolution steps are stored as infinities (JS numbers stay exact)."""
KIND_FINITE, KIND_NAN, KIND_POS_INF, KIND_NEG_INF = 0, 1, 2, 3


def varint(values: np.ndarray) -> bytes:
    """Return the LEB128 bytes of non-negative integers (uint64), vectorised."""
    z = np.asarray(values, dtype=np.uint64)
    if z.size == 0:
        return b''
    nbytes = np.ones(z.size, dtype=np.int64)
    top = int(z.max())
    for k in range(1, 10):
        if top < 1 << (7 * k):
            break
        nbytes += z >= np.uint64(1 << (7 * k))
    ends = np.cumsum(nbytes)
    out = np.empty(int(ends[-1]), dtype=np.uint8)
    starts = ends - nbytes
    for j in range(int(nbytes.max())):
        m = nbytes > j
        byte = ((z[m] >> np.uint64(7 * j)) & np.uint64(0x7F)).astype(np.uint8)
        byte |= np.where(nbytes[m] > j + 1, 0x80, 0).astype(np.uint8)
        out[starts[m] + j] = byte
    return out.tobytes()


def unvarint(data: bytes) -> np.ndarray:
    """Return the integers (uint64) of LEB128 bytes, vectorised (the inverse of :func:`varint`)."""
    b = np.frombuffer(data, dtype=np.uint8)
    if b.size == 0:
        return np.zeros(0, dtype=np.uint64)
    ends = np.flatnonzero(b < 0x80)
    if ends.size == 0 or ends[-1] != b.size - 1:
        raise ValueError('varint stream ends inside a value')
    starts = np.r_[0, ends[:-1] + 1]
    pos = np.arange(b.size) - np.repeat(starts, ends - starts + 1)
    parts = (b & 0x7F).astype(np.uint64) << (np.uint64(7) * pos.astype(np.uint64))
    return np.add.reduceat(parts, starts)


def zigzag(d: np.ndarray) -> np.ndarray:
    """Map signed integers to unsigned ones, small magnitudes to small numbers."""
    d = d.astype(np.int64)
    return ((d << 1) ^ (d >> 63)).astype(np.uint64)


def unzigzag(z: np.ndarray) -> np.ndarray:
    """Inverse of :func:`zigzag`."""
    z = z.astype(np.uint64)
    return ((z >> np.uint64(1)).astype(np.int64) ^ -(z & np.uint64(1)).astype(np.int64))


def quantise(y: np.ndarray, res: float) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(q, kind)``: ``round(y / res)`` as int64 (0 where not finite) and the kinds."""
    with np.errstate(invalid='ignore', over='ignore'):
        s = np.asarray(y, dtype=float) / res
        if s.size and np.abs(s).max() <= LIMIT:  # all finite and in range (NaN fails the test)
            return np.rint(s).astype(np.int64), np.zeros(s.size, dtype=np.int64)
        kind = np.zeros(s.size, dtype=np.int64)
        kind[np.isnan(s)] = KIND_NAN
        kind[s > LIMIT] = KIND_POS_INF
        kind[s < -LIMIT] = KIND_NEG_INF
        q = np.where(kind == KIND_FINITE, np.round(s), 0.0).astype(np.int64)
    return q, kind


def _runs(kind: np.ndarray) -> np.ndarray:
    """Return ``(start, length, kind)`` rows of the runs of equal non-zero kind."""
    if not kind.any():
        return np.zeros((0, 3), dtype=np.int64)
    edge = np.flatnonzero(np.diff(np.r_[0, kind, 0]) != 0)
    starts, stops = edge[:-1], edge[1:]
    rows = np.column_stack([starts, stops - starts, kind[starts]])
    return rows[rows[:, 2] != 0]


class QuantEncoder:
    """A float series to one zlib stream of quantised, delta-coded blocks, fed in slices."""

    def __init__(self, res: float, level: int = 6) -> None:
        self.res = float(res)
        self.n = 0
        self._z = zlib.compressobj(level)
        self._parts: list[bytes] = []
        self._prev = np.zeros(2, dtype=np.int64)  # the last two quantised values (q[-2], q[-1])

    def add(self, y: np.ndarray) -> None:
        """Append the next samples."""
        y = np.asarray(y, dtype=float)
        for a in range(0, y.size, BLOCK):
            self._block(y[a:a + BLOCK])

    def _block(self, y: np.ndarray) -> None:
        if y.size == 0:
            return
        q, kind = quantise(y, self.res)
        bad = kind != KIND_FINITE
        if bad.any():  # a non-finite sample repeats the last finite value: a zero difference
            idx = np.where(bad, -1, np.arange(q.size))
            idx = np.maximum.accumulate(idx)
            q = np.where(idx >= 0, q[np.maximum(idx, 0)], self._prev[1])
        d1 = np.diff(q, prepend=self._prev[1])
        d2 = np.diff(d1, prepend=self._prev[1] - self._prev[0])
        order = 1 if np.abs(d1).sum(dtype=float) <= np.abs(d2).sum(dtype=float) else 2
        d = d1 if order == 1 else d2
        g = int(np.gcd.reduce(np.abs(d))) or 1
        runs = _runs(kind)
        head = np.r_[q.size, order, g, runs.shape[0], runs.ravel()].astype(np.uint64)
        self._parts.append(self._z.compress(varint(head) + varint(zigzag(d // g))))
        self._prev = np.r_[self._prev, q][-2:]
        self.n += q.size

    def finish(self) -> bytes:
        """Return the whole zlib stream (call once, at the end)."""
        self._parts.append(self._z.flush())
        data = b''.join(self._parts)
        self._parts = [data]
        return data


def decode(data: bytes, res: float) -> np.ndarray:
    """Return the series a :class:`QuantEncoder` stream holds (the reference decoder)."""
    ints = unvarint(zlib.decompress(data))
    return decode_ints(ints, res)[0]


def decode_ints(ints: np.ndarray, res: float) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(values, q)`` of a stream's varints (``q``: the quantised integers)."""
    out_q: list[np.ndarray] = []
    out_kind: list[np.ndarray] = []
    prev = np.zeros(2, dtype=np.int64)
    i = 0
    while i < ints.size:
        count, order, g, nruns = (int(v) for v in ints[i:i + 4])
        i += 4
        runs = ints[i:i + 3 * nruns].astype(np.int64).reshape(-1, 3)
        i += 3 * nruns
        d = unzigzag(ints[i:i + count]) * g
        i += count
        if d.size != count:
            raise ValueError('stream ends inside a block')
        if order == 1:
            q = prev[1] + np.cumsum(d)
        else:
            e = (prev[1] - prev[0]) + np.cumsum(d)
            q = prev[1] + np.cumsum(e)
        kind = np.zeros(count, dtype=np.int64)
        for start, length, k in runs:
            kind[start:start + length] = k
        out_q.append(q)
        out_kind.append(kind)
        prev = np.r_[prev, q][-2:]
    q = np.concatenate(out_q) if out_q else np.zeros(0, dtype=np.int64)
    kind = np.concatenate(out_kind) if out_kind else np.zeros(0, dtype=np.int64)
    y = q * res
    y[kind == KIND_NAN] = np.nan
    y[kind == KIND_POS_INF] = np.inf
    y[kind == KIND_NEG_INF] = -np.inf
    return y, q


@dataclass(frozen=True)
class Steps:
    """A step series' change points: the sample index where each value starts, and the value."""

    index: np.ndarray
    value: np.ndarray

    def expand(self, n: int) -> np.ndarray:
        """Return the series of ``n`` samples (each sample holds the value last changed to)."""
        if self.index.size == 0:
            return np.full(n, np.nan)
        k = np.searchsorted(self.index, np.arange(n), 'right') - 1
        return self.value[np.maximum(k, 0)]


class StepEncoder:
    """A series that changes rarely, as its change points (two :class:`QuantEncoder` streams).

    A change is a change of the quantised value or of its kind (NaN, infinities), so a float
    wobbling below the resolution makes none.
    """

    def __init__(self, res: float) -> None:
        self.res = float(res)
        self.n = 0
        self.changes = 0
        self.index = QuantEncoder(1.0)
        self.value = QuantEncoder(res)
        self._last: tuple[int, int] | None = None  # (q, kind) of the last sample

    def add(self, y: np.ndarray) -> None:
        """Append the next samples."""
        y = np.asarray(y, dtype=float)
        if y.size == 0:
            return
        q, kind = quantise(y, self.res)
        change = np.r_[True, (q[1:] != q[:-1]) | (kind[1:] != kind[:-1])]
        if self._last is not None:
            change[0] = (int(q[0]), int(kind[0])) != self._last
        at = np.flatnonzero(change)
        self.index.add((at + self.n).astype(float))
        self.value.add(y[at])
        self.changes += at.size
        self._last = (int(q[-1]), int(kind[-1]))
        self.n += y.size

    def finish(self) -> tuple[bytes, bytes]:
        """Return the index and value streams."""
        return self.index.finish(), self.value.finish()


def decode_steps(index: bytes, value: bytes, res: float) -> Steps:
    """Return the change points of a :class:`StepEncoder`'s two streams."""
    return Steps(decode(index, 1.0).astype(np.int64), decode(value, res))
