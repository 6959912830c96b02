"""Measure whether a subscriber stalls a SCHED_FIFO 2 kHz publisher (priority inversion).

    scripts/in-env python bench/repro/shm_inversion.py [--seconds 15] [--conditions ...]

The bring-up's and the tests' stalls hit the follow node and the sim node at the same moment
(both SCHED_FIFO: a busy loop cannot preempt them), and the follow node's stalled tick was
*inside* ``tick()`` (its publishes), not a late wake-up. A candidate: both publish to a
SCHED_OTHER reader (the recorder; the test's probe) over Fast DDS' shared-memory transport,
whose ports are guarded by interprocess mutexes without priority inheritance; a reader thread
preempted by a busy loop while it holds one blocks the real-time writer until the scheduler
gives the reader its CPU back (a CFS slice: milliseconds).

The experiment: the follow node's loop (bench/stalls.py's: EventsExecutor ``spin_once``
deadline loop, SCHED_FIFO 50 via ``apply_realtime``, memory locked) publishing one
``FollowStatus``-sized message per 0.5 ms, and the time each ``publish`` takes; with

* ``alone``       no subscriber, two busy loops
* ``other_shm``   a subscriber process at SCHED_OTHER (a Python callback per message, as the
                  recorder), two busy loops, Fast DDS default transports (SHM for local)
* ``other_udp``   the same with ``FASTDDS_BUILTIN_TRANSPORTS=UDPv4`` in both processes (and
                  subnet discovery: rmw_fastrtps keeps shared memory under localhost discovery)
* ``fifo_shm``    the subscriber at SCHED_FIFO 50 too (its middleware threads 51), SHM
* ``fifo_shm_idle`` the same without the busy loops
* ``fifo_udp``    the FIFO subscriber over UDPv4 only

Last stdout line: JSON, per condition: lateness p99/max, publish max, ticks late > 2/5/10 ms,
publishes longer than 1/5 ms.
"""

from __future__ import annotations

import argparse
from array import array
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from stalls import percentiles_ms, start_busy_loops, stop_busy_loops  # noqa: E402

PERIOD_NS = 500_000
CONDITIONS = ('alone', 'other_shm', 'other_udp', 'fifo_shm', 'fifo_shm_idle', 'fifo_udp')
PAYLOAD = 400  # bytes: about a FollowStatus


def publisher(seconds: float) -> dict:
    """Run the FIFO loop; return lateness and publish durations."""
    import gc

    from ladrc_contract import qos
    from ladrc_contract.qos import to_rclpy
    from ladrc_contract.realtime import apply_realtime
    import rclpy
    from rclpy.experimental import EventsExecutor
    from std_msgs.msg import UInt8MultiArray
    rclpy.init()
    node = rclpy.create_node('inversion_pub')
    pub = node.create_publisher(UInt8MultiArray, 'inversion/data', to_rclpy(qos.HIGH_RATE))
    executor = EventsExecutor()
    executor.add_node(node)
    applied, warnings = apply_realtime(50, [], True)
    msg = UInt8MultiArray(data=bytes(PAYLOAD))
    # wait for the subscriber (if any) to match
    end = time.monotonic() + 3.0
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    gc.collect()
    gc.freeze()
    n = int(seconds / (PERIOD_NS * 1e-9)) + 10
    late, pubd = array('q', bytes(8 * n)), array('q', bytes(8 * n))
    mono = time.monotonic_ns
    t_start = mono()
    events: list[tuple[float, float, float]] = []  # (s from start, late ms, publish ms)
    stop = t_start + int(seconds * 1e9)
    next_ns = mono() + PERIOD_NS
    i = 0
    while True:
        remaining = next_ns - mono()
        if remaining > 0:
            executor.spin_once(timeout_sec=remaining * 1e-9)
            continue
        now = mono()
        if now >= stop or i >= n:
            break
        late[i] = now - next_ns
        pub.publish(msg)
        pubd[i] = mono() - now
        if late[i] > 2_000_000 or pubd[i] > 1_000_000:
            events.append((round((now - t_start) * 1e-9, 4), round(late[i] * 1e-6, 3),
                           round(pubd[i] * 1e-6, 3)))
        i += 1
        next_ns += PERIOD_NS
        if mono() - next_ns > PERIOD_NS:
            next_ns = mono() + PERIOD_NS
    subs = pub.get_subscription_count()
    shm = sum('/dev/shm/fastrtps' in line for line in open('/proc/self/maps'))
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()
    lat, pd = late[:i], pubd[:i]
    p, q = percentiles_ms(lat), percentiles_ms(pd)
    return {'applied': applied, 'warnings': warnings, 'subscribers': subs, 'ticks': i,
            'fastdds_shm_mappings': shm,
            'late_p99_ms': p['p99'], 'late_max_ms': p['max'],
            'late_over_2ms': sum(1 for x in lat if x > 2_000_000),
            'late_over_5ms': sum(1 for x in lat if x > 5_000_000),
            'late_over_10ms': sum(1 for x in lat if x > 10_000_000),
            'publish_p99_ms': q['p99'], 'publish_max_ms': q['max'],
            'publishes_over_1ms': sum(1 for x in pd if x > 1_000_000),
            'publishes_over_5ms': sum(1 for x in pd if x > 5_000_000),
            'events_t_late_publish_ms': events[:30]}


