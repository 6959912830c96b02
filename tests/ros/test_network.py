"""Not reachable from the network: bring-up's node processes keep their sockets on loopback.

The shipped Fast DDS profile (config/fastdds_localhost.xml, docs/safety.md): after 10 s of
following, no process bring-up started has a UDP socket bound or a TCP socket listening on an
address outside 127.0.0.0/8 (0.0.0.0 and :: count as outside). Bring-up's environment is made
from a user's that asks for the rmw's LOCALHOST range, which alone binds every interface.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

pytest.importorskip('ladrc_msgs', reason='needs the built workspace (make test)')
from ladrc_bringup.bringup import Bringup, isolated_env, node_specs  # noqa: E402
from ladrc_msgs.msg import FollowStatus  # noqa: E402
from ladrc_msgs.srv import StartFollow  # noqa: E402
from rosnodes import Probe  # noqa: E402
from sockets import exposed, sockets  # noqa: E402
import sros2_policy  # noqa: E402

SCENARIOS = Path(__file__).parent / 'scenarios'
pytestmark = pytest.mark.ros


def test_bringup_binds_no_socket_outside_loopback(monkeypatch, tmp_path):
    domain = int(os.environ['ROS_DOMAIN_ID'])  # the session's (tests/ros/conftest.py)
    probe = Probe()  # on the tests' own loopback settings (tests/ros/conftest.py)
    # the environment of a user who set nothing but the rmw's localhost range
    monkeypatch.delenv('FASTRTPS_DEFAULT_PROFILES_FILE', raising=False)
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    up = Bringup(node_specs(str(SCENARIOS / 'follow_sine.yaml'), bag=str(tmp_path / 'bag')),
                 isolated_env(domain), tmp_path / 'logs')
    try:
        up.start()
        status = probe.record(FollowStatus, 'follow/status', fields=['state', 'gap_seq'])
        assert probe.spin_until(lambda: len(status) > 200 and status[-1][1] > 0, 60.0), (
            (tmp_path / 'logs' / 'ladrc_follow.log').read_text())
        assert probe.call(StartFollow, 'follow/start',
                          StartFollow.Request(target_gap_mm=1.0)).accepted
        probe.spin_for(10.0)
        opened = {name: sockets(p.pid) for name, p in up.procs.items()}
        assert all(opened.values()), opened  # each process has its sockets, on loopback:
        outside = {name: exposed(p.pid) for name, p in up.procs.items()}
        assert not any(outside.values()), outside
        # the SROS2 policy (docs/safety.md) allows every endpoint the node set uses
        graph = probe.graph()
        assert {'/ladrc_sim', '/ladrc_follow', '/recorder'} <= set(graph), sorted(graph)
        missing = sros2_policy.uncovered(graph, sros2_policy.profiles())
        assert not missing, '\n'.join(missing)
    finally:
        try:
            probe.close()
        finally:
            up.stop()
