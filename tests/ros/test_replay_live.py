"""A live bag (sim + follow + recorder nodes over DDS) replays bit for bit with ``ladrc replay``.

The follow node builds each tick's inputs from DDS messages arriving at real-time moments; the
bag keeps them in ``follow/status`` and the commands and parameter changes in ``follow/events``.
Replaying them through a fresh controller must reproduce every command bit, including across a
parameter change made through the parameter service while following.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import subprocess

import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from ladrc_msgs.msg import FollowEvent, FollowStatus  # noqa: E402
from ladrc_msgs.srv import StartFollow, StopFollow  # noqa: E402
from ladrc_tools.offline.replay import load_recording  # noqa: E402
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import GetParameters, SetParameters  # noqa: E402
from rosnodes import LATCHED, NodeProcesses, Probe  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
LADRC = ROOT / 'ros2_ws' / 'install' / 'ladrc_tools' / 'lib' / 'ladrc_tools' / 'ladrc'
SCENARIO = Path(__file__).parent / 'scenarios' / 'follow_sine.yaml'
pytestmark = pytest.mark.ros
S = FollowStatus


def _follow_state(m: DiagnosticArray) -> tuple[str, str] | None:
    for st in m.status:
        if st.name.startswith('ladrc_follow'):
            values = {kv.key: kv.value for kv in st.values}
            return values.get('state', ''), values.get('fault_reason', '')
    return None


def _recorded(bag: Path, topic: str) -> int:
    # messages of ``topic`` as far as metadata.yaml says (the recorder rewrites it every 5 s)
    try:
        info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return 0
    for t in info.get('topics_with_message_count') or []:
        if t['topic_metadata']['name'].lstrip('/') == topic.lstrip('/'):
            return int(t['message_count'])
    return 0


def test_live_bag_replays_bit_for_bit(ros_context, tmp_path):
    if not LADRC.exists():
        pytest.skip('ladrc console script not installed (build the workspace)')
    bag = tmp_path / 'live'
    nodes = NodeProcesses()
    probe = None
    try:
        # recorder first, so the bag holds the run from the follow node's first ticks
        nodes.start('recorder', 'ladrc_tools', 'recorder', '-p', f'output:={bag}')
        # Timeouts relaxed (stale input 10 -> 100 ms, the schema's largest; drive watchdog
        # 5 -> 200 ms) so a loaded 2-core machine still reaches LADRC; the replay is what this
        # test checks.
        nodes.start('follow', 'ladrc_follow', 'follow_node', '-p',
                    'follow.stale_timeout_s:=0.1')
        nodes.start('sim', 'ladrc_sim', 'sim_node', '-p', f'scenario:={SCENARIO}',
                    '-p', 'wait_for_controller_s:=0.0', '-p', 'watchdog_timeout_s:=0.2')
        probe = Probe(ros_context)
        # The follow state from the node's 1 Hz diagnostics (raw subscription, decoded on
        # access): a 2 kHz subscriber in the test would compete with the three nodes for the
        # two cores and make the recorder lose messages.
        diag = probe.record(DiagnosticArray, '/diagnostics', keep=_follow_state)
        events = probe.record(FollowEvent, 'follow/events', qos=LATCHED, keep=lambda m: m.kind)

        def state() -> str:
            for i in range(len(diag) - 1, -1, -1):
                if diag[i] is not None:
                    return diag[i][0]
            return ''
        assert probe.spin_until(lambda: state() == 'IDLE', 30.0), (
            nodes.log('follow') + nodes.log('sim') + nodes.log('recorder'))
        # start following only once the recorder has the status stream (discovery is per
        # topic; a command before the bag's first tick could not be replayed)
        assert probe.spin_until(lambda: _recorded(bag, 'follow/status') > 0, 30.0), (
            nodes.log('recorder'))

        res = probe.call(StartFollow, 'follow/start', StartFollow.Request(target_gap_mm=1.0))
        assert res.accepted, res.message
        # LADRC on a quiet machine; on a loaded 2-core one the sim may starve into a stale-input
        # FAULT: the replay must be exact either way, so both are fine here.
        assert probe.spin_until(lambda: state() in ('LADRC', 'FAULT'), 20.0), state()
        probe.spin_for(1.0)

        # a parameter change through the parameter service during the run
        got = probe.call(GetParameters, '/ladrc_follow/get_parameters',
                         GetParameters.Request(names=['law.kp']))
        kp = got.values[0].double_value
        req = SetParameters.Request(parameters=[Parameter(
            name='law.kp', value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                                double_value=kp * 1.3))])
        result = probe.call(SetParameters, '/ladrc_follow/set_parameters', req).results[0]
        assert result.successful, result.reason
        probe.spin_for(1.5)
        reached = diag[-1]

        assert probe.call(StopFollow, 'follow/stop', StopFollow.Request()).accepted
        assert probe.spin_until(lambda: FollowEvent.STOP_FOLLOW in list(events), 5.0)
        probe.spin_for(0.3)
        # A starved recorder may lag the probe: stop only once its bag holds the four events
        # (parameters at tick 0, start, parameter change, stop) in complete segments.
        assert probe.spin_until(lambda: _recorded(bag, 'follow/events') >= 4, 30.0), (
            nodes.log('recorder'))
        assert nodes.interrupt('follow') == 0
        assert nodes.interrupt('recorder', timeout_s=30.0) == 0, nodes.log('recorder')
        nodes.interrupt('sim')
    finally:
        if probe is not None:
            probe.close()
        nodes.close()

    # The recorder's own count of lost messages (seq gaps): a loaded machine may lose some,
    # and the replay must then say so (missing ticks) rather than pass silently.
    summary = json.loads(nodes.log('recorder').strip().splitlines()[-1])
    lost_status = summary['messages_lost_by_topic']['follow/status']

    # The bag holds what the replay must re-apply: start, the parameter change, stop.
    rec = load_recording(bag)
    states = set(rec.status['state'].tolist())
    assert states & {S.STATE_LOCKING, S.STATE_PREINTERPOLATE, S.STATE_PID, S.STATE_LADRC}, (
        states, reached)
    kinds = [e.kind for e in rec.events]
    assert FollowEvent.START_FOLLOW in kinds and FollowEvent.STOP_FOLLOW in kinds
    changes = [e for e in rec.events if e.kind == FollowEvent.PARAMETERS]
    assert changes and f'kp: {kp * 1.3}' in changes[-1].text
    assert int(rec.ticks[0]) < changes[-1].tick < int(rec.ticks[-1])

    proc = subprocess.run([str(LADRC), 'replay', str(bag)], capture_output=True, text=True,
                          timeout=300, env=dict(os.environ))
    line = json.loads(proc.stdout.strip().splitlines()[-1])
    assert line['mismatches'] == 0 and line['first_mismatch_tick'] is None, (line, proc.stdout)
    assert line['internal_mismatch_ticks'] == 0, line
    assert line['enable_mismatches'] == 0, line
    assert line['ticks'] > 2000 * 2  # seconds of 2 kHz
    assert line['missing_ticks'] == lost_status, (line, summary)
    # exit 0 only for a complete, exact replay
    assert proc.returncode == (0 if lost_status == 0 else 1), proc.stdout + proc.stderr
