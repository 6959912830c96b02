"""The seed-faithful options cannot take the nozzle where the data and the limits forbid.

The target wave (SIN_GEN), ``follow.reinterpolate: false`` and the gated Kalman filter on the
PID path, each against what a review found a naive version would do.
"""

from __future__ import annotations

from dataclasses import replace

from ladrc_follow.control.follow import FollowController
from ladrc_follow.control.params import ControllerParams, params_from_dict
from ladrc_sim.headless.runner import run
from ladrc_sim.headless.scenario import scenario_from_dict
import numpy as np


def _scenario(timeline: list, duration_s: float = 2.5, gap_mm: float = 1.0, **extra) -> dict:
    return {'name': 'safety', 'duration_s': duration_s, 'seed': 4, 'initial_gap_mm': gap_mm,
            'sensor': {'noise_std_mm': 0.003, 'quant_mm': 0.001},
            'timeline': [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': gap_mm},
                         *timeline], **extra}


def test_a_target_change_ends_the_wave_so_it_never_pushes_below_the_allowed_gap():
    """Square 0.6 mm on 1.0 mm, then set_target 0.4: the wave would reach −0.2 mm; it ends."""
    sc = scenario_from_dict(_scenario([
        {'t_s': 0.5, 'do': 'target_wave', 'kind': 'square', 'amp_mm': 0.6, 'freq_hz': 2.0},
        {'t_s': 1.0, 'do': 'set_target', 'target_gap_mm': 0.4}]))
    c = FollowController()
    res = run(sc, c, record_internals=True)
    assert c.fault_reason == '' and res.metrics.collisions == 0
    assert res.true_gap_mm[int(1.2 / 0.0005):].min() > 0.3


def test_the_wave_is_clamped_to_the_allowed_gaps_when_they_change_under_it():
    """min_target_gap_mm raised to 0.9 mm mid-wave (0.6 mm on 1.0 mm): never below 0.9."""
    c = FollowController()
    tighter = replace(ControllerParams(), follow=replace(ControllerParams().follow,
                                                         min_target_gap_mm=0.9))

    class Swap:  # sets the tighter limits at 1.0 s, through the controller's own queue
        def __init__(self, inner):
            self.inner, self.done = inner, False

        def step(self, tick):
            if tick[0] >= 1.0 and not self.done:
                self.inner.set_params(tighter)
                self.done = True
            return self.inner.step(tick)

        def command(self, name, **kw):
            return self.inner.command(name, **kw)

        def internals(self):
            return self.inner.internals()

    sc = scenario_from_dict(_scenario([
        {'t_s': 0.5, 'do': 'target_wave', 'kind': 'square', 'amp_mm': 0.6, 'freq_hz': 2.0,
         'duration_s': 1.8}], duration_s=3.0))
    res = run(sc, Swap(c), record_internals=True)
    td = np.asarray(res.internals['td_x1_mm'])
    assert td[int(0.7 / 0.0005):int(1.0 / 0.0005)].min() < 0.6  # the wave ran below 0.9
    assert td[int(1.3 / 0.0005):].min() > 0.9 - 1e-9  # clamped from the swap on
    assert res.true_gap_mm[int(1.6 / 0.0005):].min() > 0.85


def test_machining_ends_a_wave_it_would_otherwise_only_pause():
    """A 1 mm square paused by machining would resume later as a 1 mm step down: it ends."""
    sc = scenario_from_dict(_scenario([
        {'t_s': 0.5, 'do': 'target_wave', 'kind': 'square', 'amp_mm': 0.5, 'freq_hz': 2.0,
         'duration_s': 5.0},
        {'t_s': 1.2, 'do': 'machining', 'on': True},
        {'t_s': 1.6, 'do': 'machining', 'on': False}], duration_s=3.0, gap_mm=1.5))
    res = run(sc, FollowController(), record_internals=True)
    td = np.asarray(res.internals['td_x1_mm'])
    assert np.ptp(td[int(0.6 / 0.0005):int(1.2 / 0.0005)]) > 0.5  # it ran
    assert np.max(np.abs(td[int(2.2 / 0.0005):] - 1.5)) < 1e-3  # and it does not come back


def test_a_wave_is_switched_off_with_the_service_defaults():
    """``follow/target_wave`` with only amp_mm 0 (kind '', freq 0): accepted as 'off'."""
    c = FollowController()
    c.command('start_follow', target_gap_mm=1.0)
    assert c.command('target_wave', kind='', amp_mm=0.0, freq_hz=0.0, freq_end_hz=0.0,
                     duration_s=0.0) == (True, 'target wave off')


def test_a_step_run_by_the_law_still_measures_closing_in_at_an_edge():
    """With `reinterpolate: false`, a 5 -> 1 mm read step over a 30 % covered edge: edge hold.

    Without an approach the closing-in would not be measured, and the nozzle would close to
    0.33 mm of true gap while the reading says 1 mm.
    """
    p = params_from_dict({'follow': {'reinterpolate': False}})
    sc = scenario_from_dict(_scenario([
        {'t_s': 0.5, 'do': 'coverage', 'value': 0.3, 'ramp_s': 0.2},
        {'t_s': 1.5, 'do': 'set_target', 'target_gap_mm': 1.0}], duration_s=3.0,
        gap_mm=5.0))
    c = FollowController(p)
    res = run(sc, c, record_internals=True)
    assert not c.fault_reason
    assert any(r.startswith('edge') for r in res.internals['hold_reason'])
    assert res.true_gap_mm.min() > 1.0


def test_a_parameter_swap_restarts_the_pids_kalman_filter():
    """on_pid off, the sheet rises 2 mm, on_pid on: no stale estimate, nothing downward."""
    base = params_from_dict({'follow': {'controller': 'pid'},
                             'kalman': {'enabled': True, 'on_pid': True}})
    off = replace(base, kalman=replace(base.kalman, on_pid=False))
    c = FollowController(base)
    h = base.h_s
    z = 10.0
    c.command('start_follow', target_gap_mm=1.0)
    low_u = 0.0
    for k in range(int(4.0 / h)):
        t = k * h
        sheet = 9.0 + 2.0 * min(max((t - 1.5) / 1.0, 0.0), 1.0)
        if k == int(1.0 / h):
            c.set_params(off)
        if k == int(3.0 / h):
            c.set_params(base)
        u = c.step((t, z - sheet, True, t, z, t, True, False))
        if t >= 2.9:
            low_u = min(low_u, u)
        z += h * u
    assert low_u > -0.5 and c.fault_reason == ''
