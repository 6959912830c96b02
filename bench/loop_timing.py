"""Closed-loop timing of the follow node against the sim node, per loop mode, with a floor.

    scripts/in-env python bench/loop_timing.py [--duration 60] [--loops deadline,sync]
                                               [--recorder both|with|without] [--lockstep 20]
                                               [--floor 10] [--domain-id N]

1. The floor: a bare rclpy 2 kHz steady timer on an EventsExecutor (spin_once loop),
   publishing one Float64 per tick, alone, for ``--floor`` seconds.
2. Per loop mode (``deadline``, ``sync``) and recorder setting: the sim node and the
   follow node as processes (the bring-up's node set, the product's defaults: 10 ms stale
   limit, 5 ms drive watchdog, SCHED_FIFO where granted), the controller following at 1 mm on
   a 0.3 mm 1 Hz sine sheet for ``--duration`` seconds after a 3 s approach (the sim plays
   the start as the CNC would). "with": the recorder records every contract topic (a third
   2 kHz process); "without": it records only ``follow/status`` and ``axis/capacitive_height``,
   which the figures need.
3. Lock step: the same scenario in lock step, unpaced, with the full recorder and without any
   (the loop alone: sim and controller): its speed as a multiple of real time (simulated
   seconds over wall seconds of the sim's loop).

Figures per run, from the bag: rate (ticks per second of the controller's own clock), tick
period p50/p99/p99.9/max and periods over 2 ms (the status' own period field); sensor samples
never received (seq gaps of what the controller used, less those it received: the node's
``missed_gap_samples`` on /diagnostics), superseded (received, never used by a tick), reused
(a tick on the same sample as the tick before), handled later than one period (the tick ran
more than h after the sample arrived); sensor → command latency p50/p99 (the sample's stamp at
the sim → the command's stamp at the controller plus its compute time: one system clock).
Last line: one JSON object, the default loop's figures at top level (``rate_hz``,
``period_p99_us``, ``latency_p99_ms``, ``fault_ticks``, ...) with ``duration_s``,
``bare_timer_rate_hz``, ``bare_timer_period_p99_us``, ``lockstep_realtime_x`` and
``lockstep_alone_realtime_x`` (null without ``--lockstep``), every run under ``runs``, the
lock-step runs under ``lockstep`` and ``lockstep_alone``.

Each node set runs on a DDS domain of its own, drawn at random, or on ``--domain-id`` (a test's
isolated domain: tests/test_benches.py).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import random
import sys
import tempfile
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

SCENARIO = """name: loop_timing
description: bench/loop_timing.py - approach from 3 mm, follow at 1 mm over a 0.3 mm 1 Hz sine.
duration_s: {duration}
seed: 3
initial_gap_mm: 3.0
sensor: {{noise_std_mm: 0.003, quant_mm: 0.001}}
sheet:
  profiles:
    - {{kind: sine, amp_mm: 0.3, freq_hz: 1.0, t_start_s: 2.0}}
timeline:
  - {{t_s: 0.5, do: start_follow, target_gap_mm: 1.0}}
