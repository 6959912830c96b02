"""The sample-synchronous loop (``loop: sync``): a sender at another period than h_s is a FAULT.

The core is discretised at h_s = 0.5 ms; ticks on samples of another period would integrate its
observer and reference at the wrong rate. The probe process sends axis/feedback at 1 kHz (half
the contract's rate; a loaded machine can only make it slower, never look like 2 kHz): the
follow node must fault with the measured period in its reason.
"""

from __future__ import annotations

import pytest

pytest.importorskip('ladrc_msgs', reason='needs the built workspace (make test)')
from ladrc_msgs.msg import AxisFeedback, FollowStatus  # noqa: E402
from rosnodes import NodeProcesses, Probe  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.realtime]
HANG_S = 120.0


def test_a_sender_at_another_period_faults_the_sync_loop():
    nodes = NodeProcesses()
    nodes.start('follow', 'ladrc_follow', 'follow_node', '-p', 'loop:=sync')
    probe = Probe()
    try:
        status = probe.record(FollowStatus, 'follow/status', fields=['state', 'fault_reason'])
        assert probe.spin_until(lambda: len(status) > 100, HANG_S), nodes.log('follow')
        assert status[-1][0] == FollowStatus.STATE_IDLE
        # 3 s at 1 kHz: the node measures the period over 2 s of its receive clock
        probe.publish(AxisFeedback, 'axis/feedback', {'seq': 1, 'drive_enabled': True},
                      qos=10, count=3000, period_s=0.001, increment=['seq'])
        assert probe.spin_until(lambda: status[-1][0] == FollowStatus.STATE_FAULT, HANG_S), (
            status[-1], nodes.log('follow'))
        reason = status[-1][1]
        assert 'sample period' in reason and 'differs from the controller period' in reason, \
            reason
    finally:
        try:
            probe.close()
        finally:
            nodes.close()
