"""Test publisher for the recorder tests: the contract topics at ~2 kHz with seq counters.

Usage: python recorder_pub.py DURATION_S
Waits until every 2 kHz topic has a subscriber (the recorder), prints ``publishing`` and
publishes one message per topic per 0.5 ms tick for DURATION_S (``published <ticks>`` every
1000 ticks), then ``done <ticks>``.
"""

from __future__ import annotations

import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from ladrc_msgs.msg import (
    AxisFeedback,
    CapacitiveHeight,
    FollowEvent,
    FollowStatus,
    SimTruth,
    VelocityCommand,
)
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String


def main() -> None:
    duration_s = float(sys.argv[1])
    rclpy.init()
    node = rclpy.create_node('recorder_test_pub')
    # Reliable with a history deeper than a test publishes (the recorder subscribes reliably,
    # its reader as deep): a loaded machine can delay a message to the recorder, never lose it,
    # so the test's verdict does not depend on how the processes get scheduled. (The nodes'
    # best-effort profile is what the live runs measure: bench/loop_timing.py, make demo.)
    fast = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE)
    latched = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    run_q = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pubs = {
        'cap': node.create_publisher(CapacitiveHeight, 'axis/capacitive_height', fast),
        'fb': node.create_publisher(AxisFeedback, 'axis/feedback', fast),
        'cmd': node.create_publisher(VelocityCommand, 'axis/velocity_command', fast),
        'st': node.create_publisher(FollowStatus, 'follow/status', fast),
        'tr': node.create_publisher(SimTruth, 'sim/truth', fast),
    }
    events = node.create_publisher(FollowEvent, 'follow/events', latched)
    params = node.create_publisher(String, 'run/parameters', run_q)
    scenario = node.create_publisher(String, 'run/scenario', run_q)
    diag = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
    # latched before the recorder exists: transient local must deliver them anyway
    events.publish(FollowEvent(tick=0, kind=FollowEvent.PARAMETERS, text='h_s: 0.0005\n'))
    params.publish(String(data='h_s: 0.0005\n'))
    scenario.publish(String(data='name: recorder_test\n'))
    deadline = time.monotonic() + 120.0  # a loaded machine starts a recorder slowly
    while any(p.get_subscription_count() == 0 for p in pubs.values()):
        if time.monotonic() > deadline:
            print('no recorder subscribed within 120 s', file=sys.stderr, flush=True)
            sys.exit(1)
        time.sleep(0.05)
    time.sleep(0.5)  # let the reliable readers finish matching
    print('publishing', flush=True)
    cap, fb, cmd, st, tr = (CapacitiveHeight(), AxisFeedback(), VelocityCommand(),
                            FollowStatus(), SimTruth())
    st.state = FollowStatus.STATE_LADRC
    t0 = time.monotonic()
    i = 0
    clock = node.get_clock()
    while True:
        now = time.monotonic()
        if now - t0 >= duration_s:
            break
        if now < t0 + i * 0.0005:
            time.sleep(0.0002)
            continue
        stamp = clock.now().to_msg()
        cap.header.stamp = fb.header.stamp = cmd.header.stamp = stamp
        st.header.stamp = tr.header.stamp = stamp
        cap.seq = fb.seq = cmd.seq = tr.seq = i
        st.tick = i
        cap.gap_mm = tr.true_gap_mm = st.gap_mm = 1.0 + 1e-4 * (i % 100)
        cap.valid = True
        st.t_s = i * 0.0005
        pubs['cap'].publish(cap)
        pubs['fb'].publish(fb)
        pubs['cmd'].publish(cmd)
        pubs['st'].publish(st)
        pubs['tr'].publish(tr)
        if i % 2000 == 0:
            arr = DiagnosticArray()
            arr.header.stamp = stamp
            arr.status = [DiagnosticStatus(name='test', message='ok')]
            diag.publish(arr)
        i += 1
        if i % 1000 == 0:
            print(f'published {i}', flush=True)  # progress, in ticks
    print(f'done {i}', flush=True)
    time.sleep(0.5)
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == '__main__':
    main()