"""
WARMUP_S = 3.0
H_S = 0.0005


def percentiles(x: np.ndarray) -> dict[str, float]:
    """p50 / p99 / p99.9 / max of ``x``."""
    if x.size == 0:
        return {'p50': float('nan'), 'p99': float('nan'), 'p999': float('nan'),
                'max': float('nan')}
    return {'p50': float(np.percentile(x, 50)), 'p99': float(np.percentile(x, 99)),
            'p999': float(np.percentile(x, 99.9)), 'max': float(x.max())}


def bare_timer(seconds: float) -> dict[str, float]:
    """Period statistics of a bare 2 kHz rclpy timer publishing a Float64 per tick."""
    import rclpy
    from rclpy.clock import Clock, ClockType
    from rclpy.experimental import EventsExecutor
    from std_msgs.msg import Float64

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('bare_timer', context=context)
    pub = node.create_publisher(Float64, 'bare/tick', 10)
    stamps: list[int] = []
    msg = Float64()

    def tick():
        stamps.append(time.monotonic_ns())
        msg.data = float(len(stamps))
        pub.publish(msg)

    node.create_timer(0.0005, tick, clock=Clock(clock_type=ClockType.STEADY_TIME))
    executor = EventsExecutor(context=context)
    executor.add_node(node)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.01)
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    periods = np.diff(np.asarray(stamps)) * 1e-3
    p = percentiles(periods[100:])
    return {'rate_hz': len(stamps) / seconds, 'period_p50_us': p['p50'],
            'period_p99_us': p['p99'], 'period_p999_us': p['p999'], 'period_max_us': p['max']}


def run_node_set(folder: Path, duration_s: float, loop: str, recorder: str,
                 lockstep: bool = False,
                 domain_id: int | None = None) -> tuple[Path, dict[str, str]]:
    """Play the scenario live with the bring-up's node set; return the bag and the logs.

    The node set runs on ROS_DOMAIN_ID ``domain_id`` (default: one drawn from 1..101).
    """
    from ladrc_bringup.bringup import Bringup, isolated_env, node_specs

    scenario = folder / 'loop_timing.yaml'
    scenario.write_text(SCENARIO.format(duration=WARMUP_S + duration_s))
    bag = folder / f'bag_{loop}_{recorder}'
    specs = node_specs(str(scenario), bag=None if recorder == 'none' else str(bag), loop=loop,
                       lockstep=lockstep, paced=False)
    for spec in specs:
        if spec.name == 'ladrc_recorder' and recorder == 'without':
            spec.parameters['topics'] = ("['follow/status', 'axis/capacitive_height', "
                                         "'/diagnostics']")
    logs = folder / f'logs_{loop}_{recorder}'
    up = Bringup(specs, isolated_env(random.randint(1, 101) if domain_id is None
                                     else domain_id), logs)
    try:
        up.start()
        if up.wait('ladrc_sim', 120 + 10 * duration_s) is None:
            raise RuntimeError('the sim node did not finish')
    finally:
        up.stop()
    return bag, {p.stem: p.read_text(errors='replace') for p in logs.glob('*.log')}


def figures(bag: Path, logs: dict[str, str]) -> dict[str, float]:
    """Return the loop's figures from its bag (module docstring)."""
    from ladrc_bags import open_bag

    with open_bag(bag) as b:
        st = b.columns('follow/status', ['tick', 't_s', 'period_us', 'compute_us', 'gap_seq',
                                         'gap_stamp_s', 'header.stamp.sec',
                                         'header.stamp.nanosec', 'state', 'overrun'])
        gap = b.columns('axis/capacitive_height', ['seq', 'header.stamp.sec',
                                                   'header.stamp.nanosec'])
        status_ns = (st['header.stamp.sec'].astype(np.int64) * 1_000_000_000
                     + st['header.stamp.nanosec'])
        last_sample_ns = int((gap['header.stamp.sec'].astype(np.int64) * 1_000_000_000
                              + gap['header.stamp.nanosec']).max())
        faults: dict[str, int] = {}  # fault reason (its cause, numbers dropped) -> ticks
        for _, msg in b.messages('/follow/status'):
            stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if msg.state == 5 and stamp_ns <= last_sample_ns:
                cause = msg.fault_reason.split(':')[0].split(' (')[0][:60]
                faults[cause] = faults.get(cause, 0) + 1
        missed = []  # the follow node's count of samples it never received, at 1 Hz
        for _, msg in b.messages('/diagnostics'):
            for s in msg.status:
                if s.name.startswith('ladrc_follow'):
                    values = {kv.key: kv.value for kv in s.values}
                    missed.append(float(values.get('missed_gap_samples', 'nan')))
    # from the end of the approach to the sim's last sample (after it the sim has finished and
    # the controller, still running until the bring-up stops it, faults on stale input)
    keep = (st['t_s'] >= st['t_s'][0] + WARMUP_S) & (status_ns <= last_sample_ns)
    t = st['t_s'][keep]
    ticks = st['tick'][keep].astype(np.int64)
    period = st['period_us'][keep]
    compute = st['compute_us'][keep]
    gseq = st['gap_seq'][keep].astype(np.int64)
    wait_s = t - st['gap_stamp_s'][keep]
    stamp_ns = (st['header.stamp.sec'][keep].astype(np.int64) * 1_000_000_000
                + st['header.stamp.nanosec'][keep])
    # the sensor stamp of the sample each tick used
    g_ns = dict(zip(gap['seq'].astype(np.int64).tolist(),
                    (gap['header.stamp.sec'].astype(np.int64) * 1_000_000_000
                     + gap['header.stamp.nanosec']).tolist(), strict=True))
    sample_ns = np.array([g_ns.get(s, -1) for s in gseq.tolist()], dtype=np.int64)
    known = sample_ns >= 0
    latency_ms = ((stamp_ns - sample_ns) * 1e-6 + compute * 1e-3)[known]
    # consecutive ticks both in the bag (a recorder may lose some: they do not count)
    pair = np.diff(ticks) == 1
    dseq = np.diff(gseq)[pair]
    skipped = int(np.maximum(dseq - 1, 0).sum())
    never_received = int(missed[-1] - missed[1]) if len(missed) > 3 else -1
    # the never-received count covers the whole run; scale it to the pairs seen
    seen = pair.sum() / max(1, ticks[-1] - ticks[0])
    p = percentiles(period[1:])
    lat = percentiles(latency_ms)
    states = st['state'][keep]
    return {
        'rate_hz': float((ticks[-1] - ticks[0]) / (t[-1] - t[0])),
        'ticks': int(ticks.size),
        'period_p50_us': p['p50'], 'period_p99_us': p['p99'], 'period_p999_us': p['p999'],
        'period_max_us': p['max'],
        # the tick's own work (inputs -> core -> command), the status' compute time
        'compute_p50_us': float(np.percentile(compute, 50)),
        'compute_p99_us': float(np.percentile(compute, 99)),
        'periods_over_2ms': int((period > 2000.0).sum()),
        'overruns': int(st['overrun'][keep].sum()),
        # over consecutive ticks: samples the sim sent that no tick used (never received by the
        # controller: its seq-gap count on /diagnostics; the rest superseded by a newer one
        # before a tick), ticks on the sample of the tick before, ticks more than one period
        # after their sample arrived
        'tick_pairs_seen': int(pair.sum()),
        'samples_never_used': skipped,
        'samples_never_received': never_received,
        'samples_superseded': int(max(0, skipped - max(never_received, 0) * seen)),
        'samples_reused': int((dseq == 0).sum()),
        'samples_handled_late': int((wait_s > H_S).sum()),
        'status_lost_by_recorder': int(ticks[-1] - ticks[0] + 1 - ticks.size),
        'latency_p50_ms': lat['p50'], 'latency_p99_ms': lat['p99'],
        'fault_ticks': int((states == 5).sum()),
        'fault_causes': faults,
        'watchdog_trips': sum(line.count('watchdog:') for line in
                              logs.get('ladrc_sim', '').splitlines()),
    }


