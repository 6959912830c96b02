"""Capacitive calibration table: raw sensor value -> gap (the notes' 电容查表), numpy only.

The capacitive sensor measures an oscillator frequency (``CapacitiveHeight.raw_hz``); the gap
comes from a table of (raw, gap) points recorded by the calibration sweep
(``ladrc calibrate``, docs/calibration.md; the notes call the reading "电容查表高度", the
height looked up from the capacitance, §0 and §4 item 4). The conversion lives in the
controller (the follow node applies it to every sample when ``sensor.table_file`` is set),
so a driver may publish only ``raw_hz``.

* **Interpolation**: monotone piecewise-cubic Hermite (PCHIP, Fritsch–Carlson derivatives as
  ``scipy.interpolate.PchipInterpolator`` computes them; tests/commissioning check the two
  agree). Between strictly monotone points it is strictly monotone too: a larger raw value
  never reads a smaller gap.
* **Range**: a raw value outside the table is never extrapolated. Beyond the far end (wider
  than calibrated): the widest gap, invalid, ``STATUS_OUT_OF_RANGE``. Beyond the near end
  (closer than calibrated): the smallest gap, invalid, status 0, so the controller infers a
  collision from the reading (``TickInput`` semantics) when the table reaches down to
  ``follow.collision_gap_mm``, which the follow node requires.
* **Checks** (:meth:`CapTable.problems`): finite numbers, enough points, gaps strictly
  increasing, raw strictly monotone, the span covered, the noise recorded by the sweep, the
  repeatability (descent vs retract: a drifting sensor) and the table's own roughness
  (leave-one-out error of each interior point). Each failure is one reason with numbers.
* **Grade** (:meth:`CapTable.grade`): the worst of noise, repeatability and roughness against
  ``GRADES`` (A <= 0.01 mm, B <= 0.02 mm, C <= 0.05 mm); worse fails the check.
"""

from __future__ import annotations

from bisect import bisect_right
from dataclasses import dataclass, field
import math
from math import isfinite
from pathlib import Path
from typing import Any, Mapping

from ladrc_contract.codes import GapStatus
from ladrc_contract.schema import Section, param
import numpy as np
import yaml

__all__ = ['CapTableParams', 'TableLimits', 'CapTable', 'RawToGap', 'TableError', 'GRADES',
           'TABLE_FORMAT', 'pchip_slopes', 'hermite_eval', 'read_table', 'load_table',
           'table_yaml', 'STATUS_OK', 'STATUS_OUT_OF_RANGE', 'STATUS_COLLISION',
           'STATUS_FAULT']

TABLE_FORMAT = 'ladrc-cap-table/1'

# ladrc_msgs/CapacitiveHeight STATUS_* (the same values as follow.GAP_STATUS_*)
STATUS_OK, STATUS_OUT_OF_RANGE, STATUS_COLLISION, STATUS_FAULT = (int(c) for c in GapStatus)

# grade -> largest figure (mm) of noise, repeatability and roughness, best first
GRADES: tuple[tuple[str, float], ...] = (('A', 0.01), ('B', 0.02), ('C', 0.05))


@dataclass(frozen=True)
class CapTableParams(Section):
    """The ``sensor`` section: where the gap reading comes from (docs/calibration.md)."""

    PREFIX = 'sensor.'

    table_file: str = param('', '', 'raw → gap calibration table (YAML written by `ladrc '
                            "calibrate`) applied to raw_hz of every sample; '' = use gap_mm "
                            'as published. Checked on load (rejected with its reason); '
                            'changes only while not following', seed='notes §4 电容查表')


class TableError(ValueError):
    """A table that cannot be used; ``reasons`` lists every problem."""

    def __init__(self, reasons: list[str]) -> None:
        self.reasons = list(reasons)
        super().__init__('; '.join(self.reasons))


@dataclass(frozen=True)
class TableLimits:
    """Acceptance limits of a table (defaults: docs/calibration.md, "Checks")."""

    min_points: int = 8
    max_points: int = 20000
    min_span_mm: float = 2.0          # the gap range covered, at least
    max_first_gap_mm: float = 0.5     # the table reaches this close to the sheet, at least
    max_noise_mm: float = GRADES[-1][1]
    max_repeatability_mm: float = GRADES[-1][1]
    max_roughness_mm: float = GRADES[-1][1]


