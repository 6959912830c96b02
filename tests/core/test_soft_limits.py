"""Soft Z travel limits (limits.soft_z_*): never commanded past, in every state."""

from __future__ import annotations

from ladrc_follow.control.follow import LIMIT_SOFT_Z, FollowController
from ladrc_follow.control.params import ControllerParams, params_from_dict, validate
from ladrc_sim.headless import runner
from ladrc_sim.headless.scenario import scenario_from_dict
import numpy as np

H = 0.0005


def _run(limits: dict, timeline, sheet=None, initial_gap_mm=3.0, duration_s=2.0):
    d = dict(name='soft', duration_s=duration_s, seed=3, initial_gap_mm=initial_gap_mm,
             sensor={'noise_std_mm': 0.005, 'quant_mm': 0.001}, timeline=timeline)
    if sheet:
        d['sheet'] = sheet
    c = FollowController(params_from_dict({'limits': limits}))
    res = runner.run(scenario_from_dict(d), c, record_internals=True)
    return (c, res, np.asarray(res.encoder_mm),
            np.nan_to_num(np.asarray(res.internals['limit_flags'], dtype=float)).astype(int))


def test_approach_stops_at_the_bottom_limit():
    # the sheet at 0, the nozzle at 3 mm, target 1 mm: the approach may go no lower than 2 mm
    c, res, z, flags = _run({'soft_z_min_mm': 2.0},
                            [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}])
    assert z.min() >= 2.0 - 0.005
    assert np.any(flags & LIMIT_SOFT_Z)
    # without the limit the same run goes down to the target (the test can fail)
    _, _, z2, _ = _run({}, [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}])
    assert z2.min() < 1.1


def test_following_a_falling_sheet_stops_at_the_bottom_limit():
    c, res, z, flags = _run(
        {'soft_z_min_mm': 0.6},
        [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}],
        sheet={'profiles': [{'kind': 'sine', 'amp_mm': 0.8, 'freq_hz': 0.5, 't_start_s': 0.5}]},
        initial_gap_mm=1.0, duration_s=3.0)
    assert z.min() >= 0.6 - 0.005
    assert np.any(flags & LIMIT_SOFT_Z)


def test_retract_stops_at_the_top_limit():
    # a sheet step up into the nozzle: the collision retract (2 mm) is cut at the top limit
    c, res, z, flags = _run(
        {'soft_z_max_mm': 1.5},
        [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}],
        sheet={'profiles': [{'kind': 'step', 'size_mm': 1.2, 't_s': 1.0}]},
        initial_gap_mm=1.0, duration_s=2.5)
    assert 'collision' in c.fault_reason
    assert z.max() <= 1.5 + 0.005
    assert np.any(flags & LIMIT_SOFT_Z)


def test_limits_must_be_ordered():
    p = params_from_dict({})
    bad = p.replace(limits=p.limits.__class__(soft_z_min_mm=5.0, soft_z_max_mm=1.0))
    assert any('soft_z_min_mm' in r for r in validate(bad))
    assert not validate(ControllerParams())
