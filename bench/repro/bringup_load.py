"""Repro (5): the product's bring-up on a flat sheet, defaults, with and without busy loops.

    scripts/in-env python bench/repro/bringup_load.py [--checkout /work/oldmain] [--runs 3]
                                  [--conditions idle,busy1,busy2] [--duration 20] [--out DIR]

Runs ``cd CHECKOUT && scripts/in-env bringup --scenario FLAT --bag B --logs L`` ``--runs``
times per condition (``idle``: nothing started by this script; ``busyN``: N
``python3 -c 'while True: pass'`` for the whole run; the issue's case is ``busy1``). The
product defaults hold: 10 ms stale limit, 5 ms drive watchdog, SCHED_FIFO where granted,
memory locked; the bring-up's recorder records every contract topic (the demo's node set).
FLAT: approach from 3 mm, ``start_follow`` 1 mm at 0.5 s, a flat sheet, ``--duration`` s.

Per run, from the bag (``follow/status``: state, fault_reason, period_us, input_age_us,
overrun; ``/diagnostics`` of both nodes: the follow node's ``realtime``, the sim's
``late_ticks`` and ``watchdog_trips``), the sim log (``watchdog:`` lines), the in-process trace
and the scheduler monitor (bench/repro/_trace.py): whether the controller reached LADRC before
its first FAULT and that fault's reason, drive watchdog trips, tick period max, input age max,
overruns, the follow node's late ticks and the sim's command gaps (with the command seq: not
sent, or lost), collections, SCHED_FIFO granted, and the timeline around the first watchdog
trip or fault (stderr).

Run it from a checkout's environment (it reads the bags with ``ladrc_tools.bags``); the
bring-up runs in ``--checkout``'s own. Last stdout line: JSON, counts per condition and runs.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _trace as tr  # noqa: E402

FLAT = """name: repro_flat
description: bench/repro - approach from 3 mm, follow at 1 mm on a flat sheet.
duration_s: {duration}
seed: 3
initial_gap_mm: 3.0
sensor: {{noise_std_mm: 0.003, quant_mm: 0.001}}
timeline:
  - {{t_s: 0.5, do: start_follow, target_gap_mm: 1.0}}
"""
STATE = {0: 'IDLE', 1: 'LOCKING', 2: 'PREINTERPOLATE', 3: 'PID', 4: 'LADRC', 5: 'FAULT'}


def bag_figures(bag: Path) -> dict:
    """Return what the bag says: states, faults, period and input age, both nodes' diagnostics."""
    from ladrc_tools.bags.bag import open_bag

    with open_bag(bag) as b:
        st = b.columns('follow/status', ['tick', 't_s', 'state', 'period_us', 'input_age_us',
                                         'overrun', 'fault_reason', 'header.stamp.sec',
                                         'header.stamp.nanosec'])
        truth = b.columns('sim/truth', ['header.stamp.sec', 'header.stamp.nanosec'])
        follow_diag, sim_diag = [], []
        for _, msg in b.messages('/diagnostics'):
            for s in msg.status:
                values = {kv.key: kv.value for kv in s.values}
                if 'follow loop' in s.name:
                    follow_diag.append(values)
                elif 'drive' in s.name:
                    sim_diag.append(values)
    # the run proper: from the sim's first sample to its last (it ends the scenario and exits;
    # the controller then sees stale input and faults, as it must: not counted)
    stamp = st['header.stamp.sec'] + st['header.stamp.nanosec'] * 1e-9
    t_truth = truth['header.stamp.sec'] + truth['header.stamp.nanosec'] * 1e-9
    keep = (stamp >= t_truth[0]) & (stamp <= t_truth[-1] - 0.005)
    end_fault = bool((st['state'][stamp > t_truth[-1]] == 5).any())
    st = {k: v[keep] for k, v in st.items()}
    state = st['state'].astype(int)
    fault = np.flatnonzero(state == 5)
    ladrc = np.flatnonzero(state == 4)
    first_fault = int(fault[0]) if fault.size else None
    reasons = []
    for i in range(1, state.size):
        if state[i] == 5 and state[i - 1] != 5:
            reasons.append((round(float(st['t_s'][i]), 3), str(st['fault_reason'][i])))
    if state.size and state[0] == 5:
        reasons.insert(0, (round(float(st['t_s'][0]), 3), str(st['fault_reason'][0])))
    ticks = st['tick'].astype(np.int64)
    period = st['period_us'][1:] * 1e-3
    age = st['input_age_us'] * 1e-3
    age = age[np.isfinite(age) & (age >= 0)]
    over_t = (stamp[keep][st['overrun'].astype(bool)] - t_truth[0]) % 1.0
    last_f = follow_diag[-1] if follow_diag else {}
    last_s = sim_diag[-1] if sim_diag else {}
    return {
        'status_messages': int(state.size),
        'status_lost_by_recorder': int(ticks[-1] - ticks[0] + 1 - ticks.size) if ticks.size
        else None,
        'reached_ladrc': bool(ladrc.size),
        'fault_before_ladrc': bool(fault.size and (not ladrc.size or fault[0] < ladrc[0])),
        'fault_transitions': reasons,
        'first_fault_t_s': float(st['t_s'][first_fault]) if first_fault is not None else None,
        'states_seen': [STATE.get(int(s), str(s)) for i, s in enumerate(state)
                        if i == 0 or s != state[i - 1]][:20],
        'tick_period_max_ms': float(period.max()) if period.size else math.nan,
        'tick_period_p999_ms': float(np.percentile(period, 99.9)) if period.size else math.nan,
        'periods_over_5ms': int((period > 5).sum()),
        'periods_over_10ms': int((period > 10).sum()),
        'input_age_max_ms': float(age.max()) if age.size else math.nan,
        'overruns': int(st['overrun'].sum()),
        # overruns by their phase in the second (a 1 Hz timer on the loop thread shows as one
        # phase): the share within 20 ms of the most common phase
        'overruns_same_phase': int(np.sum(np.abs(((over_t - np.median(over_t)) + 0.5) % 1.0
                                                 - 0.5) < 0.02)) if over_t.size else 0,
        'fault_after_the_sim_ended': end_fault,
        'follow_realtime': last_f.get('realtime'),
        'follow_diag_period_max_us': max((float(d.get('period_max_us', 'nan'))
                                          for d in follow_diag), default=math.nan),
        'follow_diag_overruns': last_f.get('overruns'),
        'sim_late_ticks': last_s.get('late_ticks'),
        'sim_watchdog_trips_diag': last_s.get('watchdog_trips'),
    }