def lockstep_speed(folder: Path, duration_s: float, recorder: str = 'with',
                   domain_id: int | None = None) -> dict[str, float]:
    """Lock step (``recorder`` 'with' or 'none'): simulated over wall seconds of the sim."""
    bag, logs = run_node_set(folder, duration_s, 'lockstep', recorder, lockstep=True,
                             domain_id=domain_id)
    lines = [line for line in logs['ladrc_sim'].splitlines() if '[ladrc_sim]: scenario' in line]

    def stamp(line: str) -> float:
        return float(line.split('[')[2].split(']')[0])

    wall = stamp(lines[-1]) - stamp(lines[0])
    sim_s = WARMUP_S + duration_s
    out = {'sim_s': sim_s, 'wall_s': wall, 'realtime_x': sim_s / wall}
    if recorder != 'none':
        out['messages_lost'] = json.loads((bag / 'recording.json').read_text())['messages_lost']
    return out


def main() -> int:
    """Measure and print the figures; last line JSON."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--duration', type=float, default=60.0,
                    help='seconds of following measured per run [60]')
    ap.add_argument('--floor', type=float, default=10.0, help='seconds of bare timer [10]')
    ap.add_argument('--loops', default='deadline,sync',
                    help='loop modes, comma separated; the first is reported at top level')
    ap.add_argument('--recorder', default='both', choices=['both', 'with', 'without'])
    ap.add_argument('--lockstep', type=float, default=20.0,
                    help='simulated seconds of the lock-step speed run; 0: none [20]')
    ap.add_argument('--domain-id', type=int, default=None,
                    help='ROS_DOMAIN_ID of the node sets [random 1..101, a new one per run]')
    args = ap.parse_args()
    os.environ.setdefault('PYTHONUNBUFFERED', '1')
    floor = bare_timer(args.floor)
    print(f'bare timer: {floor}', file=sys.stderr)
    recs = ['without', 'with'] if args.recorder == 'both' else [args.recorder]
    runs: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix='loop_timing_') as tmp:
        for loop in args.loops.split(','):
            for rec in recs:
                folder = Path(tmp) / f'{loop}_{rec}'
                folder.mkdir()
                bag, logs = run_node_set(folder, args.duration, loop, rec,
                                         domain_id=args.domain_id)
                runs[f'{loop}/{rec}_recorder'] = figures(bag, logs)
                print(f'{loop}, {rec} recorder: {runs[f"{loop}/{rec}_recorder"]}',
                      file=sys.stderr)
        lock = alone = None
        if args.lockstep > 0:
            folder = Path(tmp) / 'lockstep'
            folder.mkdir()
            lock = lockstep_speed(folder, args.lockstep, domain_id=args.domain_id)
            print(f'lock step: {lock}', file=sys.stderr)
            folder = Path(tmp) / 'lockstep_alone'
            folder.mkdir()
            alone = lockstep_speed(folder, args.lockstep, 'none', domain_id=args.domain_id)
            print(f'lock step, no recorder: {alone}', file=sys.stderr)
    main_run = runs[next(iter(runs))]
    out = {'duration_s': args.duration, **main_run,
           'bare_timer_rate_hz': floor['rate_hz'],
           'bare_timer_period_p99_us': floor['period_p99_us'],
           'lockstep_realtime_x': lock['realtime_x'] if lock else None,
           'lockstep_alone_realtime_x': alone['realtime_x'] if alone else None,
           'runs': runs, 'lockstep': lock, 'lockstep_alone': alone}
    print(json.dumps(out))
    return 0


if __name__ == '__main__':
    sys.exit(main())
