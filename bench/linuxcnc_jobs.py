"""Shipped jobs under LinuxCNC beside the simulated CNC.

Per job (default: every shipped job):

* ``headless``: ``ladrc job NAME --separate-cnc`` (the simulated CNC apart from the world, no
  ROS; deterministic);
* ``sim_live``: ``bringup --job NAME --separate-cnc`` (the simulated CNC as a node of its own,
  free-running, the live world of the LinuxCNC runs; ``--no-sim-live`` leaves it out);
* ``linuxcnc``: ``bringup --cnc linuxcnc --job NAME``, ``--runs`` times with each of
  ``--allowances`` (``allowance``: config/linuxcnc_allowance.yaml; ``product``: the product's
  timing guards, ``--allowance none``); how many ran to their end with each (``ran_to_end``).

Per run: ``job_time_s``, the holds by kind (``holds``: corner lock, void lock, commanded hold,
edge ahead; count and seconds), ``corner_max_down_mm`` (the largest excursion below the target
at corners), ``contacts``, ``faults``, ``min_gap_over_target_cutting`` (the true gap over the
target while cutting), ``pierces``, ``finished``, ``aborted``; LinuxCNC's runs add the bridge's
``moved_before_ready`` (contours whose XY left the pierce point before the controller was
ready: must be 0), ``leapfrogs``, ``m62_holds`` and ``linuxcnc_max_gap_ms``.

``blend``: one job (``--blend-job``, default plate_holes) with the post-processor's ``G64
P0.05`` and with ``G61`` (exact stop): the same figures, LinuxCNC's planner's two ways.
``foreign``: a G-code program no one here wrote, as it is (``--gcode-job``, default LinuxCNC's
own plasmatest.ngc: tests/data/linuxcnc).

Must hold: every LinuxCNC run 0 contacts (the tipping part's declared one, which
ends in the collision retract, the FAULT and the feed hold, apart) and ``moved_before_ready``
0; a run to its end: true gap >= 0.7 x the target while cutting.

Run: scripts/in-env python bench/linuxcnc_jobs.py [--jobs plate_holes ...] [--runs 2]
     [--allowances allowance,product] [--blend-job NAME|none] [--gcode-job FILE|none]
     [--no-sim-live] [--domain-id N]
The last line is one JSON object: ``jobs`` (per job: ``headless``, ``sim_live`` (or null),
``linuxcnc`` (per allowance: a list of runs), ``ran_to_end`` (per allowance: ``[ended,
runs]``), ``verdict``), ``blend`` (``job``, ``g64``, ``g61``, or null), ``foreign`` (or null),
``runs``, ``allowances``, ``all_ok``, ``wall_s``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import random
import subprocess
import sys
import tempfile
import time
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
for pkg in ('ladrc_contract', 'ladrc_linuxcnc', 'ladrc_follow', 'ladrc_sim', 'ladrc_tools',
            'ladrc_bags', 'ladrc_bringup'):
    src = str(ROOT / 'ros2_ws' / 'src' / pkg)
    if src not in sys.path:
        sys.path.insert(0, src)

from ladrc_sim.job.jobfile import find_job, shipped_jobs  # noqa: E402

FIGURES = ('job_time_s', 'holds', 'corner_max_down_mm', 'contacts', 'faults',
           'min_gap_over_target_cutting', 'pierces', 'finished', 'aborted')
BRIDGE = ('moved_before_ready', 'leapfrogs', 'linuxcnc_max_gap_ms', 'component_max_gap_ms',
          'sample_delay_ms_p99', 'pierces')
BAR = 0.7
FOREIGN = ROOT / 'tests' / 'data' / 'linuxcnc' / 'plasmatest.yaml'


def pick(figures: dict) -> dict:
    """Return the compared figures of a run."""
    out = {k: figures.get(k) for k in FIGURES}
    bridge = figures.get('linuxcnc', {}).get('bridge')
    if bridge is not None:
        out.update({f'bridge_{k}': bridge.get(k) for k in BRIDGE})
        out['m62_holds'] = bridge.get('holds')
        out['bridge_aborted'] = bridge.get('aborted')
    return out


def run(cmd: list[str], timeout_s: float) -> dict:
    """Run a command whose last stdout line is JSON; return it ({'error': ...} if none)."""
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s,
                           env=dict(os.environ), check=False)
    except subprocess.TimeoutExpired:
        return {'finished': False, 'aborted': f'timed out after {timeout_s:g} s'}
    lines = [ln for ln in r.stdout.strip().splitlines() if ln.startswith('{')]
    if not lines:
        print(f'{" ".join(cmd)}: exit {r.returncode}: {r.stderr.strip()[-1500:]}',
              file=sys.stderr, flush=True)
        return {'finished': False, 'aborted': f'exit {r.returncode}: {r.stderr.strip()[-300:]}'}
    return json.loads(lines[-1])


def domain(args: argparse.Namespace) -> list[str]:
    return ['--domain-id', str(args.domain_id if args.domain_id is not None
                               else random.randint(120, 200))]


def linuxcnc_run(job: str, args: argparse.Namespace, *extra: str) -> dict:
    """One ``bringup --cnc linuxcnc`` run; its figures."""
    with tempfile.TemporaryDirectory(prefix='linuxcnc-jobs-') as tmp:
        f = run(['bringup', '--cnc', 'linuxcnc', '--job', job, '--logs', tmp,
                 '--timeout', '900', *domain(args), *extra], 1500.0)
    return pick(f)


def verdict(job: Any, runs: dict[str, list[dict]]) -> str:
    """'' if every LinuxCNC run keeps the bar, else why not."""
    tipping = bool(getattr(job, 'tip_parts', ()))
    for name, rs in runs.items():
        for r in rs:
            if r.get('bridge_moved_before_ready'):
                return f'{name}: XY moved before ready ({r["bridge_moved_before_ready"]})'
            if r.get('contacts') and not tipping:
                return f'{name}: {r["contacts"]} contacts'
            if tipping and r.get('contacts') and not r.get('faults'):
                return f'{name}: the tipping contact did not fault'
            ratio = r.get('min_gap_over_target_cutting')
            if r.get('finished') and not (ratio is not None and ratio >= BAR):
                return f'{name}: min gap {ratio} x target < {BAR}'
    return ''


def ended(job: Any, r: dict) -> bool:
    """Return whether a run ran to its end (the tipping job: or to its declared collision)."""
    if getattr(job, 'tip_parts', ()) and 'collision' in str(r.get('aborted', '')):
        return True
    return bool(r.get('finished'))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--jobs', nargs='+', default=list(shipped_jobs()))
    ap.add_argument('--runs', type=int, default=2)
    ap.add_argument('--allowances', default='allowance,product')
    ap.add_argument('--blend-job', default='plate_holes')
    ap.add_argument('--gcode-job', default=str(FOREIGN))
    ap.add_argument('--no-sim-live', action='store_true')
    ap.add_argument('--domain-id', type=int, default=None)
    a = ap.parse_args()
    t0 = time.monotonic()
    allowances = [x for x in a.allowances.split(',') if x]
    flags = {'allowance': [], 'product': ['--allowance', 'none']}
    out: dict[str, Any] = {'jobs': {}, 'runs': a.runs, 'allowances': allowances}
    ok = True
    for name in a.jobs:
        job = find_job(name)
        entry: dict[str, Any] = {
            'headless': pick(run(['ladrc', 'job', name, '--separate-cnc'], 1800.0))}
        entry['sim_live'] = None if a.no_sim_live else pick(run(
            ['bringup', '--job', name, '--separate-cnc', '--timeout', '900', *domain(a)],
            1500.0))
        entry['linuxcnc'] = {k: [] for k in allowances}
        for k in allowances:
            for i in range(a.runs):
                r = linuxcnc_run(name, a, *flags[k])
                entry['linuxcnc'][k].append(r)
                print(f'{name} linuxcnc {k} run {i + 1}: {json.dumps(r, default=str)}',
                      flush=True)
        entry['ran_to_end'] = {k: [sum(ended(job, r) for r in rs), len(rs)]
                               for k, rs in entry['linuxcnc'].items()}
        entry['verdict'] = verdict(job, entry['linuxcnc'])
        ok = ok and not entry['verdict']
        print(f'{name}: headless {json.dumps(entry["headless"], default=str)}', flush=True)
        print(f'{name}: ran to end {entry["ran_to_end"]} verdict {entry["verdict"] or "ok"}',
              flush=True)
        out['jobs'][name] = entry
    out['blend'] = None
    if a.blend_job != 'none':
        out['blend'] = {'job': a.blend_job, 'g64': linuxcnc_run(a.blend_job, a),
                        'g61': linuxcnc_run(a.blend_job, a, '--blend-mm', '0')}
        print(f'blend: {json.dumps(out["blend"], default=str)}', flush=True)
    out['foreign'] = None
    if a.gcode_job != 'none':
        out['foreign'] = linuxcnc_run(a.gcode_job, a)
        print(f'foreign: {json.dumps(out["foreign"], default=str)}', flush=True)
    out['all_ok'] = ok
    out['wall_s'] = round(time.monotonic() - t0, 1)
    print(json.dumps(out, default=str))
    return 0


if __name__ == '__main__':
    sys.exit(main())
