"""colcon test: the simulated axis on its own (no controller, no ROS).

A scenario runs headless with a fixed velocity command and the axis moves by its integral
(after the velocity loop's lag); a malformed scenario is one clear error.
"""

from ladrc_sim.headless import runner
from ladrc_sim.headless.scenario import ScenarioError, scenario_from_dict
import pytest


class _Constant:
    def command(self, name, **kwargs):
        return True, ''

    def step(self, tick):
        return 2.0  # mm/s, up

    def internals(self):
        return {}


def test_axis_integrates_the_command():
    sc = scenario_from_dict({'name': 'x', 'duration_s': 1.0, 'initial_gap_mm': 1.0})
    res = runner.run(sc, _Constant())
    # 2 mm/s for 1 s, less the velocity loop's lag (T1 = 8 ms): about 1.98 mm up
    assert 1.95 < res.true_gap_mm[-1] - 1.0 < 2.0


def test_malformed_scenario_is_one_error():
    with pytest.raises(ScenarioError):
        scenario_from_dict({'name': 'x', 'duration_s': -1.0})
