"""Fixtures for tests that talk DDS: an isolated domain, localhost-only discovery, and rclpy.

Every test session picks its own ROS_DOMAIN_ID (from its process id) so parallel runs and other
ROS traffic on the machine never meet; discovery stays on localhost. Processes a test starts are
tracked and killed at teardown. The tests that watch nodes do it through the probe process
(tests/support/rosnodes.py: ``Probe``, a process like the nodes), so the test process runs no
rclpy; ``ros_context`` is for the tests of rclpy itself in the test process
(test_msgs_contract.py).
"""

from __future__ import annotations

import importlib.util
import os

import pytest

if importlib.util.find_spec('rclpy') is None:
    pytest.skip('needs the built workspace (make test)', allow_module_level=True)

# Domain ids 1..101 for tests (0 is the default users run on; 102+ may collide with ports of
# other tools). Set before any rclpy.init so every context and child process uses them.
# scripts/run-tests gives its pytest runs disjoint ranges (LADRC_TEST_DOMAIN_BASE and _SPAN: lane 1
# 1-50, lane 2's two lock-step steps 51-75 and 76-100) so two pytest runs of one `make test`
# never share a domain.
_BASE = int(os.environ.get('LADRC_TEST_DOMAIN_BASE', '1'))
_SPAN = int(os.environ.get('LADRC_TEST_DOMAIN_SPAN',
                           50 if 'LADRC_TEST_DOMAIN_BASE' in os.environ else 101))
os.environ['ROS_DOMAIN_ID'] = str(_BASE + os.getpid() % _SPAN)
from ladrc_bringup.bringup import loopback_settings  # noqa: E402

# this machine only: the shipped loopback profile, whatever the environment says (docs/safety.md)
os.environ.pop('FASTRTPS_DEFAULT_PROFILES_FILE', None)
os.environ.update(loopback_settings(os.environ))
os.environ.pop('ROS_LOCALHOST_ONLY', None)


@pytest.fixture()
def ros_context():
    """Yield an initialised rclpy context on the test domain; shut it down afterwards."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)