def subscriber(fifo: bool) -> None:
    """Read with a Python callback per message (as the recorder), until SIGTERM."""
    from ladrc_contract.realtime import apply_realtime
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import UInt8MultiArray

    rclpy.init()
    node = rclpy.create_node('inversion_sub')
    count = [0]
    node.create_subscription(
        UInt8MultiArray, 'inversion/data', lambda m: count.__setitem__(0, count[0] + 1),
        QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                   reliability=ReliabilityPolicy.BEST_EFFORT,
                   durability=DurabilityPolicy.VOLATILE))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    if fifo:
        apply_realtime(50, [], True)
    running = [True]
    signal.signal(signal.SIGTERM, lambda *_: running.__setitem__(0, False))
    while running[0]:
        executor.spin_once(timeout_sec=0.1)
    print(json.dumps({'received': count[0]}), flush=True)


def run_condition(name: str, seconds: float) -> dict:
    """One condition: busy loops, the subscriber (if any), the publisher; its figures."""
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(90 + CONDITIONS.index(name))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    if '_udp' in name:
        # rmw_fastrtps keeps its shared-memory transport under localhost discovery whatever
        # FASTDDS_BUILTIN_TRANSPORTS says (seen in /proc/<pid>/maps): subnet discovery on a
        # domain other sessions' tests (1..101) do not use
        env['FASTDDS_BUILTIN_TRANSPORTS'] = 'UDPv4'
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SUBNET'
        env['ROS_DOMAIN_ID'] = str(210 + CONDITIONS.index(name))
    busy = start_busy_loops(0 if name.endswith('_idle') else 2)
    sub = None
    try:
        if name != 'alone':
            sub = subprocess.Popen([sys.executable, __file__, '--role', 'sub'
                                    + ('_fifo' if name.startswith('fifo') else '')],
                                   env=env, stdout=subprocess.PIPE, text=True,
                                   start_new_session=True)
            time.sleep(2.0)
        out = subprocess.run([sys.executable, __file__, '--role', 'pub', '--seconds',
                              str(seconds)], env=env, capture_output=True, text=True,
                             timeout=seconds + 60, check=False)
        received = None
        if sub is not None:
            sub.terminate()
            try:
                received = json.loads(sub.communicate(timeout=10)[0].strip().splitlines()[-1])
            except (subprocess.TimeoutExpired, IndexError, json.JSONDecodeError):
                received = None
    finally:
        if sub is not None and sub.poll() is None:
            os.killpg(sub.pid, signal.SIGKILL)
            sub.wait()
        stop_busy_loops(busy)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    r.update({'condition': name, 'subscriber_received': received,
              'loadavg': Path('/proc/loadavg').read_text().split()[0]})
    return r


def main() -> int:
    """Every condition in turn; human lines on stderr; last line JSON."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--seconds', type=float, default=15.0)
    ap.add_argument('--conditions', default=','.join(CONDITIONS))
    ap.add_argument('--role', choices=['pub', 'sub', 'sub_fifo'], help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.role == 'pub':
        print(json.dumps(publisher(args.seconds)))
        return 0
    if args.role:
        subscriber(args.role == 'sub_fifo')
        return 0
    results = {}
    for name in args.conditions.split(','):
        r = run_condition(name, args.seconds)
        results[name] = r
        print(f"{name:10s} late p99 {r['late_p99_ms']:.3f} max {r['late_max_ms']:.2f} ms, "
              f">2/5/10 ms {r['late_over_2ms']}/{r['late_over_5ms']}/{r['late_over_10ms']}; "
              f"publish p99 {r['publish_p99_ms']:.3f} max {r['publish_max_ms']:.2f} ms, "
              f">1/5 ms {r['publishes_over_1ms']}/{r['publishes_over_5ms']}; subscribers "
              f"{r['subscribers']}, received {r['subscriber_received']}, SHM mappings "
              f"{r['fastdds_shm_mappings']}; (t, late, publish): "
              f"{r['events_t_late_publish_ms'][:6]}", file=sys.stderr)
    print(json.dumps({'seconds': args.seconds, 'conditions': results}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
