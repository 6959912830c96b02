"""Batch closed loop speed: N parameter sets x the batchable scenario library.

    scripts/in-env python bench/sweep_speed.py [--sets 1000] [--quick]

The LADRC core on numpy rows (``LADRC.batch``) in the batch closed loop
(``ladrc_sim.headless.batch.run_batch``): every library scenario the batch models (those that
start followed; see its docstring: the approaches and the fault scenario are not), all
``--sets`` random parameter sets at once (observer bandwidth 30-150 rad/s, kp 3-30 1/s, b0
0.7-1.4). Also one scenario (``sine_5hz``) at N = 1, 100 and 1000 rows. Last line JSON: ``n_sets``,
``scenarios``, ``wall_s``, ``aggregate_realtime_x`` (simulated seconds of all rows per wall
second; target >= 1500 on this 2-core class, wall <= 60 s), ``single_scenario``,
``worst_error_rms_mm`` (per scenario). ``--quick``: one scenario (``sine_5hz``) and the single
scenario at N = 1 only, a smoke test of the bench.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import json
from pathlib import Path
import sys
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for pkg in ('ladrc_follow', 'ladrc_sim'):
    sys.path.insert(0, str(ROOT / 'ros2_ws' / 'src' / pkg))

from ladrc_follow.control.ladrc import LADRC  # noqa: E402
from ladrc_follow.control.params import ControllerParams, ESOParams, LawParams  # noqa: E402
from ladrc_sim.headless.batch import batchable_scenarios, run_batch  # noqa: E402


def parameter_sets(n: int, seed: int = 1) -> list[ControllerParams]:
    """Random sets over the observer bandwidth, the gain kp and b0 (one structure)."""
    rng = np.random.default_rng(seed)
    base = ControllerParams()
    out = []
    for w0, kp, b0 in zip(rng.uniform(30, 150, n), rng.uniform(3, 30, n),
                          rng.uniform(0.7, 1.4, n), strict=True):
        out.append(replace(base, eso=replace(ESOParams(), gains='bandwidth',
                                             w0_rad_s=float(w0), b0=float(b0)),
                           law=LawParams(kp=float(kp))))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--sets', type=int, default=1000)
    ap.add_argument('--quick', action='store_true',
                    help='sine_5hz only, the single scenario at N = 1 only (a smoke test)')
    a = ap.parse_args()
    sets = parameter_sets(a.sets)
    names = ['sine_5hz'] if a.quick else batchable_scenarios()
    single = {}
    for n in (1,) if a.quick else (1, 100, 1000):
        res = run_batch('sine_5hz', LADRC.batch(sets[:n] if n <= len(sets)
                                                 else parameter_sets(n)), n)
        single[str(n)] = {'wall_s': round(res.wall_s, 2), 'realtime_x': round(res.realtime_x, 1)}
        print(f'sine_5hz, {n} rows: {res.wall_s:.2f} s, {res.realtime_x:.0f}x real time',
              file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    sim_s = 0.0
    worst = {}
    batch = LADRC.batch(sets)  # built (and every set validated) once; run_batch resets it
    for name in names:
        res = run_batch(name, batch, len(sets))
        sim_s += res.t_s.size * 0.0005 * len(sets)
        e = res.true_gap_mm - res.target_gap_mm[:, None]
        worst[name] = round(float(np.max(np.sqrt(np.mean(e * e, axis=0)))), 4)
        print(f'{name}: {res.wall_s:.1f} s', file=sys.stderr, flush=True)
    wall = time.perf_counter() - t0
    print(json.dumps({'n_sets': len(sets), 'scenarios': names, 'wall_s': round(wall, 1),
                      'aggregate_realtime_x': round(sim_s / wall, 1),
                      'single_scenario': {'sine_5hz': single},
                      'worst_error_rms_mm': worst}))


if __name__ == '__main__':
    main()
