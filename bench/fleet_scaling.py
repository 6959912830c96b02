"""Fleet tools on the engine: 1 vs 2 workers, per-bag cost vs ``ladrc report``, memory, flags.

    scripts/in-env python bench/fleet_scaling.py [--machines 8 --days 5 --bags-per-day 4]
        [--bag-s 8] [--seed 2] [--fleet DIR] [--report-bags 3]

Generates a fleet (``ladrc fleet-gen``'s generator on the local cluster; or reads ``--fleet``),
then in the same run reads it with ``run_fleet`` on a local cluster of 1 and of 2 worker
processes (no cache), and times ``ladrc report`` (a process per bag, plots included) on three
of its bags (``--report-bags``). Judges the flags against the fleet's truth file (which the
tool never reads): every degraded machine flagged by its rule; every healthy machine flagged
listed. The rules' limits were set on the seed-1 fleet; the default ``--seed 2`` is another
fleet.
Last line JSON: ``bags``, ``wall_s_1_worker``, ``wall_s_2_workers``, ``speedup``,
``per_bag_s`` (fleet task, mean), ``report_per_bag_s``, ``worker_peak_rss_mb``,
``degraded_flagged``, ``healthy_flagged``, ``all_degraded_flagged``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parents[1]
for pkg in ('ladrc_contract', 'ladrc_follow', 'ladrc_sim', 'ladrc_tools', 'ladrc_bags',
            'ladrc_fleet'):
    src = str(ROOT / 'ros2_ws' / 'src' / pkg)
    if src not in sys.path:
        sys.path.insert(0, src)

from ladrc_fleet.generate import FleetSpec, plan, write_bag, write_truth  # noqa: E402
from ladrc_fleet.run import run_fleet  # noqa: E402
from ladrc_tools.offline.engine import client, in_order  # noqa: E402

RULE_OF = {'gain_drift': 'sensor_gain', 'slow_axis': 'slow_axis', 'noisy_sensor': 'sensor_noise'}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--machines', type=int, default=8)
    ap.add_argument('--days', type=int, default=5)
    ap.add_argument('--bags-per-day', type=int, default=4)
    ap.add_argument('--bag-s', type=float, default=8.0)
    ap.add_argument('--seed', type=int, default=2)
    ap.add_argument('--fleet', help='an existing fleet folder (with fleet_truth.json)')
    ap.add_argument('--report-bags', type=int, default=3,
                    help='bags to time `ladrc report` on (at least 1) [3]')
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        gen_s = None
        if a.fleet:
            root = Path(a.fleet)
        else:
            root = tmp / 'fleet'
            fp = plan(FleetSpec(machines=a.machines, days=a.days, bags_per_day=a.bags_per_day,
                                bag_s=a.bag_s, seed=a.seed))
            t0 = time.perf_counter()
            with client(workers=2) as c:
                in_order(c, write_bag, fp.bags, str(root))
            gen_s = round(time.perf_counter() - t0, 1)
            write_truth(fp, root)
        truth = json.loads((root / 'fleet_truth.json').read_text())
        walls, res = {}, None
        for n in (1, 2):
            res = run_fleet([str(root)], tmp / f'out{n}', workers=n, use_cache=False)
            walls[n] = res.summary['wall_s']
            print(f'{n} worker(s): {res.summary["bags"]} bags in {walls[n]} s, worker peak '
                  f'{res.summary["worker_peak_rss_mb"]} MB', flush=True)
        ok = [r for r in res.rows if r['status'] == 'ok']
        per_bag = sum(r['task_s'] for r in ok) / len(ok)
        report_s = []
        for r in ok[:max(1, a.report_bags)]:
            t0 = time.perf_counter()
            subprocess.run([sys.executable, '-m', 'ladrc_tools.cli', 'report', r['bag'], '-o',
                            str(tmp / f'report_{len(report_s)}')], check=True,
                           capture_output=True)
            report_s.append(time.perf_counter() - t0)
        flagged: dict[str, set[str]] = {}
        for f in res.flags:
            flagged.setdefault(f['machine_id'], set()).add(f['rule'])
        degraded = {m: {'how': how, 'flagged_by': sorted(flagged.get(m, ())),
                        'found': RULE_OF[how] in flagged.get(m, set())}
                    for m, how in truth['degraded'].items()}
        healthy = {m: sorted(r) for m, r in flagged.items() if m not in truth['degraded']}
        healthy_why = [f for f in res.flags if f['machine_id'] in healthy]
        out = {'bags': res.summary['bags'], 'generate_s_2_workers': gen_s,
               'wall_s_1_worker': walls[1], 'wall_s_2_workers': walls[2],
               'speedup': round(walls[1] / walls[2], 2), 'per_bag_s': round(per_bag, 3),
               'report_per_bag_s': round(sum(report_s) / len(report_s), 3),
               'worker_peak_rss_mb': res.summary['worker_peak_rss_mb'], 'seed': a.seed,
               'degraded_flagged': degraded, 'healthy_flagged': healthy,
               'healthy_flags': healthy_why,
               'all_degraded_flagged': all(d['found'] for d in degraded.values())}
    print(json.dumps(out))
    return 0


if __name__ == '__main__':
    sys.exit(main())
