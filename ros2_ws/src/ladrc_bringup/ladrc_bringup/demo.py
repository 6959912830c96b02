"""The demo (``make demo``): the showcase live on ROS, recorded to a bag, and its report.

Starts the sim node, the follow node and the recorder as separate processes on an isolated DDS
domain. By default in lock step paced to real time (the sim steps the plant only when the
controller has answered the step, never faster than the wall clock): the run is the same on
any machine, a loaded one only makes it slower. ``--free-running``: the product's own 2 kHz
deadline loop against the sim's 5 ms drive watchdog, whose timing guards this machine may
trip; the report names every fault with its reason. When the scenario ends the controller is
stopped first, then the sim, then the recorder; the report is written and the last line says
how the run ended. Exit 0 only when every node exited cleanly and the run did not end in an
undeclared FAULT.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
import time

from ladrc_bags import BagError
from ladrc_tools.offline.report import write_report

from .bringup import Bringup, isolated_env, node_specs


def main(argv: list[str] | None = None) -> int:
    """Run the demo; print the bag, the report and the run's outcome (last line)."""
    ap = argparse.ArgumentParser(prog='demo', description=__doc__.split('\n\n')[0])
    ap.add_argument('--scenario', default='showcase', help='scenario name or YAML [showcase]')
    ap.add_argument('--params', default=None, help='controller parameter file [shipped]')
    ap.add_argument('--free-running', action='store_true',
                    help="the follow node's own deadline loop instead of lock step")
    ap.add_argument('-o', '--out', default='out', help='output folder [out]')
    args = ap.parse_args(argv)

    run_dir = Path(args.out) / time.strftime('demo-%Y%m%d-%H%M%S')
    bag = run_dir / 'bag'
    run_dir.mkdir(parents=True, exist_ok=False)
    mode = 'free-running' if args.free_running else 'lock step, paced to real time'
    up = Bringup(node_specs(args.scenario, args.params, str(bag),
                            lockstep=not args.free_running, paced=True),
                 isolated_env(), log_dir=run_dir / 'logs')
    print(f'demo: running scenario {args.scenario} live ({mode}; sim + controller + '
          f'recorder), logs in {run_dir / "logs"}', file=sys.stderr)
    t0 = time.monotonic()
    early = ''
    try:
        up.start()
        while up.wait('ladrc_sim', 0.5) is None:
            dead = [n for n, p in up.procs.items() if n != 'ladrc_sim' and p.poll() is not None]
            if dead:
                early = f'{", ".join(dead)} exited early (see {run_dir / "logs"})'
                break
    except KeyboardInterrupt:
        early = 'interrupted'
    finally:
        codes = up.stop()
    run_s = time.monotonic() - t0
    try:
        report_dir = write_report(bag, run_dir / 'report', progress=True)
    except BagError as exc:
        print(f'demo: FAILED: no report: {exc}')
        return 1
    summary = json.loads((report_dir / 'report.json').read_text())
    print(f'bag:    {bag}')
    print(f'report: {report_dir / "report.md"}')
    print(json.dumps({'bag': str(bag), 'report': str(report_dir / 'report.md'), 'mode': mode,
                      'run_s': round(run_s, 1), 'exit_codes': codes,
                      'messages_lost': summary.get('messages_lost'),
                      'faults': summary['faults'], 'final_state': summary['final_state']}))
    clean = all(c == 0 for c in codes.values()) and not early
    ok = clean and summary['ok'] and summary.get('messages_lost') == 0
    problems = [early] if early else []
    if not all(c == 0 for c in codes.values()):
        problems.append(f'exit codes {codes}')
    if summary.get('messages_lost'):
        problems.append(f'{summary["messages_lost"]} messages lost')
    print(f'demo: {args.scenario}: {"ok" if ok else "FAILED"}: {summary["outcome"]}'
          + (f'; {"; ".join(problems)}' if problems else ''))
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
