"""``ladrc tune``: a grid of LADRC sets, gated, swept in the batch closed loop, Pareto front.

The grid spans the observer bandwidth ω0 (``eso.gains: bandwidth``), the gain ``law.kp``,
``eso.b0`` and the second TD's speed factor ``td_b.r_per_s`` around a base set. Every grid
set is validated and put through the stability gate
(:mod:`ladrc_follow.analysis.gate`); the sets that pass run together, as rows of one batch
(:mod:`ladrc_sim.headless.batch`), through each chosen scenario. The scenarios fall in three
classes, and each class gives its own scores (averaged over its scenarios, from 0.2 s on):

* **tracking** (the target changes): ``tracking_rms_mm``, true gap − target RMS;
* **rejection** (the target stays, the sheet moves): ``rejection_rms_mm``, the same RMS;
* **edge** (coverage below 1 at some time: the reading is not the gap there, so the gap error
  says nothing): ``edge_chatter_mm_s``, the command's RMS above 20 Hz (the notes' edge-step
  chatter, §5.3 item 3), and the closest approach ``edge_min_gap_mm`` (reported);

and ``chatter_mm_s``, the command's RMS above 20 Hz on the tracking and rejection scenarios.
A set whose nozzle touches the sheet in any scenario is out, with the scenario and time. The
sets no other set beats in every score are the Pareto front; the chosen set is the front's
point with the least sum of the scores, each divided by its smallest value on the front.
Written: ``tuned.yaml`` (a parameter file the node, ``simulate`` and the suite load),
``tune.md``, ``tune.json``, ``pareto.png``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import itertools
import json
import math
from pathlib import Path
from typing import Any, Callable, Sequence

from ladrc_follow import (
    LADRC,
    ControllerParams,
    ParameterError,
    check,
    dump_params,
    stability_reasons,
)
from ladrc_sim import load_scenario, run_batch
import numpy as np

from .outdir import building
from .report import strict_json

SETTLE_S = 0.2
"""The first 0.2 s of each run (the TD's start) count in no score."""
CHATTER_HZ = 20.0
OBJECTIVES = ('tracking_rms_mm', 'rejection_rms_mm', 'chatter_mm_s', 'edge_chatter_mm_s')
"""The scores the Pareto front is taken over (module docstring); lower is better."""


@dataclass
class Candidate:
    """One grid point: its values, its set, the gate's verdict and its scores."""

    w0_rad_s: float
    kp: float
    b0: float
    td_r_per_s: float
    params: ControllerParams | None
    rejected: str = ''
    scores: dict[str, float] = field(default_factory=dict)  # OBJECTIVES that were measured
    edge_min_gap_mm: float = math.nan
    front: bool = False
    passed: bool = False  # validated, gated in, ran without contact (``params`` may be dropped)

    @property
    def point(self) -> tuple[float, float, float, float]:
        """Return the grid point (ω0, kp, b0, TD R)."""
        return (self.w0_rad_s, self.kp, self.b0, self.td_r_per_s)

    @property
    def error_rms_mm(self) -> float:
        """Gap error RMS over the tracking and rejection scenarios (mean of the two)."""
        e = [self.scores[k] for k in ('tracking_rms_mm', 'rejection_rms_mm')
             if k in self.scores]
        return float(np.mean(e)) if e else math.nan

    @property
    def chatter_mm_s(self) -> float:
        """Command RMS above CHATTER_HZ away from edges (at edges if there is nothing else)."""
        return self.scores.get('chatter_mm_s', self.scores.get('edge_chatter_mm_s', math.nan))


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


Point = tuple[float, float, float, float]
"""One grid point: ω0 [rad/s], kp [1/s], b0, TD R [1/s]."""
CHUNK_MAX = 2000
"""Most grid points per task on the engine (:func:`sweep_on`): a task's batch holds this many
rows (about 1.5 GB with every library scenario); a grid is cut into two parts per worker when
that is fewer, as each part pays the batch loop's cost per tick once (5 120 points in parts of
500: 126 s on two workers against 147 s in one batch on one core)."""


def grid(base: ControllerParams, w0s: Sequence[float], kps: Sequence[float],
         b0s: Sequence[float], td_rs: Sequence[float] | None = None) -> list[Point]:
    """Return the grid's points in sweep order (``td_rs`` default: the base's TD R)."""
    return [tuple(map(float, p)) for p in itertools.product(  # type: ignore[misc]
        w0s, kps, b0s, td_rs or [base.td_b.r_per_s])]


def point_params(base: ControllerParams, point: Point) -> ControllerParams:
    """Return the parameter set of one grid point over ``base``."""
    w0, kp, b0, r = point
    return replace(base, eso=replace(base.eso, gains='bandwidth', w0_rad_s=w0, b0=b0),
                   law=replace(base.law, gains='explicit', kp=kp),
                   td_b=replace(base.td_b, r_per_s=r),
                   follow=replace(base.follow, controller='ladrc'))


def evaluate(base: ControllerParams, points: Sequence[Point], scenarios: Sequence[Any],
             progress: Callable[[int, int], None] | None = None,
             keep_params: bool = True) -> list[Candidate]:
    """Validate, gate and run ``points`` in one batch; return their candidates (no front yet).

    Every point's scores depend on its own row of the batch only, so any split of a grid
    into parts gives the same candidates (:func:`sweep_on`). ``keep_params=False``: the sets
    are not kept (``passed`` says which ran; :func:`point_params` rebuilds one).
    """
    cands = []
    for point in points:
        c = Candidate(*point, None)
        try:
            p = point_params(base, point)
            check(p)
            reasons = stability_reasons(p)
        except (ParameterError, ValueError) as exc:
            c.rejected = '; '.join(getattr(exc, 'reasons', [str(exc)]))
        else:
            if reasons:
                c.rejected = reasons[0]
            else:
                c.params = p
                c.passed = True
        cands.append(c)
    live = [c for c in cands if c.passed]
    if not live:
        return cands
    batch = LADRC.batch([c.params for c in live])
    sums: dict[str, np.ndarray] = {}
    counts: dict[str, int] = {}
    edge_min = np.full(len(live), np.inf)
    contact = [''] * len(live)
    i0 = int(round(SETTLE_S / base.h_s))
    for k, name in enumerate(scenarios):
        res = run_batch(name, batch, len(live))
        label = getattr(name, 'name', name)
        kind = scenario_class(res)
        gap, cmd = res.true_gap_mm, res.command_mm_s
        for j in np.flatnonzero(np.any(gap <= 0.0, axis=0)):
            if not contact[j]:
                t_hit = float(res.t_s[np.argmax(gap[:, j] <= 0.0)])
                contact[j] = f'contact with the sheet in {label} at {t_hit:.3f} s'
        found = {'edge_chatter_mm_s': _chatter(cmd[i0:], base.h_s)} if kind == 'edge' else {
            f'{kind}_rms_mm': np.sqrt(np.mean((gap[i0:] - res.target_gap_mm[i0:, None]) ** 2,
                                              axis=0)),
            'chatter_mm_s': _chatter(cmd[i0:], base.h_s)}
        if kind == 'edge':
            edge_min = np.minimum(edge_min, gap[i0:].min(axis=0))
        for key, val in found.items():
            sums[key] = sums.get(key, 0.0) + val
            counts[key] = counts.get(key, 0) + 1
        if progress is not None:
            progress(k + 1, len(scenarios))
    for j, c in enumerate(live):
        c.scores = {key: float(sums[key][j] / counts[key]) for key in OBJECTIVES if key in sums}
        c.edge_min_gap_mm = float(edge_min[j]) if np.isfinite(edge_min[j]) else math.nan
        if contact[j]:
            c.rejected, c.params, c.passed = contact[j], None, False
        elif not keep_params:
            c.params = None
    return cands


def mark_front(cands: list[Candidate]) -> list[Candidate]:
    """Mark the Pareto front of the candidates that ran (no other beats them in every score).

    In lexicographic order of the scores a dominating point comes before the point it
    dominates, and a point dominated by one off the front is dominated by one on it: so each
    point is checked against the front found so far only (the front stays small), not against
    every other point (10^10 pairs for 10^5 sets).
    """
    ran = [c for c in cands if c.passed]
    if not ran:
        return cands
    keys = list(ran[0].scores)
    order = sorted(range(len(ran)), key=lambda i: [ran[i].scores[k] for k in keys])
    front = np.zeros((0, len(keys)))
    for i in order:
        s = np.array([ran[i].scores[k] for k in keys])
        dominated = np.any(np.all(front <= s, axis=1) & np.any(front < s, axis=1))
        ran[i].front = not dominated
        if not dominated:
            front = np.vstack((front, s))
    return cands


def sweep(base: ControllerParams, w0s: Sequence[float], kps: Sequence[float],
          b0s: Sequence[float], scenarios: Sequence[Any],
          progress: Callable[[int, int], None] | None = None,
          td_rs: Sequence[float] | None = None) -> list[Candidate]:
    """Build, gate and run the grid in one batch on this core; mark the Pareto front.

    ``td_rs``: speed factors R of the second TD (``td_b.r_per_s``; default: the base's).
    """
    return mark_front(evaluate(base, grid(base, w0s, kps, b0s, td_rs), scenarios, progress))


def _evaluate_part(points: list[Point], base: ControllerParams, scenarios: list[Any]
                   ) -> list[Candidate]:
    return evaluate(base, points, scenarios, keep_params=False)


def sweep_on(client: Any, base: ControllerParams, w0s: Sequence[float], kps: Sequence[float],
             b0s: Sequence[float], scenarios: Sequence[Any],
             progress: Callable[[int, int], None] | None = None,
             td_rs: Sequence[float] | None = None, chunk: int | None = None
             ) -> list[Candidate]:
    """Run the sweep of :func:`sweep` in parts of ``chunk`` points on a Dask cluster.

    ``chunk`` default: two parts per worker, at most :data:`CHUNK_MAX` points each. Each task
    holds one part's batch (memory bounded by ``chunk``, whatever the grid's size);
    the sets are not sent back (``point_params`` rebuilds the chosen one); the front is marked
    over all parts at the end, so it is the one :func:`sweep` marks.
    """
    from .engine import in_order

    points = grid(base, w0s, kps, b0s, td_rs)
    if chunk is None:
        workers = max(1, len(client.scheduler_info().get('workers', {})))
        chunk = min(CHUNK_MAX, max(1, math.ceil(len(points) / (2 * workers))))
    parts = [points[i:i + chunk] for i in range(0, len(points), chunk)]
    done = in_order(client, _evaluate_part, parts, base, list(scenarios), progress=progress)
    return mark_front([c for part in done for c in part])


def scenario_kind(name: str) -> str:
    """Return the class of a library scenario without running it (as :func:`scenario_class`)."""
    sc = load_scenario(name)
    if sc.initial_coverage < 1.0 or any(e.name == 'coverage' and e.args['value'] < 1.0
                                        for e in sc.timeline):
        return 'edge'
    return 'tracking' if any(e.name == 'set_target' for e in sc.timeline) else 'rejection'


def scenario_class(res: Any) -> str:
    """Return ``edge``, ``tracking`` or ``rejection`` for a batch run (module docstring)."""
    if np.any(res.coverage < 1.0):
        return 'edge'
    return 'tracking' if np.any(res.target_gap_mm != res.target_gap_mm[0]) else 'rejection'


def _dominates(o: Candidate, c: Candidate) -> bool:
    """Return whether ``o`` is no worse than ``c`` in every score and better in one."""
    pairs = [(o.scores[k], c.scores[k]) for k in c.scores]
    return all(a <= b for a, b in pairs) and any(a < b for a, b in pairs)


def scores(cands: Sequence[Candidate]) -> dict[int, float]:
    """Return the choice's score of each point that ran, keyed by its index in ``cands``.

    Each of the point's scores divided by its smallest value on the Pareto front, summed.
    """
    front = [c for c in cands if c.front]
    if not front:
        return {}
    least = {k: min(c.scores[k] for c in front) or 1e-12 for k in front[0].scores}
    return {i: sum(c.scores[k] / least[k] for k in least)
            for i, c in enumerate(cands) if c.passed}


def choose(cands: Sequence[Candidate]) -> Candidate | None:
    """Return the front's point with the least score (:func:`scores`)."""
    sc = scores(cands)
    return cands[min(sc, key=sc.get)] if sc else None


def _plot(cands: Sequence[Candidate], chosen: Candidate, path: Path) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    live = [c for c in cands if c.passed]
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


def write_tune(cands: Sequence[Candidate], scenarios: Sequence[str], out: Path,
               base: ControllerParams | None = None) -> tuple[Path, dict[str, Any]]:
    """Write the chosen set and the tables; return the folder and the summary.

    ``base``: the sweep's base set, to rebuild the chosen set when the sweep dropped the sets
    (:func:`sweep_on`).
    """
    chosen = choose(cands)
    if chosen is None:
        raise ValueError('no grid point passed the validation and the stability gate '
                         f'(first reason: {cands[0].rejected if cands else "empty grid"})')
    keys = [k for k in OBJECTIVES if k in chosen.scores]
    rows = [{'w0_rad_s': c.w0_rad_s, 'kp': c.kp, 'b0': c.b0, 'td_r_per_s': c.td_r_per_s,
             'rejected': c.rejected or None, **{k: c.scores.get(k) for k in keys},
             'error_rms_mm': c.error_rms_mm, 'chatter_mm_s': c.chatter_mm_s,
             'edge_min_gap_mm': c.edge_min_gap_mm, 'front': c.front} for c in cands]
    live = [c for c in cands if c.passed]
    summary = {'grid': len(cands), 'gated_in': len(live), 'front': sum(c.front for c in cands),
               'scenarios': list(scenarios), 'objectives': keys,
               'chosen': {'w0_rad_s': chosen.w0_rad_s, 'kp': chosen.kp, 'b0': chosen.b0,
                          'td_r_per_s': chosen.td_r_per_s, **chosen.scores,
                          'error_rms_mm': chosen.error_rms_mm,
                          'chatter_mm_s': chosen.chatter_mm_s,
                          'edge_min_gap_mm': chosen.edge_min_gap_mm},
               'worst_error_rms_mm': max(c.error_rms_mm for c in live),
               'chosen_score': min(scores(cands).values()),
               'worst_score': max(scores(cands).values())}
    names = {'tracking_rms_mm': 'tracking RMS [mm]', 'rejection_rms_mm': 'rejection RMS [mm]',
             'chatter_mm_s': 'chatter [mm/s]', 'edge_chatter_mm_s': 'edge chatter [mm/s]'}
    by_class = {}
    for name in scenarios:
        by_class.setdefault(scenario_kind(name), []).append(name)
    lines = ['# Tuning sweep', '',
             f'{len(cands)} grid points, {len(live)} pass the validation, the stability '
             f'gate and the contact check, {summary["front"]} on the Pareto front (batch '
             'closed loop, rows start followed). Scores averaged over the scenarios of their '
             'class: ' + '; '.join(f'{k}: {", ".join(v)}' for k, v in by_class.items()) + '.',
             '',
             f'Chosen: ω0 {chosen.w0_rad_s:g} rad/s, kp {chosen.kp:g} 1/s, b0 {chosen.b0:g}, '
             f'TD R {chosen.td_r_per_s:g} 1/s: '
             + ', '.join(f'{names[k]} {chosen.scores[k]:.4g}' for k in keys)
             + (f', closest approach at edges {chosen.edge_min_gap_mm:.3f} mm'
                if math.isfinite(chosen.edge_min_gap_mm) else '') + ' (`tuned.yaml`).', '',
             '| ω0 [rad/s] | kp [1/s] | b0 | TD R [1/s] | '
             + ' | '.join(names[k] for k in keys) + ' | front | gate |',
             '| --- | --- | --- | --- | ' + '--- | ' * len(keys) + '--- | --- |']
    for c in cands:
        lines.append(f'| {c.w0_rad_s:g} | {c.kp:g} | {c.b0:g} | {c.td_r_per_s:g} | '
                     + ''.join(f'{c.scores.get(k, math.nan):.4g} | ' for k in keys)
                     + f'{"yes" if c.front else ""} | {c.rejected or "passes"} |')
    with building(out) as tmp:
        chosen_params = chosen.params if chosen.params is not None else point_params(
            base or ControllerParams(), chosen.point)
        (tmp / 'tuned.yaml').write_text(dump_params(chosen_params), encoding='utf-8')
        (tmp / 'tune.json').write_text(json.dumps(strict_json({**summary, 'grid_points': rows}),
                                                  indent=1) + '\n', encoding='utf-8')
        (tmp / 'tune.md').write_text('\n'.join(lines + ['', '![pareto](pareto.png)', '']),
                                     encoding='utf-8')
        _plot(cands, chosen, tmp / 'pareto.png')
    return out, summary
