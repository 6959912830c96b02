"""Headless job speed: job seconds per wall-clock second of the job loop (realtime_x).

Runs shipped jobs (``ladrc_sim.job.runner.run_job``, the same path as ``ladrc job``) with the
follow controller, geometry included (coverage, true gap, kerfs and parts every tick; the
sheet's raster fill before the loop is not counted), best of ``--repeat`` runs. A second,
timed pass wraps the controller's ``step`` to show its share of the loop (the wrapper's own
cost is in that pass only). Target: ``realtime_x >= 20`` on one core.

Run: python bench/job_speed.py [--jobs plate_holes thin_warped] [--repeat 2]
The last line of output is one JSON object: ``jobs`` (per job: ``job_time_s``, ``wall_s``,
``realtime_x``, ``controller_share``), ``realtime_x_min``, ``target_x`` and ``met``.
"""

import argparse
import json
from pathlib import Path
import sys
import time

ROOT = Path(__file__).resolve().parents[1]
for pkg in ('ladrc_contract', 'ladrc_follow', 'ladrc_sim'):
    src = str(ROOT / 'ros2_ws' / 'src' / pkg)
    if src not in sys.path:
        sys.path.insert(0, src)

from ladrc_follow.control.follow import FollowController  # noqa: E402
from ladrc_follow.control.params import params_from_dict  # noqa: E402
from ladrc_sim.job.jobfile import load_job  # noqa: E402
from ladrc_sim.job.runner import run_job  # noqa: E402

JOBS = ROOT / 'ros2_ws' / 'src' / 'ladrc_sim' / 'ladrc_sim' / 'job' / 'jobs'
TARGET_X = 20.0


def _controller(job):
    return FollowController(params_from_dict(dict(job.controller)))


def _timed_share(job) -> float:
    """Return the controller step's share of the loop's wall time (one wrapped run)."""
    ctl = _controller(job)
    step, spent = ctl.step, [0.0]

    def timed(*a, **kw):
        t0 = time.perf_counter()
        try:
            return step(*a, **kw)
        finally:
            spent[0] += time.perf_counter() - t0

    ctl.step = timed
    result = run_job(job, ctl)
    return spent[0] / result.wall_s


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--jobs', nargs='+', default=['plate_holes', 'thin_warped'])
    ap.add_argument('--repeat', type=int, default=2)
    a = ap.parse_args()
    rows = {}
    for name in a.jobs:
        job = load_job(JOBS / f'{name}.yaml')
        best = None
        for _ in range(max(1, a.repeat)):
            r = run_job(job, _controller(job))
            if best is None or r.wall_s < best.wall_s:
                best = r
        x = best.figures['job_time_s'] / best.wall_s
        share = _timed_share(job)
        rows[name] = {'job_time_s': best.figures['job_time_s'], 'wall_s': round(best.wall_s, 3),
                      'realtime_x': round(x, 2), 'controller_share': round(share, 3)}
        print(f'{name}: {best.figures["job_time_s"]:.1f} s of job in {best.wall_s:.2f} s: '
              f'{x:.1f} x real time (controller step {100 * share:.0f} % of the loop)')
    worst = min(r['realtime_x'] for r in rows.values())
    print(json.dumps({'jobs': rows, 'realtime_x_min': worst, 'target_x': TARGET_X,
                      'met': worst >= TARGET_X}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
