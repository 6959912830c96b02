"""The raw -> gap table of a calibration sweep: local fits, checks, grade (calibration.py, part 2).

Gap of each descent sample = encoder position − contact position; table points at gaps from
``min_gap_mm`` up, spaced ``clip(step_rel·gap, step_min_mm, step_max_mm)`` (finer near the
sheet, where the oscillator curve bends hardest); the raw value at each point by a local
quadratic least-squares fit of raw against gap over ±max(step, ``window_min_mm``) (the encoder
is exact, the raw value noisy: regress raw on gap). The fit residuals give the noise (in mm
through the local slope); the same fit on the retract samples gives the repeatability
(descent vs retract: a drifting sensor or a lag); with the simulator's truth, the table's
error against the true gap (window means, so the noise averages out). The checks and the
grade are the controller's own (``CapTable.problems``, ``CapTable.grade``).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any

from ladrc_follow import STATUS_OK, CapTable, RawToGap, TableLimits
import numpy as np

from .calibration import CalibrationError, Phase, SweepRecord, TableSettings


@dataclass
class Calibration:
    """The result of :func:`build_table`: the table, its figures and the fit per point."""

    table: CapTable
    figures: dict[str, Any]
    problems: list[str]
    knots_gap_mm: np.ndarray
    knots_raw_hz: np.ndarray
    knots_noise_mm: np.ndarray
    knots_samples: np.ndarray
    retract_diff_mm: np.ndarray
    truth_error_mm: np.ndarray
    samples: dict[str, np.ndarray]

    @property
    def grade(self) -> str:
        """The table's grade, 'F' when it has problems."""
        return 'F' if self.problems else self.figures['grade']


def _local_fit(g: np.ndarray, r: np.ndarray, order: np.ndarray, centre: float, half: float,
               min_n: int) -> tuple[float, float, float, int]:
    """Quadratic fit of raw on gap within ±half of ``centre``: (raw, slope, resid std, n)."""
    lo = np.searchsorted(g[order], centre - half, side='left')
    hi = np.searchsorted(g[order], centre + half, side='right')
    idx = order[lo:hi]
    n = len(idx)
    if n < min_n:
        return math.nan, math.nan, math.nan, n
    u = (g[idx] - centre) / half
    y = r[idx]
    y0 = float(np.median(y))
    a = np.stack([np.ones(n), u, u * u], axis=1)
    coef, *_ = np.linalg.lstsq(a, y - y0, rcond=None)
    resid = y - y0 - a @ coef
    std = float(np.sqrt(resid @ resid / max(n - 3, 1)))
    return float(coef[0] + y0), float(coef[1] / half), std, n


