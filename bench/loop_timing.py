"""Closed-loop timing of the follow node against the sim node, with a bare-timer floor.

    scripts/in-env python bench/loop_timing.py [--duration 60] [--loop deadline|timer|both]

1. The floor: a bare rclpy 2 kHz steady timer on an EventsExecutor (spin_once loop),
   publishing one Float64 per tick, alone, for ``--floor`` seconds.
2. The closed loop: sim node + follow node as separate processes (isolated domain), the
   controller following at 1 mm on the ``follow_sine`` test scenario, for ``--duration``
   seconds per loop mode. A probe records follow/status and /diagnostics.

Figures: controller rate, tick period p50/p99/p99.9/max and overruns (from the status' own
period field), sensor samples the controller never received (its seq-gap counter, reported in
/diagnostics), samples it received but never used (superseded before a tick), and
sensor-stamp → command latency p50/p99 (tick time − sample stamp + compute time). Last line:
one JSON object (keys ``rate_hz``, ``period_p99_us``, ``bare_timer_period_p99_us``,
``missed_samples``, ``latency_p99_ms`` for the default loop, plus per-mode details).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import random
import sys
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'tests' / 'support'))
os.environ['ROS_DOMAIN_ID'] = str(random.randint(1, 101))
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

import rclpy  # noqa: E402
from rclpy.clock import Clock, ClockType  # noqa: E402
from rclpy.experimental import EventsExecutor  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402


def percentiles(x: np.ndarray) -> dict[str, float]:
    """p50 / p99 / p99.9 / max of ``x``."""
    if x.size == 0:
        return {'p50': float('nan'), 'p99': float('nan'), 'p999': float('nan'),
                'max': float('nan')}
    return {'p50': float(np.percentile(x, 50)), 'p99': float(np.percentile(x, 99)),
            'p999': float(np.percentile(x, 99.9)), 'max': float(x.max())}


def bare_timer(seconds: float) -> dict[str, float]:
    """Period statistics of a bare 2 kHz rclpy timer publishing a Float64 per tick."""
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


def closed_loop(seconds: float, loop: str) -> dict[str, float]:
    """Run sim + follow node for ``seconds`` of following; return the loop figures."""
    from diagnostic_msgs.msg import DiagnosticArray
    from ladrc_msgs.msg import FollowStatus
    from ladrc_msgs.srv import StartFollow
    from rosnodes import NodeProcesses, Probe

    context = rclpy.Context()
    rclpy.init(context=context)
    nodes = NodeProcesses()
    probe = Probe(context, 'loop_timing_probe')
    diags: dict[str, str] = {}
    try:
        nodes.start('follow', 'ladrc_follow', 'follow_node', '-p', f'loop:={loop}')
        scenario = ROOT / 'tests' / 'ros' / 'scenarios' / 'follow_sine.yaml'
        nodes.start('sim', 'ladrc_sim', 'sim_node', '-p', f'scenario:={scenario}',
                    '-p', 'wait_for_controller_s:=0.0')
        log = probe.record(FollowStatus, 'follow/status', keep=lambda m: (
            m.tick, m.period_us, m.compute_us, m.t_s, m.gap_stamp_s, m.gap_seq, m.overrun))

        def on_diag(msg):
            for st in msg.status:
                if st.name.startswith('ladrc_follow'):
                    diags.update({kv.key: kv.value for kv in st.values})

        probe.subscribe(DiagnosticArray, '/diagnostics', on_diag)
        if not probe.spin_until(lambda: len(log) > 100 and log[-1][5] > 0, 30.0):
            raise RuntimeError('no follow/status: ' + nodes.log('follow')[-2000:])
        probe.call(StartFollow, 'follow/start', StartFollow.Request(target_gap_mm=1.0))
        probe.spin_for(2.0)  # approach; then measure
        first = len(log)
        missed0 = float(diags.get('missed_gap_samples', 0))
        probe.spin_for(seconds)
        last = len(log)
        probe.spin_for(1.2)  # one more diagnostics message
        missed = float(diags.get('missed_gap_samples', 0)) - missed0
        cols = log[first:last]  # decoded here, off the receive path
    finally:
        probe.close()
        nodes.close()
        rclpy.try_shutdown(context=context)
    a = np.asarray(cols, dtype=float)
    ticks = a[:, 0]
    period = a[:, 1]
    latency_ms = ((a[:, 3] - a[:, 4]) * 1e3 + a[:, 2] * 1e-3)
    used = np.unique(a[:, 5])
    p = percentiles(period[1:])
    lat = percentiles(latency_ms)
    return {
        'loop': loop,
        # from the controller's own tick counter over the stamps of the first and last status
        'rate_hz': (ticks[-1] - ticks[0]) / (a[-1, 3] - a[0, 3]),
        'status_received': int(len(ticks)),
        'status_lost_to_probe': int(ticks[-1] - ticks[0] + 1 - len(ticks)),
        'period_p50_us': p['p50'], 'period_p99_us': p['p99'], 'period_p999_us': p['p999'],
        'period_max_us': p['max'],
        'overruns': int(a[:, 6].sum()),
        'missed_samples': int(missed),
        'unused_samples': int(used[-1] - used[0] + 1 - used.size),
        'latency_p50_ms': lat['p50'], 'latency_p99_ms': lat['p99'],
    }


def main() -> int:
    """Measure and print the figures; last line JSON."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--duration', type=float, default=60.0,
                    help='seconds of closed loop per loop mode [60]')
    ap.add_argument('--floor', type=float, default=10.0, help='seconds of bare timer [10]')
    ap.add_argument('--loop', default='deadline', choices=['deadline', 'timer', 'both'])
    args = ap.parse_args()
    floor = bare_timer(args.floor)
    print(f'bare timer: {floor}', file=sys.stderr)
    modes = ['deadline', 'timer'] if args.loop == 'both' else [args.loop]
    runs = {}
    for mode in modes:
        runs[mode] = closed_loop(args.duration, mode)
        print(f'{mode}: {runs[mode]}', file=sys.stderr)
    main_run = runs[modes[0]]
    out = {
        'duration_s': args.duration,
        'rate_hz': main_run['rate_hz'],
        'period_p50_us': main_run['period_p50_us'],
        'period_p99_us': main_run['period_p99_us'],
        'period_p999_us': main_run['period_p999_us'],
        'period_max_us': main_run['period_max_us'],
        'overruns': main_run['overruns'],
        'missed_samples': main_run['missed_samples'],
        'unused_samples': main_run['unused_samples'],
        'latency_p50_ms': main_run['latency_p50_ms'],
        'latency_p99_ms': main_run['latency_p99_ms'],
        'bare_timer_rate_hz': floor['rate_hz'],
        'bare_timer_period_p99_us': floor['period_p99_us'],
        'period_p99_over_bare': main_run['period_p99_us'] / floor['period_p99_us'],
        'runs': runs,
    }
    print(json.dumps(out))
    return 0


if __name__ == '__main__':
    sys.exit(main())
