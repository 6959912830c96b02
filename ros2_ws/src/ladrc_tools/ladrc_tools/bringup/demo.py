"""The demo (``make demo``): a live simulated run, recorded to a bag, and its report.

Starts the sim node, the follow node and the recorder as separate processes on an isolated DDS
domain with the showcase scenario (approach from 10 mm, follow at 1 mm over a wavy sheet, a sheet
edge, a thin sheet set vibrating by the assist gas), stops them in the safe order when the
scenario ends, writes the report (plots + Markdown) and prints the bag and report paths.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
import time

from ..bags.bag import BagError
from ..offline.report import write_report
from .bringup import Bringup, isolated_env, node_specs


def main(argv: list[str] | None = None) -> int:
    """Run the demo; print the bag and report paths; last line JSON."""
    ap = argparse.ArgumentParser(prog='demo', description=__doc__.split('\n\n')[0])
    ap.add_argument('--scenario', default='showcase', help='scenario name or YAML [showcase]')
    ap.add_argument('--params', default=None, help='controller parameter file [shipped]')
    ap.add_argument('-o', '--out', default='out', help='output folder [out]')
    args = ap.parse_args(argv)

    run_dir = Path(args.out) / time.strftime('demo-%Y%m%d-%H%M%S')
    bag = run_dir / 'bag'
    run_dir.mkdir(parents=True, exist_ok=False)
    up = Bringup(node_specs(args.scenario, args.params, str(bag)), isolated_env(),
                 log_dir=run_dir / 'logs')
    print(f'demo: running scenario {args.scenario} live (sim + controller + recorder), '
          f'logs in {run_dir / "logs"}', file=sys.stderr)
    t0 = time.monotonic()
    try:
        up.start()
        while up.wait('ladrc_sim', 0.5) is None:
            dead = [n for n, p in up.procs.items() if n != 'ladrc_sim' and p.poll() is not None]
            if dead:
                print(f'demo: {", ".join(dead)} exited early; see {run_dir / "logs"}',
                      file=sys.stderr)
                break
    except KeyboardInterrupt:
        print('demo: interrupted; stopping the nodes', file=sys.stderr)
    finally:
        codes = up.stop()
    run_s = time.monotonic() - t0
    try:
        report_dir = write_report(bag, run_dir / 'report', progress=True)
    except BagError as exc:
        print(f'demo: no report: {exc}', file=sys.stderr)
        return 1
    summary = json.loads((report_dir / 'report.json').read_text())
    print(f'bag:    {bag}')
    print(f'report: {report_dir / "report.md"}')
    print(json.dumps({'bag': str(bag), 'report': str(report_dir / 'report.md'),
                      'run_s': round(run_s, 1), 'exit_codes': codes,
                      'messages_lost': summary.get('messages_lost')}))
    return 0 if all(c == 0 for c in codes.values()) else 1


if __name__ == '__main__':
    sys.exit(main())
