"""The notes' experiments as the notes ran them, beside the notes' figures.

    scripts/in-env python bench/seed_experiments.py [--jobs 2] [--quick]

Runs ``ladrc_tools.offline.seed_experiments`` (headless, 2 kHz): the 5 Hz sine on the
target (SIN_GEN) with the "9.8 Hz" and "14.6 Hz" observers; the notes' steps run by the
LADRC and its TD as in the seed (no re-interpolation), with chatter during the step; the thin
sheet with the notes' LADRC (90 rad/s, b0 200 mapped) and PID (suppression 5) beside the
shipped sets, and a b0 sweep; the nonlinear observer (fal) against the linear one with equal
small-signal gains; the gated Kalman filter in the loop. Prints one table per experiment; the
last line is JSON with ``sine5_td_ratio``, ``sine5_gap_ratio_9_8hz``,
``sine5_gap_ratio_14_6hz``, ``edge_step_chatter_9_8hz``, ``edge_step_chatter_14_6hz``
(command RMS above 20 Hz during the LADRC-run half-off 3->1 mm step, mm/s),
``thin_sheet_ladrc_range_mm``, ``thin_sheet_pid_range_mm`` (the notes' settings), ``runs``,
``wall_s`` and the rows (``rows``). ``--quick``: only the experiments those figures come from
and one of each other table (8 runs), a smoke test of the bench.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
import json
import math
from pathlib import Path
import sys
import time

ROOT = Path(__file__).resolve().parents[1]
for pkg in ('ladrc_follow', 'ladrc_sim', 'ladrc_tools', 'ladrc_bags'):
    sys.path.insert(0, str(ROOT / 'ros2_ws' / 'src' / pkg))

from ladrc_tools.offline import seed_experiments as se  # noqa: E402


def jobs() -> list[tuple]:
    """Return every experiment as (function name, args)."""
    out: list[tuple] = [('sine_on_target', (o,)) for o in se.OBSERVERS]
    out += [('step', (label, o, ri)) for label in se.STEPS for o in se.OBSERVERS
            for ri in (False, True)]
    thin = [('shipped LADRC (180, 10800; b0 1)', {}, False),
            (f'notes LADRC (270, 24300; b0 {se.B0_UNIT_MAPPING:g})',
             se.notes_ladrc(se.B0_UNIT_MAPPING), False),
            (f'notes LADRC (270, 24300; b0 {se.B0_IDENTIFIED:.3g})',
             se.notes_ladrc(se.B0_IDENTIFIED), False),
            ('notes PID "3.0" (suppression 5, machining)', se.NOTES_PID, True),
            ('PID, suppression off (not machining)', {'follow': {'controller': 'pid'}},
             False)]
    out += [('thin_sheet', args) for args in thin]
    out += [('thin_sheet', (f'notes LADRC, b0 {b0:g}', se.notes_ladrc(b0), False))
            for b0 in (0.5, 1.0, 4.0, 8.0, 16.0)]
    settings = {'linear (shipped)': {},
                'fal on the disturbance, δ 10 µm': se.fal_params('disturbance', 0.01),
                'fal on the disturbance, δ 2 µm': se.fal_params('disturbance', 0.002),
                'fal on all (NESO), δ 10 µm': se.fal_params('all', 0.01),
                'fal on the disturbance, δ 10 µm, table': se.fal_params('disturbance', 0.01,
                                                                         table=True)}
    for scenario in ('chirp_0_5hz', 'sine on the target', 'edge 3->1 mm (half off)',
                     'thin_sheet', 'feedback_gain_noise'):
        out += [('nonlinear', (scenario, label, p)) for label, p in settings.items()]
    for scenario in ('triangle_ridge', 'feedback_gain_noise'):
        out += [('kalman', (scenario, label, p)) for label, p in se.KALMAN_SETTINGS.items()]
    return out


def quick_jobs() -> list[tuple]:
    """Return the experiments of the JSON's figures and the first of each other kind."""
    def wanted(job: tuple) -> bool:
        name, args = job
        return (name == 'sine_on_target'
                or (name == 'step' and args[0] == 'edge 3->1 mm (half off)' and not args[2])
                or (name == 'thin_sheet' and args[0].startswith(('notes LADRC (270, 24300; b0 '
                                                                  f'{se.B0_UNIT_MAPPING:g})',
                                                                  'notes PID'))))
    todo = jobs()
    out = [j for j in todo if wanted(j)]
    return out + [next(j for j in todo if j[0] == kind) for kind in ('nonlinear', 'kalman')]