@dataclass(frozen=True)
class CapTable:
    """Points of a raw -> gap table, in order of increasing gap, and the sweep's figures.

    ``noise_mm``: per-sample noise of the reading seen by the sweep (mm). ``repeatability_mm``:
    largest difference descent vs retract (NaN: not measured). ``meta``: free metadata
    (how and when the sweep was made), written back unchanged.
    """

    raw_hz: tuple[float, ...]
    gap_mm: tuple[float, ...]
    noise_mm: float
    repeatability_mm: float = math.nan
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # plain floats (numpy scalars would print as np.float64(...) into the file)
        for name in ('raw_hz', 'gap_mm'):
            object.__setattr__(self, name, tuple(float(v) for v in getattr(self, name)))
        for name in ('noise_mm', 'repeatability_mm'):
            object.__setattr__(self, name, float(getattr(self, name)))

    def __len__(self) -> int:
        return len(self.gap_mm)

    # ---- checks ------------------------------------------------------------------------
    def structure_problems(self, limits: TableLimits = TableLimits()) -> list[str]:
        """Reasons the points cannot form a monotone table (count, finiteness, order)."""
        out: list[str] = []
        n = len(self.gap_mm)
        if len(self.raw_hz) != n:
            return [f'{len(self.raw_hz)} raw values for {n} gaps']
        if n < limits.min_points:
            out.append(f'too few points: {n} (at least {limits.min_points})')
        if n > limits.max_points:
            out.append(f'too many points: {n} (at most {limits.max_points})')
        raw = np.asarray(self.raw_hz, dtype=float)
        gap = np.asarray(self.gap_mm, dtype=float)
        bad = ~(np.isfinite(raw) & np.isfinite(gap))
        if bad.any():
            i = int(np.argmax(bad))
            out.append(f'{int(bad.sum())} non-finite values (first at point {i}: raw '
                       f'{raw[i]!r} Hz, gap {gap[i]!r} mm)')
            return out
        if not (math.isfinite(self.noise_mm) and self.noise_mm >= 0.0):
            out.append(f'noise_mm = {self.noise_mm!r}: must be a finite number >= 0')
        if n < 2:
            return out
        dg = np.diff(gap)
        if (dg <= 0.0).any():
            i = int(np.argmax(dg <= 0.0))
            out.append(f'gaps not strictly increasing at point {i + 1} ({gap[i]:.4f} -> '
                       f'{gap[i + 1]:.4f} mm)')
        dr = np.diff(raw)
        sign = 1.0 if raw[-1] > raw[0] else -1.0
        back = sign * dr <= 0.0
        if sign < 0.0:
            # the contract (CapacitiveHeight.raw_hz): the oscillator's frequency falls as the
            # capacitance rises, i.e. as the nozzle closes in; a table the other way round is
            # a mix-up that would read "far" at contact
            out.append(f'raw falls with the gap ({raw[0]:.6g} Hz at {gap[0]:.4f} mm, '
                       f'{raw[-1]:.6g} Hz at {gap[-1]:.4f} mm): the raw frequency must rise '
                       'with the gap (docs/interfaces.md)')
        elif back.any():
            i = int(np.argmax(back))
            out.append(f'not monotonic: raw {"falls" if sign > 0 else "rises"} from '
                       f'{raw[i]:.6g} to {raw[i + 1]:.6g} Hz between gaps {gap[i]:.4f} and '
                       f'{gap[i + 1]:.4f} mm ({int(back.sum())} reversals)')
        return out

    def roughness_mm(self) -> float:
        """Largest leave-one-out error (mm) of the interior points (0 for < 4 points).

        Each interior point is predicted by the PCHIP through the others; a smooth curve
        sampled densely predicts its points to a few µm, a noisy or kinked table does not.
        """
        x, y = _increasing(self.raw_hz, self.gap_mm)
        n = len(x)
        if n < 4:
            return 0.0
        worst = 0.0
        for j in range(1, n - 1):
            lo, hi = max(0, j - 3), min(n, j + 4)
            keep = [i for i in range(lo, hi) if i != j]
            xs, ys = x[keep], y[keep]
            d = pchip_slopes(xs, ys, left_end=lo == 0, right_end=hi == n)
            err = abs(float(hermite_eval(xs, ys, d, np.array([x[j]]))[0]) - y[j])
            worst = max(worst, err)
        return worst

    def figures(self) -> dict[str, float]:
        """Points, gap range, noise, repeatability and roughness (mm) of the table."""
        return {'points': len(self), 'gap_min_mm': float(min(self.gap_mm)),
                'gap_max_mm': float(max(self.gap_mm)),
                'range_mm': float(max(self.gap_mm) - min(self.gap_mm)),
                'noise_mm': float(self.noise_mm),
                'repeatability_mm': float(self.repeatability_mm),
                'roughness_mm': self.roughness_mm()}

    def grade(self, roughness_mm: float | None = None) -> str:
        """Return 'A', 'B', 'C' (usable) or 'F' from the worst of its noise figures."""
        rough = self.roughness_mm() if roughness_mm is None else roughness_mm
        worst = max(self.noise_mm, rough,
                    self.repeatability_mm if math.isfinite(self.repeatability_mm) else 0.0)
        for name, limit in GRADES:
            if worst <= limit:
                return name
        return 'F'

    def problems(self, limits: TableLimits = TableLimits()) -> list[str]:
        """Every reason why this table cannot be used (empty: usable)."""
        out = self.structure_problems(limits)
        if any('non-finite' in r or 'raw values for' in r for r in out) or len(self) < 2:
            return out
        structure_ok = not out
        gap = self.gap_mm
        span = gap[-1] - gap[0]
        if span < limits.min_span_mm:
            out.append(f'too short: covers {gap[0]:.3f}–{gap[-1]:.3f} mm ({span:.3f} mm, at '
                       f'least {limits.min_span_mm:g} mm)')
        if gap[0] > limits.max_first_gap_mm:
            out.append(f'starts at {gap[0]:.3f} mm: it must reach down to '
                       f'{limits.max_first_gap_mm:g} mm (closer readings would be unknown)')
        if self.noise_mm > limits.max_noise_mm:
            out.append(f'noisy: {self.noise_mm:.4f} mm noise per sample (at most '
                       f'{limits.max_noise_mm:g} mm)')
        rep = self.repeatability_mm
        if math.isfinite(rep) and rep > limits.max_repeatability_mm:
            out.append(f'drifted: descent and retract differ by up to {rep:.4f} mm (at most '
                       f'{limits.max_repeatability_mm:g} mm)')
        rough = self.roughness_mm() if structure_ok else 0.0
        if rough > limits.max_roughness_mm:
            out.append(f'not smooth: a point differs by {rough:.4f} mm from the curve through '
                       f'its neighbours (at most {limits.max_roughness_mm:g} mm)')
        return out


