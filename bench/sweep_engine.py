"""``ladrc tune`` on the engine: a grid on one core vs in parts on a local Dask cluster.

    scripts/in-env python bench/sweep_engine.py [--sets 5000] [--scenarios step,sine_5hz]
    scripts/in-env python bench/sweep_engine.py --sets 100000 --engine-only --scenarios ...

The grid (ω0 × kp × b0 × TD R, about ``--sets`` points around the shipped set) is swept by
``offline.tune.sweep`` in one batch on this core and by ``sweep_on`` in parts (``--chunk``
points on a local cluster of ``--workers`` processes); every candidate's scores, verdict and
front flag are compared. ``--engine-only`` skips the one-core sweep (a 100 000-point batch on
one core would hold every row's time series at once: the engine's parts bound the memory).
Peak resident memory: this process (the driver, and the one-core sweep) and each worker.
Last line JSON: ``points``, ``one_core_s``, ``engine_s``, ``identical`` (scores, verdicts,
fronts), ``front``, ``driver_peak_rss_mb``, ``worker_peak_rss_mb``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for pkg in ('ladrc_contract', 'ladrc_follow', 'ladrc_sim', 'ladrc_tools', 'ladrc_bags',
            'ladrc_fleet'):
    src = str(ROOT / 'ros2_ws' / 'src' / pkg)
    if src not in sys.path:
        sys.path.insert(0, src)

from ladrc_fleet.run import peak_rss_mb  # noqa: E402
from ladrc_follow.control.params import ControllerParams  # noqa: E402
from ladrc_sim.headless.batch import batchable_scenarios  # noqa: E402
from ladrc_tools.offline.engine import client  # noqa: E402
from ladrc_tools.offline.tune import sweep, sweep_on  # noqa: E402


def axes(n: int) -> tuple[list[float], ...]:
    """Return ω0, kp, b0, TD R values whose product has about ``n`` points."""
    k = max(2, round((n / 10) ** (1 / 3)))
    return (list(np.linspace(30, 150, k)), list(np.linspace(3, 30, k)),
            list(np.linspace(0.7, 1.4, max(2, round(n / (10 * k * k))))),
            list(np.linspace(60, 150, 10)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--sets', type=int, default=5000)
    ap.add_argument('--scenarios', default=None, help='comma-separated [every batchable one]')
    ap.add_argument('--workers', type=int, default=2)
    ap.add_argument('--chunk', type=int, default=None, help='points per part [two parts '
                    'per worker, at most 2000]')
    ap.add_argument('--engine-only', action='store_true')
    a = ap.parse_args()
    base = ControllerParams()
    names = a.scenarios.split(',') if a.scenarios else batchable_scenarios()
    w0s, kps, b0s, rs = axes(a.sets)
    n = len(w0s) * len(kps) * len(b0s) * len(rs)
    print(f'{n} points x {len(names)} scenarios', flush=True)
    one = None
    one_s = None
    if not a.engine_only:
        t0 = time.perf_counter()
        one = sweep(base, w0s, kps, b0s, names, td_rs=rs)
        one_s = round(time.perf_counter() - t0, 1)
        print(f'one core: {one_s} s', flush=True)
    t0 = time.perf_counter()
    with client(workers=a.workers) as c:
        parts = sweep_on(c, base, w0s, kps, b0s, names, td_rs=rs, chunk=a.chunk)
        worker_mb = max(c.run(peak_rss_mb).values())
    engine_s = round(time.perf_counter() - t0, 1)
    print(f'engine ({a.workers} workers, parts of {a.chunk or "the default size"}): '
          f'{engine_s} s', flush=True)
    identical = None
    if one is not None:
        identical = ([x.point for x in one] == [x.point for x in parts]
                     and [x.scores for x in one] == [x.scores for x in parts]
                     and [x.rejected for x in one] == [x.rejected for x in parts]
                     and [x.front for x in one] == [x.front for x in parts])
    print(json.dumps({'points': n, 'scenarios': len(names), 'workers': a.workers,
                      'chunk': a.chunk, 'one_core_s': one_s, 'engine_s': engine_s,
                      'identical': identical, 'passed': sum(x.passed for x in parts),
                      'front': sum(x.front for x in parts),
                      'driver_peak_rss_mb': round(peak_rss_mb(), 1),
                      'worker_peak_rss_mb': round(worker_mb, 1)}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