def one_run(checkout: Path, folder: Path, busy: int, duration: float) -> dict:
    """One bring-up; return what happened."""
    folder.mkdir(parents=True)
    scenario = folder / 'flat.yaml'
    scenario.write_text(FLAT.format(duration=duration))
    env = tr.trace_env(folder)
    mon = tr.Monitor()
    loops = tr.start_busy_loops(busy)
    machine = tr.machine_state()
    mon.start()
    try:
        code, output, wall = tr.run_traced(
            tr.in_env(checkout, 'bringup', '--scenario', str(scenario), '--bag',
                      str(folder / 'bag'), '--logs', str(folder / 'logs'),
                      '--timeout', str(duration + 90)),
            checkout, env, timeout_s=duration + 150, log_path=folder / 'bringup.log')
    finally:
        mon.stop()
        tr.stop_busy_loops(loops)
        left = tr.end_descendants()
    events = tr.read_traces(folder)
    summary = tr.summarize(events)
    sim_log = (folder / 'logs' / 'ladrc_sim.log').read_text(errors='replace') if (
        folder / 'logs' / 'ladrc_sim.log').is_file() else ''
    watchdog = [ln for ln in sim_log.splitlines() if 'watchdog:' in ln]
    try:
        figs = bag_figures(folder / 'bag')
    except Exception as exc:  # noqa: BLE001 - a broken run is a result too
        figs = {'bag_error': f'{type(exc).__name__}: {exc}'}
    follow = summary.get('follow', {})
    sim = summary.get('sim', {})
    # the moment to look at: the first watchdog trip, else the first fault
    trip = tr.first(events, 'sim_fault', lambda e: bool(e['reason']))
    fault = tr.first(events, 'follow_state', lambda e: e['state'] == 'FAULT')
    anchor = trip or fault
    timeline = tr.timeline(events, mon.windows, anchor['t'], 0.3, 0.1) if anchor else []
    return {
        'exit_code': code, 'wall_s': round(wall, 1), 'busy_loops': busy,
        'watchdog_trips': len(watchdog), 'watchdog_lines': watchdog[:6], **figs,
        'trace_fault_reasons': [s[2] for s in follow.get('follow_states', [])
                                if s[1] == 'FAULT'],
        'follow_late_ticks': follow.get('follow_late_tick'),
        'follow_long_ticks': follow.get('follow_long_tick'),
        'follow_long_callbacks': follow.get('follow_long_callback'),
        'sim_late_cycles': sim.get('sim_late_cycle'),
        'sim_command_gaps': sim.get('sim_command_gap'),
        'gc_long': {p: s.get('gc') for p, s in summary.items() if s.get('gc')},
        'gc_counts': {p: s.get('gc_counts') for p, s in summary.items() if s.get('gc_counts')},
        'realtime': {p: s.get('realtime') for p, s in summary.items() if s.get('realtime')},
        'monitor_policies': mon.policies,
        'monitor_waits_over_2ms': len(mon.windows),
        'foreign_rt_processes_seconds': mon.foreign_rt,
        'follow_long_ticks_blocked_in': tr.blocked_in(mon, events, min_ms=20.0)[:10],
        'monitor_worst_waits': sorted(mon.windows, key=lambda w: -max(
            w['main_thread_waited_ms'].values()))[:3],
        'machine': machine, 'left_over_processes': left,
        'timeline': timeline, 'anchor': anchor and anchor['kind'],
        'bringup_tail': output.strip().splitlines()[-2:],
    }


