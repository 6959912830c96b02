"""colcon test: the controller core on its own (no simulator, no ROS).

The project's full suite is tests/ at the repository root (make test); these are the
package's own checks: the shipped parameter set is valid, a follow closes in on a simple
integrating axis and settles at the target, and invalid input stops all downward motion.
"""

import math

from ladrc_follow.control.follow import FollowController, TickInput
from ladrc_follow.control.params import ControllerParams, validate

H = 0.0005


def test_shipped_parameters_are_valid():
    assert validate(ControllerParams()) == []


def _loop(c, ticks, gap0=3.0, bad=lambda i: False):
    z, u = gap0, 0.0  # sheet at 0: gap = axis position; the axis integrates the command
    us = []
    for i in range(ticks):
        t = i * H
        valid = not bad(i)
        u = c.step(TickInput(t, z if valid else math.nan, valid, t, z, t, True, False, 0))
        z += u * H
        us.append(u)
    return z, us


def test_follow_settles_at_the_target():
    c = FollowController(ControllerParams())
    c.command('start_follow', target_gap_mm=1.0)
    z, _ = _loop(c, 6000)
    assert abs(z - 1.0) < 0.01
    assert c.followed


def test_invalid_readings_stop_downward_motion_at_once():
    c = FollowController(ControllerParams())
    c.command('start_follow', target_gap_mm=1.0)
    _, us = _loop(c, 200, bad=lambda i: i >= 100)
    assert all(u >= 0.0 for u in us[100:])
