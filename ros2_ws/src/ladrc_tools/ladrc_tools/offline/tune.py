"""``ladrc tune``: a grid of LADRC sets, gated, swept in the batch closed loop, Pareto front.

The grid spans the observer bandwidth ω0 (``eso.gains: bandwidth``), the gain ``law.kp``,
``eso.b0`` and the second TD's speed factor ``td_b.r_per_s`` around a base set. Every grid
set is validated and put through the stability gate
(:mod:`ladrc_follow.control.stability`); the sets that pass run together, as rows of one batch
(:mod:`ladrc_sim.headless.batch`), through each chosen scenario. Two scores per set, averaged
over the scenarios: the **error RMS** (true gap − target, from 0.2 s on: tracking and
rejection of the sheet's motion together) and the **chatter** (RMS of the command's content
above 20 Hz). The sets no other set beats in both are the Pareto front; the chosen set is the
front's point with the least sum of the two scores, each divided by its smallest value on
the front. Written: ``tuned.yaml`` (a parameter file the node, ``simulate`` and the suite
load), ``tune.md``, ``tune.json``, ``pareto.png``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import itertools
import json
import math
from pathlib import Path
from typing import Any, Callable, Sequence

from ladrc_follow.control.ladrc import LADRC
from ladrc_follow.control.params import ControllerParams, ParameterError, check, dump_params
from ladrc_follow.control.stability import stability_reasons
from ladrc_sim.headless.batch import run_batch
import numpy as np

from .outdir import building
from .report import strict_json

SETTLE_S = 0.2
"""The first 0.2 s of each run (the TD's start) count in no score."""
CHATTER_HZ = 20.0


@dataclass
class Candidate:
    """One grid point: its values, its set, the gate's verdict and its scores."""

    w0_rad_s: float
    kp: float
    b0: float
    td_r_per_s: float
    params: ControllerParams | None
    rejected: str = ''
    error_rms_mm: float = math.nan
    chatter_mm_s: float = math.nan
    front: bool = False


def parse_range(text: str, what: str) -> list[float]:
    """``a:b:n`` (n values from a to b) or a single value; ValueError with the reason."""
    parts = text.split(':')
    try:
        if len(parts) == 1:
            return [float(parts[0])]
        if len(parts) == 3:
            a, b, n = float(parts[0]), float(parts[1]), int(parts[2])
            if n < 1 or not (math.isfinite(a) and math.isfinite(b)):
                raise ValueError
            return [float(x) for x in np.linspace(a, b, n)]
    except ValueError:
        pass
    raise ValueError(f'--{what} {text!r}: give a value or a:b:n (n values from a to b)')


def _chatter(u: np.ndarray, h_s: float) -> np.ndarray:
    """RMS of each column's content above CHATTER_HZ (mm/s), from the FFT."""
    n = u.shape[0]
    spec = np.fft.rfft(u - u.mean(axis=0), axis=0)
    f = np.fft.rfftfreq(n, h_s)
    hi = spec[f > CHATTER_HZ]
    # Parseval for a real signal: the one-sided bins count twice
    return np.sqrt(2.0 * np.sum(np.abs(hi) ** 2, axis=0)) / n


def sweep(base: ControllerParams, w0s: Sequence[float], kps: Sequence[float],
          b0s: Sequence[float], scenarios: Sequence[str],
          progress: Callable[[int, int], None] | None = None,
          td_rs: Sequence[float] | None = None) -> list[Candidate]:
    """Build, gate and run the grid; mark the Pareto front.

    ``td_rs``: speed factors R of the second TD (``td_b.r_per_s``; default: the base's).
    """
    cands = []
    for w0, kp, b0, r in itertools.product(w0s, kps, b0s, td_rs or [base.td_b.r_per_s]):
        c = Candidate(w0, kp, b0, r, None)
        try:
            p = replace(base, eso=replace(base.eso, gains='bandwidth', w0_rad_s=w0, b0=b0),
                        law=replace(base.law, gains='explicit', kp=kp),
                        td_b=replace(base.td_b, r_per_s=r),
                        follow=replace(base.follow, controller='ladrc'))
            check(p)
            reasons = stability_reasons(p)
        except (ParameterError, ValueError) as exc:
            c.rejected = '; '.join(getattr(exc, 'reasons', [str(exc)]))
        else:
            if reasons:
                c.rejected = reasons[0]
            else:
                c.params = p
        cands.append(c)
    live = [c for c in cands if c.params is not None]
    if not live:
        return cands
    batch = LADRC.batch([c.params for c in live])
    err = np.zeros(len(live))
    chat = np.zeros(len(live))
    for k, name in enumerate(scenarios):
        res = run_batch(name, batch, len(live))
        i0 = int(round(SETTLE_S / base.h_s))
        e = res.true_gap_mm[i0:] - res.target_gap_mm[i0:, None]
        err += np.sqrt(np.mean(e * e, axis=0)) / len(scenarios)
        chat += _chatter(res.command_mm_s[i0:], base.h_s) / len(scenarios)
        if progress is not None:
            progress(k + 1, len(scenarios))
    for c, e_, ch in zip(live, err, chat, strict=True):
        c.error_rms_mm, c.chatter_mm_s = float(e_), float(ch)
    for c in live:
        c.front = not any(o.error_rms_mm <= c.error_rms_mm and o.chatter_mm_s <= c.chatter_mm_s
                          and (o.error_rms_mm < c.error_rms_mm
                               or o.chatter_mm_s < c.chatter_mm_s) for o in live)
    return cands


def scores(cands: Sequence[Candidate]) -> dict[int, float]:
    """Return the choice's score of each point that ran, keyed by its index in ``cands``.

    Error RMS and chatter, each divided by its smallest value on the Pareto front, summed.
    """
    front = [c for c in cands if c.front]
    if not front:
        return {}
    e_min = min(c.error_rms_mm for c in front) or 1e-12
    ch_min = min(c.chatter_mm_s for c in front) or 1e-12
    return {i: c.error_rms_mm / e_min + c.chatter_mm_s / ch_min
            for i, c in enumerate(cands) if c.params is not None}


def choose(cands: Sequence[Candidate]) -> Candidate | None:
    """Return the front's point with the least score (:func:`scores`)."""
    sc = scores(cands)
    return cands[min(sc, key=sc.get)] if sc else None


def _plot(cands: Sequence[Candidate], chosen: Candidate, path: Path) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    live = [c for c in cands if c.params is not None]
    fig, ax = plt.subplots(figsize=(8, 6))
    ax.scatter([c.chatter_mm_s for c in live], [c.error_rms_mm for c in live], s=12,
               color='0.6', label='gated in')
    front = sorted((c for c in live if c.front), key=lambda c: c.chatter_mm_s)
    ax.plot([c.chatter_mm_s for c in front], [c.error_rms_mm for c in front], 'o-',
            color='C0', label='Pareto front')
    ax.plot([chosen.chatter_mm_s], [chosen.error_rms_mm], '*', ms=16, color='C3',
            label=f'chosen: ω0 {chosen.w0_rad_s:g}, kp {chosen.kp:g}, b0 {chosen.b0:g}')
    ax.set_xlabel(f'chatter: command RMS above {CHATTER_HZ:g} Hz [mm/s]')
    ax.set_ylabel('gap error RMS [mm]')
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_tune(cands: Sequence[Candidate], scenarios: Sequence[str], out: Path
               ) -> tuple[Path, dict[str, Any]]:
    """Write the chosen set and the tables; return the folder and the summary."""
    chosen = choose(cands)
    if chosen is None:
        raise ValueError('no grid point passed the validation and the stability gate '
                         f'(first reason: {cands[0].rejected if cands else "empty grid"})')
    rows = [{'w0_rad_s': c.w0_rad_s, 'kp': c.kp, 'b0': c.b0, 'td_r_per_s': c.td_r_per_s,
             'rejected': c.rejected or None,
             'error_rms_mm': c.error_rms_mm, 'chatter_mm_s': c.chatter_mm_s,
             'front': c.front} for c in cands]
    live = [c for c in cands if c.params is not None]
    summary = {'grid': len(cands), 'gated_in': len(live), 'front': sum(c.front for c in cands),
               'scenarios': list(scenarios),
               'chosen': {'w0_rad_s': chosen.w0_rad_s, 'kp': chosen.kp, 'b0': chosen.b0,
                          'td_r_per_s': chosen.td_r_per_s,
                          'error_rms_mm': chosen.error_rms_mm,
                          'chatter_mm_s': chosen.chatter_mm_s},
               'worst_error_rms_mm': max(c.error_rms_mm for c in live),
               'chosen_score': min(scores(cands).values()),
               'worst_score': max(scores(cands).values())}
    lines = ['# Tuning sweep', '',
             f'{len(cands)} grid points, {len(live)} pass the validation and the stability '
             f'gate, {summary["front"]} on the Pareto front; scores averaged over '
             f'{", ".join(scenarios)} (batch closed loop, rows start followed).', '',
             f'Chosen: ω0 {chosen.w0_rad_s:g} rad/s, kp {chosen.kp:g} 1/s, b0 {chosen.b0:g}, '
             f'TD R {chosen.td_r_per_s:g} 1/s: '
             f'error RMS {chosen.error_rms_mm:.4g} mm, chatter {chosen.chatter_mm_s:.4g} mm/s '
             '(`tuned.yaml`).', '',
             '| ω0 [rad/s] | kp [1/s] | b0 | TD R [1/s] | error RMS [mm] | chatter [mm/s] '
             '| front | gate |',
             '| --- | --- | --- | --- | --- | --- | --- | --- |']
    for c in cands:
        lines.append(f'| {c.w0_rad_s:g} | {c.kp:g} | {c.b0:g} | {c.td_r_per_s:g} | '
                     f'{c.error_rms_mm:.4g} | '
                     f'{c.chatter_mm_s:.4g} | {"yes" if c.front else ""} | '
                     f'{c.rejected or "passes"} |')
    with building(out) as tmp:
        (tmp / 'tuned.yaml').write_text(dump_params(chosen.params), encoding='utf-8')
        (tmp / 'tune.json').write_text(json.dumps(strict_json({**summary, 'grid_points': rows}),
                                                  indent=1) + '\n', encoding='utf-8')
        (tmp / 'tune.md').write_text('\n'.join(lines + ['', '![pareto](pareto.png)', '']),
                                     encoding='utf-8')
        _plot(cands, chosen, tmp / 'pareto.png')
    return out, summary
