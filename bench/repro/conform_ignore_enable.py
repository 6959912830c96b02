"""Repro (1): the conformance kit's ignore_enable run aborts on a drive watchdog fault.

    scripts/in-env python bench/repro/conform_ignore_enable.py [--checkout /work/oldmain]
                                  [--runs 6] [--conditions idle,busy] [--defect ignore_enable]

Runs ``tests/commissioning/test_conform_live.py::test_each_broken_driver_fails_exactly_its_rules
[ignore_enable]`` of the checkout (``cd CHECKOUT && scripts/in-env python -m pytest ...``)
``--runs`` times per condition: idle (nothing started by this script) and busy (two
``python3 -c 'while True: pass'`` for the whole run). In it the kit (``ladrc conform``, a
Python process commanding at 2 kHz, SCHED_FIFO 50 if granted, no mlockall) drives the broken
driver (the sim node with ``enable=false`` ignored; SCHED_FIFO 50, memory locked, its drive
watchdog 5 ms = 10 of its cycles).

Evidence per run: the kit's result (conform.json: rules failed and not run, abort, notes);
from its bag, the commands the kit sent and the feedback it received around the first drive
fault (largest gap between two commands sent, by the kit's own send stamps, in the 20 ms
before); from the in-process trace (bench/repro/_trace.py): the kit's gaps between two sends
and its long polls (deserializing a backlog), the driver's command gaps as received with the
command seq (contiguous: sent late; a jump: lost), its watchdog trips and late cycles,
collections, what SCHED_FIFO each process was granted, and the scheduler monitor's windows in
which a loop thread waited for a CPU; the timeline around the first trip goes to stderr.

Last stdout line: JSON with the counts per condition and every run's summary.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import re
import sys
import tempfile
import time

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _trace as tr  # noqa: E402

TEST = 'tests/commissioning/test_conform_live.py::test_each_broken_driver_fails_exactly_its_rules'


def bag_evidence(bag: Path) -> dict:
    """Commands sent and feedback received around the first drive fault (the kit's bag)."""
    try:
        from ladrc_tools.bags.bag import open_bag
        import numpy as np
    except ImportError:
        return {'bag': 'not read (run this from a checkout environment: scripts/in-env)'}
    with open_bag(bag) as b:
        cmd = b.columns('/axis/velocity_command', ['header.stamp.sec', 'header.stamp.nanosec',
                                                   'seq'])
        fb = b.columns('/axis/feedback', ['drive_fault', 'fault_reason', 'seq'])
    send = cmd['header.stamp.sec'].astype(np.int64) * 10**9 + cmd['header.stamp.nanosec']
    recv = fb['timestamp_ns']
    fault = np.flatnonzero(fb['drive_fault'].astype(bool))
    gaps = np.diff(send) * 1e-6
    out = {'commands': int(send.size), 'command_gap_max_ms': float(gaps.max()) if gaps.size
           else None, 'command_gaps_over_5ms': int((gaps > 5).sum()),
           'feedback_gap_max_ms': float(np.diff(recv).max() * 1e-6) if recv.size > 1 else None}
    if fault.size:
        t = recv[fault[0]]
        before = (send > t - 20_000_000) & (send <= t)
        g = np.diff(send[before]) * 1e-6
        out.update({'first_fault_reason': str(fb['fault_reason'][fault[0]]),
                    'first_fault_feedback_seq': int(fb['seq'][fault[0]]),
                    'command_gap_max_in_20ms_before_fault_ms': float(g.max()) if g.size else None,
                    'commands_in_20ms_before_fault': int(before.sum())})
        # the last command sent before the fault was received, and how long before
        last = send[send <= t]
        if last.size:
            out['ms_from_last_command_sent_to_fault_received'] = float((t - last[-1]) * 1e-6)
    return out


def one_run(checkout: Path, folder: Path, busy: bool, defect: str) -> dict:
    """Run the test once; return what happened."""
    folder.mkdir(parents=True)
    env = tr.trace_env(folder)
    mon = tr.Monitor()
    loops = tr.start_busy_loops(2) if busy else []
    machine = tr.machine_state()
    mon.start()
    try:
        code, output, wall = tr.run_traced(
            tr.in_env(checkout, 'python', '-m', 'pytest', '-x', '-q', '-p', 'no:cacheprovider',
                      '--basetemp', str(folder / 'bt'), f'{TEST}[{defect}]'),
            checkout, env, timeout_s=240, log_path=folder / 'pytest.log')
    finally:
        mon.stop()
        tr.stop_busy_loops(loops)
        left = tr.end_descendants()
    events = tr.read_traces(folder)
    summary = tr.summarize(events)
    kit = summary.get('kit', {})
    drv = summary.get('driver', {})
    result = {}
    reports = sorted((folder / 'bt').glob('**/conform.json'))
    if reports:
        d = json.loads(reports[-1].read_text())
        result = {'rules_failed': d.get('rules_failed'),
                  'aborted': d.get('aborted'), 'not_run': d.get('not_run'),
                  'notes': d.get('notes')}
        try:
            result['bag'] = bag_evidence(reports[-1].parent / 'bag')
        except Exception as exc:  # noqa: BLE001
            result['bag'] = {'error': f'{type(exc).__name__}: {exc}'}
        log = reports[-1].parent / 'driver.log'
        if log.is_file():
            result['driver_watchdog_lines'] = [ln for ln in log.read_text(
                errors='replace').splitlines() if 'watchdog:' in ln]
    failure = ''
    m = re.search(r'^E\s+(AssertionError.*)$', output, re.M)
    if m:
        failure = m.group(1)[:300]
    elif code != 0:
        failure = '\n'.join(output.strip().splitlines()[-3:])[:300]
    # the driver's watchdog trips; the one in the kit's silence (the watchdog test: no
    # command for 0.2 s, a send gap >= 150 ms) is expected, any other is what aborts a test
    silences = [(e['t'] - e['ms'] * 1e-3, e['t']) for e in events
                if e['kind'] == 'kit_send_gap' and e['ms'] >= 150]
    all_trips = [e for e in events if e['kind'] == 'sim_fault' and e['reason']]
    trips = [e for e in all_trips if not any(a <= e['t'] <= b for a, b in silences)]
    aborts = [e for e in events if e['kind'] == 'kit_abort']
    anchor = trips[0] if trips else None
    sends = [e['ms'] for e in events if e['kind'] == 'kit_send_gap' and e['ms'] < 150]
    timeline = tr.timeline(events, mon.windows, anchor['t'], 0.25, 0.05) if anchor else []
    return {
        'passed': code == 0, 'exit_code': code, 'wall_s': round(wall, 1), 'failure': failure,
        **result,
        'kit_aborts': [e['reason'] for e in aborts],
        'driver_watchdog_trips': [(round(e['t'] - (trips[0]['t'] if trips else 0), 3),
                                   e['reason'], e.get('ms_since_command')) for e in trips],
        'driver_watchdog_trips_in_the_silence': len(all_trips) - len(trips),
        'kit_send_gaps': {'count': len(sends), 'max_ms': max(sends, default=0),
                          'top_ms': sorted(sends, reverse=True)[:5],
                          'note': 'the silence (watchdog test) left out'},
        'kit_send_gaps_all': kit.get('kit_send_gap'),
        'kit_long_polls': kit.get('kit_long_poll'),
        'driver_command_gaps': drv.get('sim_command_gap'),
        'driver_late_cycles': drv.get('sim_late_cycle'),
        'gc_long': {p: s.get('gc') for p, s in summary.items() if s.get('gc')},
        'gc_counts': {p: s.get('gc_counts') for p, s in summary.items() if s.get('gc_counts')},
        'realtime': {p: s.get('realtime') for p, s in summary.items() if s.get('realtime')},
        'monitor_policies': mon.policies,
        'monitor_waits_over_2ms': len(mon.windows),
        'foreign_rt_processes_seconds': mon.foreign_rt,
        'kit_send_gaps_blocked_in': tr.blocked_in(mon, events, 'kit_send_gap', 'kit', 10.0)[:10],
        'monitor_worst_waits': sorted(mon.windows, key=lambda w: -max(
            w['main_thread_waited_ms'].values()))[:3],
        'machine': machine, 'left_over_processes': left,
        'timeline_first_trip': timeline,
    }


def main() -> int:
    """Run, print per-run lines and the timeline of each trip; last line JSON."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--checkout', type=Path, default=Path('/work/oldmain'))
    ap.add_argument('--runs', type=int, default=6, help='runs per condition [6]')
    ap.add_argument('--conditions', default='idle,busy')
    ap.add_argument('--defect', default='ignore_enable')
    ap.add_argument('--out', type=Path, default=None, help='keep the runs here [temp]')
    args = ap.parse_args()
    tr.become_subreaper()
    out = args.out or Path(tempfile.mkdtemp(prefix='repro_conform_'))
    results: dict[str, list[dict]] = {}
    for cond in args.conditions.split(','):
        results[cond] = []
        for i in range(args.runs):
            r = one_run(args.checkout.resolve(), out / f'{cond}_{i}', cond == 'busy',
                        args.defect)
            results[cond].append(r)
            sends = r['kit_send_gaps'] or {}
            gaps = r['driver_command_gaps'] or {}
            print(f"{cond} run {i}: {'pass' if r['passed'] else 'FAIL'} ({r['wall_s']} s); "
                  f"failed {r.get('rules_failed')}; aborted {r.get('aborted')!r}; watchdog "
                  f"trips outside the silence {len(r['driver_watchdog_trips'])}; kit send gaps "
                  f"{sends.get('count', 0)} (max {sends.get('max_ms', 0)} ms); driver command "
                  f"gaps {gaps.get('count', 0)} (max {gaps.get('max_ms', 0)} ms)",
                  file=sys.stderr)
            if r['failure']:
                print(f'    failure: {r["failure"]}', file=sys.stderr)
            for line in r['timeline_first_trip']:
                print('  ' + line[:300], file=sys.stderr)
            time.sleep(1.0)
    counts = {c: {'runs': len(rs), 'failed': sum(not r['passed'] for r in rs),
                  'runs_with_unexpected_watchdog_trip': sum(bool(r['driver_watchdog_trips'])
                                                             for r in rs),
                  'runs_aborted': sum(bool(r.get('aborted')) for r in rs),
                  'kit_send_gap_max_ms': max(((r['kit_send_gaps'] or {}).get('max_ms', 0)
                                              for r in rs), default=0)}
              for c, rs in results.items()}
    print(f'outputs: {out}', file=sys.stderr)
    print(json.dumps({'test': f'{TEST}[{args.defect}]', 'checkout': str(args.checkout),
                      'counts': counts, 'runs': results}, default=str))
    return 0


if __name__ == '__main__':
    sys.exit(main())
