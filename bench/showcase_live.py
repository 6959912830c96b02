"""The showcase free-running, N times: how many runs a timing guard stopped on this machine.

Each run is ``bringup --scenario SCENARIO`` with the product's defaults (the follow node's
deadline loop, the sim's 5 ms drive watchdog, the 10 ms stale-input limit), no recorder; its
outcome is the follow node's run summary (``ladrc_contract.run_log``: every fault with its
``FaultCode``, reason and input ages) from bringup's last line. A run "stopped by a timing
guard" is one whose first fault has a code of ``ladrc_contract.codes.TIMING_GUARDS``.

Run: scripts/in-env python bench/showcase_live.py [--runs 10] [--scenario showcase]
     [--domain-id N]
The last line of output is one JSON object: ``scenario``, ``runs``, ``clean_runs`` (0 faults,
ended IDLE), ``stopped_by_timing_guard``, ``other_faults`` (runs whose first fault is not a
timing guard), ``faults_by_code`` (code -> count over all runs), ``first_faults`` (per faulted
run: t_s, code, reason) and ``failed`` (runs whose bringup did not exit cleanly).
"""

import argparse
from collections import Counter
import json
import os
from pathlib import Path
import random
import subprocess
import sys

ROOT = Path(__file__).resolve().parents[1]
BIN = ROOT / 'ros2_ws' / 'install' / 'ladrc_bringup' / 'lib' / 'ladrc_bringup'
HANG_S = 600  # a bound on a hang, not on speed


def one_run(scenario: str, domain_id: int) -> dict:
    """Run bringup once; return its last line (``run``: the follow node's summary)."""
    cmd = [str(BIN / 'bringup'), '--scenario', scenario, '--domain-id', str(domain_id)]
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                          timeout=HANG_S, env=dict(os.environ), check=False)
    try:
        last = json.loads(proc.stdout.strip().splitlines()[-1])
    except (IndexError, ValueError):
        return {'exit': proc.returncode, 'run': {}}
    return {**last, 'exit': proc.returncode}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--runs', type=int, default=10)
    ap.add_argument('--scenario', default='showcase')
    ap.add_argument('--domain-id', type=int, default=None)
    a = ap.parse_args()
    clean = guard = other = failed = 0
    codes: Counter = Counter()
    first_faults = []
    for k in range(a.runs):
        domain = a.domain_id if a.domain_id is not None else random.randint(120, 200)
        res = one_run(a.scenario, domain)
        run = res.get('run') or {}
        faults = run.get('faults', [])
        codes.update(f.get('code') or 'unknown' for f in faults)
        if not run or any(c not in (0, -2, 130) for c in res.get('exit_codes', {}).values()):
            failed += 1
        if not faults and run.get('final_state') == 'IDLE':
            clean += 1
        elif faults:
            first = faults[0]
            first_faults.append({'run': k, 't_s': first['t_s'], 'code': first.get('code'),
                                 'reason': first['reason']})
            if first.get('timing_guard'):
                guard += 1
            else:
                other += 1
        print(f'run {k + 1}/{a.runs}: {res.get("outcome", "no outcome")}', file=sys.stderr)
    print(json.dumps({'scenario': a.scenario, 'runs': a.runs, 'clean_runs': clean,
                      'stopped_by_timing_guard': guard, 'other_faults': other,
                      'faults_by_code': dict(codes), 'first_faults': first_faults,
                      'failed': failed}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
