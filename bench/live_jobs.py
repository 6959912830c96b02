"""Shipped jobs live: each job on the ROS graph (``bringup --job``), beside its headless run.

Per job: ``bringup --job NAME --bag DIR`` (the sim node playing the simulated CNC, the follow
node in its deadline loop, the recorder; real time, separate processes over DDS), its figures
from the last line of bringup, and the same job headless (``ladrc job NAME``). A live run is
not equal to the headless one (the CNC reads the controller's status a cycle or two late, the
transport adds a tick): the figures are compared, not the samples (lock step is the bit-for-bit
check: tests/ros/test_lockstep.py). The bags go to a temporary folder and are deleted.

Must hold: every job runs to its end; 0 contacts except the declared tipping
part's (which ends in the retract and a feed hold); ``min_gap_over_target_cutting`` >= 0.7.

``--separate-cnc``: the CNC node plays the CNC (three processes; the headless run then is
``ladrc job --separate-cnc``, and in lock step equal to it). Each bring-up runs on a DDS domain
drawn at random from 120..200, or on ``--domain-id`` (a test's isolated domain).

Run: scripts/in-env python bench/live_jobs.py [--jobs plate_holes tipping_pair] [--lockstep]
     [--separate-cnc] [--domain-id N]
The last line of output is one JSON object: ``lockstep``, ``separate_cnc``, ``jobs`` (per job:
``live`` and ``headless`` figures, ``declared_tipping``, ``verdict``) and ``all_ok``.
"""

import argparse
import json
import os
from pathlib import Path
import random
import subprocess
import sys
import tempfile

ROOT = Path(__file__).resolve().parents[1]
for pkg in ('ladrc_contract', 'ladrc_follow', 'ladrc_sim', 'ladrc_tools', 'ladrc_bags'):
    src = str(ROOT / 'ros2_ws' / 'src' / pkg)
    if src not in sys.path:
        sys.path.insert(0, src)

from ladrc_sim.job.jobfile import find_job, shipped_jobs  # noqa: E402
from ladrc_tools.cli_job import run as run_headless  # noqa: E402

FIGURES = ('finished', 'job_time_s', 'contacts', 'faults', 'pierces',
           'min_gap_over_target_cutting', 'corner_max_down_mm', 'feed_hold_s')
BAR = 0.7


def live(name: str, folder: Path, lockstep: bool, separate: bool = False,
         domain_id: int | None = None) -> dict:
    """Run one job live with bringup; return its figures (bringup's last line)."""
    domain = random.randint(120, 200) if domain_id is None else domain_id
    cmd = ['bringup', '--job', name, '--bag', str(folder / f'{name}.bag'),
           '--logs', str(folder / f'{name}.logs'), '--domain-id', str(domain),
           '--timeout', '900'] + (['--lockstep', '--unpaced'] if lockstep else []) + (
               ['--separate-cnc'] if separate else [])
    res = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ),
                         check=False)
    lines = res.stdout.strip().splitlines()
    if res.returncode != 0 or not lines:
        print(f'{name}: bringup exit {res.returncode}: {res.stderr.strip()[-2000:]}',
              file=sys.stderr, flush=True)
        return {'finished': False, 'aborted': f'bringup exit {res.returncode}: '
                f'{res.stderr.strip()[-300:]}'}
    return json.loads(lines[-1])


def verdict(job, figures: dict) -> str:
    """Return '' if the job's figures meet the bar, else why not."""
    if not figures.get('finished') and not job.tip_parts:
        return f'not finished: {figures.get("aborted", "")}'
    if job.tip_parts:  # a declared tipping part: its contact must end in the retract
        return '' if figures.get('faults', 0) >= 1 else 'the tipping contact did not fault'
    if figures.get('contacts', 1):
        return f'{figures.get("contacts")} contacts'
    ratio = figures.get('min_gap_over_target_cutting')
    return '' if ratio is not None and ratio >= BAR else f'min gap {ratio} x target < {BAR}'


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--jobs', nargs='+', default=list(shipped_jobs()))
    ap.add_argument('--lockstep', action='store_true',
                    help='lock step, unpaced (deterministic: equal to headless)')
    ap.add_argument('--separate-cnc', action='store_true',
                    help='the CNC node plays the CNC (bringup --separate-cnc)')
    ap.add_argument('--domain-id', type=int, default=None,
                    help='ROS_DOMAIN_ID of every bring-up [random 120..200 per job]')
    a = ap.parse_args()
    rows = {}
    with tempfile.TemporaryDirectory(prefix='live-jobs-') as tmp:
        for name in a.jobs:
            job = find_job(name)
            head = run_headless(job, [], separate_cnc=a.separate_cnc).figures
            got = live(name, Path(tmp), a.lockstep, a.separate_cnc, a.domain_id)
            row = {'live': {k: got.get(k) for k in FIGURES + ('realtime_x',)},
                   'headless': {k: head.get(k) for k in FIGURES},
                   'declared_tipping': bool(job.tip_parts)}
            row['verdict'] = verdict(job, got) or 'ok'
            rows[name] = row
            print(f'{name}: live {row["live"]} | headless {row["headless"]} -> {row["verdict"]}',
                  flush=True)
    print(json.dumps({'lockstep': a.lockstep, 'separate_cnc': a.separate_cnc, 'jobs': rows,
                      'all_ok': all(r['verdict'] == 'ok' for r in rows.values())}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