def run_job(job: tuple) -> dict:
    """Run one experiment in this process."""
    name, args = job
    return getattr(se, name)(*args)


def fmt(v: object) -> str:
    """Format a cell."""
    if isinstance(v, float):
        return 'n/a' if not math.isfinite(v) else f'{v:.4g}'
    return str(v)


def table(rows: list[dict], keys: list[str]) -> None:
    """Print rows as a Markdown table of ``keys``."""
    print('| ' + ' | '.join(keys) + ' |')
    print('|' + ' --- |' * len(keys))
    for r in rows:
        print('| ' + ' | '.join(fmt(r.get(k, '')) for k in keys) + ' |')
    print()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--jobs', type=int, default=2, help='worker processes [2]')
    ap.add_argument('--quick', action='store_true',
                    help="only the JSON's experiments and one of each table (a smoke test)")
    a = ap.parse_args()
    t0 = time.perf_counter()
    todo = quick_jobs() if a.quick else jobs()
    with ProcessPoolExecutor(max_workers=max(1, a.jobs)) as pool:
        rows = list(pool.map(run_job, todo, chunksize=2))
    by = {}
    for r in rows:
        by.setdefault(r['experiment'], []).append(r)
    print('## 5 Hz sine on the target (SIN_GEN), notes §5.3 item 4: notes 0.72 (9.8 Hz)')
    table(by['sine on the target'], ['observer', 'td_ratio', 'firmware_tdb_ratio',
                                     'gap_ratio', 'gap_phase_deg', 'loop_error_rms_mm'])
    print('## Steps run by the LADRC (seed: no re-interpolation) and, for contrast, shipped')
    table(by['step'], ['step', 'observer', 'reinterpolate', 'chatter_mm_s',
                       'ladrc_share_in_step', 'travel_mm', 'min_true_gap_mm'])
    print('## Thin sheet (notes §5.3 item 5: PID -1…+1.49 mm, LADRC ±0.7 mm)')
    table(by['thin sheet'], ['setting', 'machining', 'deviation_min_mm', 'deviation_max_mm',
                             'range_mm', 'error_rms_mm', 'ladrc_share'])
    print('## Nonlinear observer (fal) vs linear with equal small-signal gains')
    table(by['nonlinear observer'], ['scenario', 'setting', 'error_rms_mm', 'chatter_mm_s',
                                     'range_mm', 'gap_ratio'])
    print('## Kalman in the loop (one-sided gate 0.05 mm, 10 ticks to confirm)')
    table(by['kalman'], ['scenario', 'setting', 'error_rms_mm', 'error_max_mm',
                         'chatter_mm_s'])

    def pick(exp: str, **match) -> dict:
        return next(r for r in by[exp] if all(r.get(k) == v for k, v in match.items()))

    s98 = pick('sine on the target', observer='9.8 Hz')
    s146 = pick('sine on the target', observer='14.6 Hz')
    e98 = pick('step', step='edge 3->1 mm (half off)', observer='9.8 Hz', reinterpolate=False)
    e146 = pick('step', step='edge 3->1 mm (half off)', observer='14.6 Hz',
                reinterpolate=False)
    lad = pick('thin sheet', setting=f'notes LADRC (270, 24300; b0 {se.B0_UNIT_MAPPING:g})')
    pid = pick('thin sheet', setting='notes PID "3.0" (suppression 5, machining)')
    wall = time.perf_counter() - t0
    print(f'{len(rows)} runs in {wall:.1f} s')
    print(json.dumps({
        'sine5_td_ratio': round(s98['td_ratio'], 4),
        'sine5_gap_ratio_9_8hz': round(s98['gap_ratio'], 4),
        'sine5_gap_ratio_14_6hz': round(s146['gap_ratio'], 4),
        'edge_step_chatter_9_8hz': round(e98['chatter_mm_s'], 3),
        'edge_step_chatter_14_6hz': round(e146['chatter_mm_s'], 3),
        'thin_sheet_ladrc_range_mm': round(lad['range_mm'], 3),
        'thin_sheet_pid_range_mm': round(pid['range_mm'], 3),
        'runs': len(rows), 'wall_s': round(wall, 1),
        'rows': [{k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                  for k, v in r.items()} for r in rows]}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