def _increasing(raw: Any, gap: Any) -> tuple[np.ndarray, np.ndarray]:
    """Points ordered by increasing raw value (the interpolation's x)."""
    x = np.asarray(raw, dtype=float)
    y = np.asarray(gap, dtype=float)
    if len(x) > 1 and x[-1] < x[0]:
        return x[::-1].copy(), y[::-1].copy()
    return x, y


def _edge_slope(h0: float, h1: float, m0: float, m1: float) -> float:
    """One-sided three-point end derivative, shape-preserving (scipy's PCHIP ``_edge_case``)."""
    d = ((2.0 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
    if np.sign(d) != np.sign(m0):
        return 0.0
    if np.sign(m0) != np.sign(m1) and abs(d) > 3.0 * abs(m0):
        return 3.0 * m0
    return float(d)


def pchip_slopes(x: np.ndarray, y: np.ndarray, left_end: bool = True,
                 right_end: bool = True) -> np.ndarray:
    """Fritsch–Carlson PCHIP derivatives at the points (x strictly increasing).

    Interior: weighted harmonic mean of the two secants (0 where they differ in sign); ends:
    the shape-preserving three-point formula. ``left_end``/``right_end`` False: the ends of a
    slice of a longer table, where only interior derivatives are used (roughness).
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    h = np.diff(x)
    m = np.diff(y) / h
    d = np.zeros_like(y)
    if len(x) == 2:
        d[:] = m[0]
        return d
    w1 = 2.0 * h[1:] + h[:-1]
    w2 = h[1:] + 2.0 * h[:-1]
    same = (np.sign(m[1:]) == np.sign(m[:-1])) & (m[1:] != 0.0) & (m[:-1] != 0.0)
    with np.errstate(divide='ignore', invalid='ignore'):
        whmean = (w1 / m[:-1] + w2 / m[1:]) / (w1 + w2)
        d[1:-1] = np.where(same, 1.0 / whmean, 0.0)
    d[0] = _edge_slope(h[0], h[1], m[0], m[1]) if left_end else m[0]
    d[-1] = _edge_slope(h[-1], h[-2], m[-1], m[-2]) if right_end else m[-1]
    return d


def hermite_eval(x: np.ndarray, y: np.ndarray, d: np.ndarray, xq: np.ndarray) -> np.ndarray:
    """Cubic Hermite through (x, y) with slopes d at ``xq`` (inside [x0, xn]; clipped)."""
    k = np.clip(np.searchsorted(x, xq, side='right') - 1, 0, len(x) - 2)
    hk = x[k + 1] - x[k]
    t = (xq - x[k]) / hk
    t2, t3 = t * t, t * t * t
    return ((2 * t3 - 3 * t2 + 1) * y[k] + (t3 - 2 * t2 + t) * hk * d[k]
            + (-2 * t3 + 3 * t2) * y[k + 1] + (t3 - t2) * hk * d[k + 1])


class RawToGap:
    """The conversion of a checked table: ``convert(raw, valid, status)`` per sample.

    Built only from a table without problems (raises :class:`TableError` with the reasons).
    The per-sample path is plain Python (bisect and one cubic), a few µs at 2 kHz.
    """

    def __init__(self, table: CapTable, limits: TableLimits = TableLimits()) -> None:
        reasons = table.problems(limits)
        if reasons:
            raise TableError(reasons)
        self.table = table
        self.roughness_mm = table.roughness_mm()
        self.grade = table.grade(self.roughness_mm)
        x, y = _increasing(table.raw_hz, table.gap_mm)
        d = pchip_slopes(x, y)
        h = np.diff(x)
        m = np.diff(y) / h
        # per segment: g = c0 + c1 t + c2 t^2 + c3 t^3, t = raw - x_k (scipy's CubicHermite)
        self._x = x.tolist()
        self._c0 = y[:-1].tolist()
        self._c1 = d[:-1].tolist()
        self._c2 = ((3.0 * m - 2.0 * d[:-1] - d[1:]) / h).tolist()
        self._c3 = ((d[:-1] + d[1:] - 2.0 * m) / (h * h)).tolist()
        self._last = len(x) - 2
        self.raw_min_hz, self.raw_max_hz = float(x[0]), float(x[-1])
        self.gap_min_mm, self.gap_max_mm = float(table.gap_mm[0]), float(table.gap_mm[-1])
        # which raw end is the sheet side (smallest gap)
        self._near_is_low = bool(y[0] < y[-1])
        self.out_of_range = 0  # samples converted out of the table's range

    def gap_mm(self, raw_hz: float) -> float:
        """Gap of one raw value; NaN outside the table (never extrapolated) or not finite."""
        x = self._x
        if not (x[0] <= raw_hz <= x[-1]):
            return math.nan
        k = bisect_right(x, raw_hz) - 1
        if k > self._last:
            k = self._last
        t = raw_hz - x[k]
        return self._c0[k] + t * (self._c1[k] + t * (self._c2[k] + t * self._c3[k]))

    def gaps_mm(self, raw_hz: np.ndarray) -> np.ndarray:
        """Vectorized :meth:`gap_mm` (NaN outside the table)."""
        r = np.asarray(raw_hz, dtype=float)
        x = np.asarray(self._x)
        k = np.clip(np.searchsorted(x, r, side='right') - 1, 0, self._last)
        t = r - x[k]
        c0, c1, c2, c3 = (np.asarray(c)[k] for c in (self._c0, self._c1, self._c2, self._c3))
        g = c0 + t * (c1 + t * (c2 + t * c3))
        return np.where((r >= x[0]) & (r <= x[-1]), g, np.nan)

    def convert(self, raw_hz: float, valid: bool, status: int) -> tuple[float, bool, int]:
        """Return ``(gap_mm, valid, status)`` of one sample (module docstring, "Range")."""
        if not isfinite(raw_hz):  # NaN or inf
            return math.nan, False, status if status else STATUS_FAULT
        g = self.gap_mm(raw_hz)
        if isfinite(g):
            return g, bool(valid) and status == STATUS_OK, status
        self.out_of_range += 1
        near = (raw_hz < self._x[0]) == self._near_is_low
        if near:  # closer than calibrated: the smallest gap, a collision whatever was sent
            return self.gap_min_mm, False, STATUS_COLLISION
        return self.gap_max_mm, False, status if status else STATUS_OUT_OF_RANGE

    def describe(self) -> str:
        """One line: points, gap range, grade."""
        t = self.table
        return (f'{len(t)} points, {self.gap_min_mm:.3f}–{self.gap_max_mm:.3f} mm, grade '
                f'{self.grade}, noise {t.noise_mm:.4f} mm')


# ---- file ------------------------------------------------------------------------------
def _num(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    try:
        return float(v)
    except OverflowError:  # an int beyond any float
        return None


def table_from_mapping(d: Any, where: str = 'table') -> CapTable:
    """Build a :class:`CapTable` from the YAML mapping; :class:`TableError` on its layout."""
    if not isinstance(d, dict):
        raise TableError([f'{where}: not a table (a mapping with format, noise_mm, points)'])
    reasons = []
    if d.get('format') != TABLE_FORMAT:
        reasons.append(f"{where}: format {d.get('format')!r}, expected {TABLE_FORMAT!r}")
    noise = _num(d.get('noise_mm'))
    if noise is None:
        reasons.append(f'{where}: noise_mm missing or not a number (the sweep records it)')
    rep = d.get('repeatability_mm')
    rep_v = math.nan if rep is None else _num(rep)
    if rep_v is None or not (rep_v != rep_v or (math.isfinite(rep_v) and rep_v >= 0.0)):
        reasons.append(f'{where}: repeatability_mm = {rep!r:.40}: must be a finite number >= 0 '
                       'or null (not measured)')
        rep_v = math.nan
    pts = d.get('points')
    raw: list[float] = []
    gap: list[float] = []
    if not isinstance(pts, list):
        reasons.append(f'{where}: points must be a list of [raw_hz, gap_mm] pairs')
    else:
        for i, p in enumerate(pts):
            pair = [_num(v) for v in p] if isinstance(p, (list, tuple)) else []
            if len(pair) != 2 or None in pair:
                reasons.append(f'{where}: points[{i}] = {p!r}: must be [raw_hz, gap_mm]')
                break
            raw.append(pair[0])
            gap.append(pair[1])
    meta = d.get('calibration', {})
    if reasons:
        raise TableError(reasons)
    return CapTable(tuple(raw), tuple(gap), float(noise), float(rep_v),
                    meta if isinstance(meta, dict) else {'calibration': meta})


def read_table(path: str | Path) -> CapTable:
    """Read a table file (layout only; :meth:`CapTable.problems` checks the values)."""
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as exc:
        raise TableError([f'cannot read {path}: {exc}']) from None
    try:
        d = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise TableError([f'{path} is not valid YAML: {" ".join(str(exc).split())}']) from None
    return table_from_mapping(d, str(path))


def load_table(path: str | Path, limits: TableLimits = TableLimits()) -> RawToGap:
    """Read and check a table file; return its conversion or raise with every reason."""
    table = read_table(path)
    try:
        return RawToGap(table, limits)
    except TableError as exc:
        raise TableError([f'{path}: {r}' for r in exc.reasons]) from None


def table_yaml(table: CapTable, header: str = '') -> str:
    """YAML text of a table (the file ``load_table`` reads); full float precision."""
    lines = [f'# {h}' for h in header.splitlines()] if header else []
    lines += [f'format: {TABLE_FORMAT}',
              f'grade: {table.grade()}  # recomputed on load',
              f'noise_mm: {table.noise_mm!r}',
              'repeatability_mm: ' + (repr(table.repeatability_mm)
                                      if math.isfinite(table.repeatability_mm) else 'null')]
    if table.meta:
        meta = yaml.safe_dump({'calibration': dict(table.meta)}, sort_keys=False,
                              default_flow_style=False, allow_unicode=True)
        lines += meta.rstrip('\n').splitlines()
    lines.append('points:  # [raw_hz, gap_mm], gap increasing')
    lines += [f'  - [{r!r}, {g!r}]' for r, g in zip(table.raw_hz, table.gap_mm, strict=True)]
    return '\n'.join(lines) + '\n'