def main() -> int:
    """Run, print per-run lines and timelines; last line JSON."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--checkout', type=Path, default=Path('/work/oldmain'))
    ap.add_argument('--runs', type=int, default=3, help='runs per condition [3]')
    ap.add_argument('--conditions', default='idle,busy1,busy2',
                    help='idle and/or busyN (N busy loops) [idle,busy1,busy2]')
    ap.add_argument('--duration', type=float, default=20.0, help='scenario seconds [20]')
    ap.add_argument('--out', type=Path, default=None, help='keep the runs here [temp]')
    args = ap.parse_args()
    tr.become_subreaper()
    out = args.out or Path(tempfile.mkdtemp(prefix='repro_bringup_'))
    results: dict[str, list[dict]] = {}
    for cond in args.conditions.split(','):
        busy = 0 if cond == 'idle' else int(cond.removeprefix('busy'))
        results[cond] = []
        for i in range(args.runs):
            r = one_run(args.checkout.resolve(), out / f'{cond}_{i}', busy, args.duration)
            results[cond].append(r)
            late = r['follow_late_ticks'] or {}
            gaps = r['sim_command_gaps'] or {}
            print(f"{cond} run {i}: watchdog trips {r['watchdog_trips']}, reached LADRC "
                  f"{r.get('reached_ladrc')}, FAULT before LADRC {r.get('fault_before_ladrc')}, "
                  f"faults {r.get('fault_transitions')}; tick period max "
                  f"{r.get('tick_period_max_ms', math.nan):.1f} ms, input age max "
                  f"{r.get('input_age_max_ms', math.nan):.1f} ms, overruns {r.get('overruns')}; "
                  f"follow late ticks {late.get('count', 0)} (max {late.get('max_ms', 0)} ms), "
                  f"sim command gaps {gaps.get('count', 0)} (max {gaps.get('max_ms', 0)} ms); "
                  f"realtime {r.get('follow_realtime')}", file=sys.stderr)
            if r.get('bag_error'):
                print(f"    bag: {r['bag_error']}", file=sys.stderr)
            if r['timeline']:
                print(f"    around the first {r['anchor']}:", file=sys.stderr)
                for line in r['timeline']:
                    print('  ' + line[:300], file=sys.stderr)
            time.sleep(1.0)
    counts = {}
    for c, rs in results.items():
        counts[c] = {
            'runs': len(rs),
            'runs_with_watchdog_trip': sum(r['watchdog_trips'] > 0 for r in rs),
            'watchdog_trips': sum(r['watchdog_trips'] for r in rs),
            'runs_fault_before_ladrc': sum(bool(r.get('fault_before_ladrc')) for r in rs),
            'runs_with_fault': sum(bool(r.get('fault_transitions')) for r in rs),
            'tick_period_max_ms': max((r.get('tick_period_max_ms', 0) for r in rs), default=0),
            'input_age_max_ms': max((r.get('input_age_max_ms', 0) for r in rs), default=0),
            'overruns': sum(r.get('overruns') or 0 for r in rs)}
    print(f'outputs: {out}', file=sys.stderr)
    print(json.dumps({'checkout': str(args.checkout), 'counts': counts, 'runs': results},
                     default=str))
    return 0


if __name__ == '__main__':
    sys.exit(main())
