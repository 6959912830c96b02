"""Fault injection through the headless simulator (the same runner the sim node drives)."""

from __future__ import annotations

from ladrc_follow.control.follow import FollowController
from ladrc_follow.control.params import ControllerParams
from ladrc_sim.headless import runner
from ladrc_sim.headless.scenario import scenario_from_dict
import numpy as np

FAULT = 5


def run(timeline, duration_s=3.0, **extra):
    d = dict(name='fault', duration_s=duration_s, seed=3, initial_gap_mm=3.0,
             sensor={'noise_std_mm': 0.005, 'quant_mm': 0.001},
             timeline=[{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}] + timeline)
    d.update(extra)
    c = FollowController(ControllerParams())
    res = runner.run(scenario_from_dict(d), c, record_internals=True)
    return c, res


def test_frozen_sensor_with_fresh_stamps_on_a_moving_sheet():
    """The value freezes while the sheet moves: fault on the evidence of the encoder."""
    c, res = run([{'t_s': 1.5, 'do': 'sensor_freeze', 'duration_s': 1.0}],
                 sheet={'profiles': [{'kind': 'sine', 'amp_mm': 0.3, 'freq_hz': 1.0}]})
    assert int(c.state) == FAULT and 'frozen gap reading' in c.fault_reason
    state = np.asarray(res.internals['state'])
    k = int(np.argmax(state == FAULT))
    assert np.all(np.asarray(res.command_mm_s)[k:] >= 0.0)
    assert np.min(np.asarray(res.true_gap_mm)[k:]) > 0.0


def test_contact_is_reported_as_contact_and_retracts():
    """A sheet step higher than the gap: the sensor says collision, the controller retracts."""
    c, res = run([], sheet={'profiles': [{'kind': 'step', 'size_mm': 1.2, 't_s': 1.5}]})
    assert 'the sensor reports nozzle contact' in c.fault_reason
    t = np.asarray(res.t_s)
    gap = np.asarray(res.true_gap_mm)
    assert gap[t > 2.5].min() > 1.0          # retracted 2 mm away from the sheet


class StopAfter:
    """A 'drive' that commands -50 mm/s, then orders a quick stop (the sim node's watchdog)."""

    def __init__(self, k_stop: int) -> None:
        self.k, self.k_stop = 0, k_stop

    def step(self, tick) -> float:
        self.k += 1
        return -50.0

    def command(self, name, **kwargs) -> None:
        pass

    def quick_stop(self) -> bool:
        return self.k >= self.k_stop


def test_quick_stop_brakes_at_the_axis_deceleration():
    sc = scenario_from_dict(dict(name='q', duration_s=0.3, seed=1, initial_gap_mm=50.0,
                                 timeline=[]))
    res = runner.run(sc, StopAfter(200))
    x = np.asarray(res.nozzle_mm)
    v = np.diff(x) / 0.0005
    a_max = sc.axis.a_max_mm_s2
    # at -50 mm/s and 5000 mm/s² the axis stops in 10 ms (20 ticks), not through its lag
    stop = 200 + int(np.ceil(50.0 / a_max / 0.0005)) + 2
    assert abs(v[199]) > 40.0 and np.all(np.abs(v[stop:]) < 1e-9)