def _descent_and_retract(record: SweepRecord, settings: TableSettings, limits: TableLimits
                         ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
    """Return the samples, their gap (encoder − contact) and the usable descent / retract masks.

    Raises :class:`CalibrationError` without a contact or with too few descent samples.
    """
    s = record.arrays()
    z_c = record.contact_position_mm
    if not math.isfinite(z_c):
        raise CalibrationError('no contact position: the sweep did not reach the sheet')
    gap = s['position_mm'] - z_c
    usable = ((s['valid'] > 0) & (s['status'] == STATUS_OK) & np.isfinite(s['raw_hz'])
              & np.isfinite(gap))
    # the rest at the start (WAIT) and the descent: the table's samples
    down = usable & ((s['phase'] == Phase.DESCEND) | (s['phase'] == Phase.WAIT))
    up = usable & (s['phase'] == Phase.RETRACT)
    if down.sum() < limits.min_points * settings.min_window_samples:
        raise CalibrationError(f'only {int(down.sum())} valid samples on the descent: too '
                               'few for a table')
    return s, gap, down, up


def _knots(gap_down: np.ndarray, settings: TableSettings) -> np.ndarray:
    """Return the table's gaps: from ``min_gap_mm`` up to the start height itself.

    The last windows are one-sided there, anchored by the rest at the start, so a follow can
    start where the calibration left the axis.
    """
    top = float(np.max(gap_down))
    knots = settings.knots(top)
    if top - knots[-1] > 0.5 * settings.step_min_mm:
        knots = np.append(knots, round(top, 9))
    if len(knots) < 2:
        raise CalibrationError(f'the descent covers only {top:.3f} mm above the contact: '
                               'start higher')
    return knots


def _repeatability(gap_up: np.ndarray, raw_up: np.ndarray, knots: np.ndarray,
                   halves: np.ndarray, raw_k: np.ndarray, slope_k: np.ndarray,
                   min_n: int) -> np.ndarray:
    """Return the retract's fit at the table's gaps, as a gap difference to the descent's."""
    diff = np.full(len(knots), np.nan)
    if gap_up.size >= min_n:
        order_u = np.argsort(gap_up, kind='stable')
        for i, (k, h) in enumerate(zip(knots, halves, strict=True)):
            r_u = _local_fit(gap_up, raw_up, order_u, k, h, min_n)[0]
            diff[i] = (r_u - raw_k[i]) / slope_k[i]
    return diff


def _truth_error(s: dict[str, np.ndarray], down: np.ndarray, table: CapTable,
                 limits: TableLimits, knots: np.ndarray, halves: np.ndarray, z_c: float,
                 min_n: int, figures: dict[str, Any]) -> np.ndarray:
    """Return the table's error per point against the simulator's truth (when there is one).

    Averaged over each fit window so the sensor noise averages out; the figures get the
    largest and the RMS error and the contact position's error.
    """
    truth_err = np.full(len(knots), np.nan)
    tg = s['true_gap_mm']
    has_truth = down & np.isfinite(tg)
    if has_truth.sum() == 0:
        return truth_err
    conv = RawToGap(table, limits)
    e = conv.gaps_mm(s['raw_hz'][has_truth]) - tg[has_truth]
    gt = tg[has_truth]
    for i, (k, h) in enumerate(zip(knots, halves, strict=True)):
        sel = np.abs(gt - k) <= h
        if sel.sum() >= min_n and np.isfinite(e[sel]).all():
            truth_err[i] = float(np.mean(e[sel]))
    if np.isfinite(truth_err).any():
        figures['max_error_mm'] = float(np.nanmax(np.abs(truth_err)))
        figures['sample_error_rms_mm'] = float(np.sqrt(np.nanmean(e * e)))
        figures['contact_error_mm'] = float(
            np.median((s['position_mm'] - tg)[has_truth]) - z_c)
    return truth_err


def build_table(record: SweepRecord, settings: TableSettings | None = None,
                limits: TableLimits | None = None, meta: dict[str, Any] | None = None
                ) -> Calibration:
    """Build, check and grade the raw -> gap table of a sweep (calibration.py, part 2).

    Raises :class:`CalibrationError` when no table can be built at all (no contact, too few
    samples); a table that is built but fails a check comes back with ``problems``.
    """
    settings = settings or TableSettings()
    limits = limits or TableLimits()
    reasons = settings.problems()
    if reasons:
        raise CalibrationError('table settings: ' + '; '.join(reasons))
    min_n = settings.min_window_samples
    s, gap, down, up = _descent_and_retract(record, settings, limits)
    gd, rd = gap[down], s['raw_hz'][down]
    knots = _knots(gd, settings)
    halves = settings.half_window_mm(knots)
    order = np.argsort(gd, kind='stable')
    fits = [_local_fit(gd, rd, order, k, h, min_n) for k, h in zip(knots, halves, strict=True)]
    raw_k, slope_k, std_k, n_k = (np.array(c, dtype=float) for c in zip(*fits, strict=True))
    problems = []
    sparse = n_k < min_n
    if sparse.any():
        i = int(np.argmax(sparse))
        problems.append(f'too few samples at {knots[i]:.3f} mm ({int(n_k[i])} within '
                        f'±{halves[i]:.3f} mm, at least {min_n}): descend slower')
    noise_k = std_k / np.abs(slope_k)
    noise_mm = float(np.nanmedian(noise_k)) if np.isfinite(noise_k).any() else math.nan
    diff = _repeatability(gap[up], s['raw_hz'][up], knots, halves, raw_k, slope_k, min_n)
    rep = float(np.nanmax(np.abs(diff))) if np.isfinite(diff).any() else math.nan

    ok = np.isfinite(raw_k)
    table = CapTable(tuple(float(v) for v in raw_k[ok]), tuple(float(v) for v in knots[ok]),
                     noise_mm if math.isfinite(noise_mm) else math.inf, rep,
                     dict(meta or {}))
    problems += table.problems(limits)
    figures: dict[str, Any] = {
        'points': len(table), 'range_mm': float(knots[ok][-1] - knots[ok][0]) if ok.any()
        else 0.0,
        'gap_min_mm': float(knots[ok][0]) if ok.any() else math.nan,
        'gap_max_mm': float(knots[ok][-1]) if ok.any() else math.nan,
        'noise_mm': noise_mm, 'noise_max_mm': float(np.nanmax(noise_k)) if ok.any()
        else math.nan,
        'repeatability_mm': rep,
        'roughness_mm': float(table.roughness_mm()) if not table.structure_problems(limits)
        else math.nan,
        'samples_descent': int(down.sum()), 'samples_retract': int(up.sum()),
        'contact': record.contact_kind, 'contact_position_mm': record.contact_position_mm,
        'start_position_mm': record.start_position_mm,
    }
    figures['grade'] = 'F' if problems else table.grade(figures['roughness_mm'])
    figures['max_error_mm'] = None
    truth_err = np.full(len(knots), np.nan)
    if not problems:
        truth_err = _truth_error(s, down, table, limits, knots, halves,
                                 record.contact_position_mm, min_n, figures)
    return Calibration(table, figures, problems, knots, raw_k, noise_k, n_k, diff, truth_err,
                       {k: v for k, v in s.items()} | {'gap_mm_enc': gap})
