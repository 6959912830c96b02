"""Fixtures for tests that talk DDS: an isolated domain, localhost-only discovery, and rclpy.

Every test session picks its own ROS_DOMAIN_ID (from its process id) so parallel runs and other
ROS traffic on the machine never meet; discovery stays on localhost. Processes a test starts are
tracked and killed at teardown.
"""

from __future__ import annotations

import os

import pytest

rclpy = pytest.importorskip('rclpy', reason='needs the built workspace (make test)')

# Domain ids 1..101 for tests (0 is the default users run on; 102+ may collide with ports of
# other tools). Set before any rclpy.init so every context and child process uses them.
os.environ['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 101)
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.pop('ROS_LOCALHOST_ONLY', None)


@pytest.fixture()
def ros_context():
    """Yield an initialised rclpy context on the test domain; shut it down afterwards."""
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)
