"""Repro (3): test_follow_ladrc_parameters_and_stop ends in FAULT after ``follow/stop``.

    python bench/repro/follow_stop_fault.py [--checkout /work/oldmain] [--runs 5]
                                            [--conditions idle,busy] [--out DIR]

Runs ``tests/ros/test_follow_node.py::test_follow_ladrc_parameters_and_stop`` of the checkout
(``cd CHECKOUT && scripts/in-env python -m pytest ...``) ``--runs`` times per condition: idle
(nothing started by this script) and busy (two ``python3 -c 'while True: pass'`` for the whole
run). The test runs the follow node and the sim node with the schema's largest stale limit and
sim watchdog (100 ms), follows a sine sheet, then sets parameters through the probe's new
GetParameters/SetParameters clients and stops.

Evidence per run (bench/repro/_trace.py): the follow node's state changes with their fault
reason (the reason the test's assertion cuts off), its late ticks (period) and long callbacks
(the parameter callback runs the stability gate on the loop thread), the sim's late cycles,
command gaps and watchdog, the probe's service calls (each a new client: DDS discovery),
garbage collections over 0.5 ms, what SCHED_FIFO/mlockall the nodes were granted, and the
scheduler monitor's windows in which a node's loop thread waited for a CPU. The timeline
around the first fault goes to stderr.

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

TEST = 'tests/ros/test_follow_node.py::test_follow_ladrc_parameters_and_stop'


def one_run(checkout: Path, folder: Path, busy: bool) -> dict:
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
                      '--basetemp', str(folder / 'bt'), TEST),
            checkout, env, timeout_s=240, log_path=folder / 'pytest.log')
    finally:
        mon.stop()
        tr.stop_busy_loops(loops)
        left = tr.end_descendants()
    events = tr.read_traces(folder)
    summary = tr.summarize(events)
    follow = summary.get('follow', {})
    sim = summary.get('sim', {})
    states = follow.get('follow_states', [])
    faults = [s for s in states if s[1] == 'FAULT']
    failure = ''
    m = re.search(r'^E\s+(AssertionError.*)$', output, re.M)
    if m:
        failure = m.group(1)[:400]
    elif code != 0:
        failure = '\n'.join(output.strip().splitlines()[-3:])[:400]
    # the node logs (NodeProcesses writes them to a temp folder the test leaves behind)
    logs = {}
    started = [e for e in events if e['kind'] == 'node_started']
    if started:
        logdir = Path(started[0]['logdir'])
        for name in ('follow', 'sim'):
            p = logdir / f'{name}.log'
            if p.is_file():
                logs[name] = p.read_text(errors='replace')
    watchdog_lines = [ln for ln in logs.get('sim', '').splitlines() if 'watchdog:' in ln]
    timeline = []
    if faults:
        timeline = tr.timeline(events, mon.windows, faults[0][0], before_s=1.0, after_s=0.1)
    return {
        'passed': code == 0, 'exit_code': code, 'wall_s': round(wall, 1), 'failure': failure,
        'fault_reasons': [s[2] for s in faults],
        'states': [s[1] for s in states],
        'first_fault_t': faults[0][0] if faults else None,
        'follow_late_ticks': follow.get('follow_late_tick'),
        'follow_long_ticks': follow.get('follow_long_tick'),
        'follow_long_callbacks': follow.get('follow_long_callback'),
        'follow_set_parameters_ms': follow.get('follow_set_parameters_ms'),
        'sim_late_cycles': sim.get('sim_late_cycle'),
        'sim_command_gaps': sim.get('sim_command_gap'),
        'sim_faults': sim.get('sim_faults'),
        'watchdog_lines': watchdog_lines,
        'probe_calls': summary.get('pytest', {}).get('probe_calls'),
        'gc_long': {p: s.get('gc') for p, s in summary.items() if s.get('gc')},
        'gc_counts': {p: s.get('gc_counts') for p, s in summary.items() if s.get('gc_counts')},
        'realtime': {p: s.get('realtime') for p, s in summary.items() if s.get('realtime')},
        'monitor_policies': mon.policies,
        'monitor_waits_over_2ms': len(mon.windows),
        'foreign_rt_processes_seconds': mon.foreign_rt,
        'follow_long_ticks_blocked_in': tr.blocked_in(mon, events, min_ms=20.0)[:10],
        'monitor_worst_waits': sorted(mon.windows, key=lambda w: -max(
            w['main_thread_waited_ms'].values()))[:3],
        'patch_failed': {p: s['patch_failed'] for p, s in summary.items()
                         if s.get('patch_failed')},
        'machine': machine, 'left_over_processes': left,
        'timeline_first_fault': timeline,
    }


def main() -> int:
    """Run, print per-run lines and the timeline of each failure; last line JSON."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--checkout', type=Path, default=Path('/work/oldmain'))
    ap.add_argument('--runs', type=int, default=5, help='runs per condition [5]')
    ap.add_argument('--conditions', default='idle,busy')
    ap.add_argument('--out', type=Path, default=None, help='keep the runs here [temp]')
    args = ap.parse_args()
    tr.become_subreaper()
    out = args.out or Path(tempfile.mkdtemp(prefix='repro_follow_stop_'))
    results: dict[str, list[dict]] = {}
    for cond in args.conditions.split(','):
        results[cond] = []
        for i in range(args.runs):
            r = one_run(args.checkout.resolve(), out / f'{cond}_{i}', cond == 'busy')
            results[cond].append(r)
            late = r['follow_late_ticks'] or {}
            gaps = r['sim_command_gaps'] or {}
            print(f"{cond} run {i}: {'pass' if r['passed'] else 'FAIL'} ({r['wall_s']} s); "
                  f"faults {r['fault_reasons']}; follow late ticks {late.get('count', 0)} "
                  f"(max {late.get('max_ms', 0)} ms); sim command gaps {gaps.get('count', 0)} "
                  f"(max {gaps.get('max_ms', 0)} ms); set_parameters ms "
                  f"{r['follow_set_parameters_ms']}; watchdog {len(r['watchdog_lines'])}",
                  file=sys.stderr)
            if r['failure']:
                print(f'    failure: {r["failure"]}', file=sys.stderr)
            for line in r['timeline_first_fault']:
                print(line, file=sys.stderr)
            time.sleep(1.0)
    counts = {c: {'runs': len(rs), 'failed': sum(not r['passed'] for r in rs),
                  'fault_seen': sum(bool(r['fault_reasons']) for r in rs),
                  'watchdog_trips': sum(len(r['watchdog_lines']) for r in rs),
                  'follow_late_tick_max_ms': max(((r['follow_late_ticks'] or {}).get('max_ms', 0)
                                                  for r in rs), default=0)}
              for c, rs in results.items()}
    print(f'outputs: {out}', file=sys.stderr)
    print(json.dumps({'test': TEST, 'checkout': str(args.checkout), 'counts': counts,
                      'runs': results}, default=str))
    return 0


if __name__ == '__main__':
    sys.exit(main())
