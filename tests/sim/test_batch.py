"""The batch closed loop (ladrc_sim/headless/batch.py): rows equal the scalar models."""

from __future__ import annotations

from dataclasses import replace

from ladrc_follow.control.ladrc import LADRC
from ladrc_follow.control.params import ControllerParams, ESOParams, LawParams
from ladrc_sim.headless.batch import (
    BatchUnsupported,
    batchable_scenarios,
    check_batchable,
    followed_gap_mm,
    run_batch,
)
from ladrc_sim.headless.scenario import load_scenario, scenario_from_dict
from ladrc_sim.models.axis import Axis
from ladrc_sim.models.encoder import Encoder
import numpy as np
import pytest

H = 0.0005


def _scalar_loop(sc, params):
    """Run the reference: the scalar models (Sheet, Plate, Sensor, Encoder, Axis), scalar core."""
    from ladrc_sim.headless.runner import draw_world, schedule

    n = int(round(sc.duration_s / H))
    sheet, sensor = draw_world(sc, n, H)  # the scalar runner's world
    encoder = Encoder(sc.encoder, n, H, ())
    cov = schedule(n, H, sc.initial_coverage, [(e.t_s, e.args['value'], e.args['ramp_s'])
                                               for e in sc.timeline if e.name == 'coverage'])
    target = check_batchable(sc)
    targets = np.full(n, target)
    for e in sc.timeline:
        if e.name == 'set_target':
            targets[int(round(e.t_s / H)):] = e.args['target_gap_mm']
    gap0 = followed_gap_mm(sensor, target, float(cov[0]))
    axis = Axis(sc.axis, float(sheet.base_mm[0]) + gap0, H)
    plate = sheet.plate
    core = LADRC(params)
    core.reset(target, 0.0, target, encoder.read(0, axis.position_mm))
    gaps, cmds = [], []
    for i in range(n):
        for e in sc.timeline:
            if int(round(e.t_s / H)) == i and e.name == 'plate_kick':
                plate.kick(e.args['velocity_mm_s'])
            elif int(round(e.t_s / H)) == i and e.name == 'gas':
                plate.set_gas(e.args['on'])
        gap = axis.position_mm - sheet.height_mm(i)
        reading, _, _ = sensor.measure(i, gap, float(cov[i]))
        u = core.step(reading, encoder.read(i, axis.position_mm), float(targets[i]))
        gaps.append(gap)
        cmds.append(u)
        axis.step(u)
        if plate is not None:
            plate.step(gap)
    return np.array(gaps), np.array(cmds)


@pytest.mark.parametrize('name,duration_s', [('sine_5hz', 1.0), ('step', 1.0),
                                             ('feedback_gain_noise', 1.0),
                                             ('thin_sheet', 1.8), ('edge_step_3_1', 1.3)])
def test_a_batch_of_one_equals_the_scalar_models_bit_for_bit(name, duration_s):
    sc = load_scenario(name)
    sc = replace(sc, duration_s=duration_s,
                 timeline=tuple(e for e in sc.timeline if e.t_s < duration_s))
    params = ControllerParams()
    gaps, cmds = _scalar_loop(sc, params)
    res = run_batch(sc, LADRC.batch([params]), 1)
    assert np.array_equal(res.true_gap_mm[:, 0], gaps)
    assert np.array_equal(res.command_mm_s[:, 0], cmds)


def test_rows_are_independent_and_differ_by_their_sets():
    """Each row of a batch of three equals its own batch of one, with a dead time."""
    sc = scenario_from_dict({
        'name': 'b', 'duration_s': 0.6, 'seed': 4, 'initial_gap_mm': 1.0,
        'axis': {'dead_time_ticks': 3},
        'sensor': {'noise_std_mm': 0.003, 'quant_mm': 0.001, 'lag_s': 0.001},
        'sheet': {'profiles': [{'kind': 'sine', 'amp_mm': 0.2, 'freq_hz': 3.0}]},
        'timeline': [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0},
                     {'t_s': 0.3, 'do': 'set_target', 'target_gap_mm': 1.2}]})
    sets = [replace(ControllerParams(), law=LawParams(kp=kp),
                    eso=replace(ESOParams(), gains='bandwidth', w0_rad_s=w0))
            for kp, w0 in ((10.0, 60.0), (20.0, 90.0), (5.0, 40.0))]
    res = run_batch(sc, LADRC.batch(sets), 3)
    for j, p in enumerate(sets):
        one = run_batch(sc, LADRC.batch([p]), 1)
        assert np.array_equal(res.command_mm_s[:, j], one.command_mm_s[:, 0]), j
    assert not np.array_equal(res.true_gap_mm[:, 0], res.true_gap_mm[:, 1])
    assert res.target_gap_mm[-1] == 1.2


def test_plate_and_edge_events_of_the_timeline_match_the_scalar_models():
    """Coverage ramps into the edge model and back, the gas is switched, the plate kicked."""
    sc = scenario_from_dict({
        'name': 'pe', 'duration_s': 0.8, 'seed': 6, 'initial_gap_mm': 1.0,
        'sensor': {'noise_std_mm': 0.004, 'quant_mm': 0.001, 'lag_s': 0.0002},
        'sheet': {'profiles': [{'kind': 'plate', 'natural_freq_hz': 8.0, 'gas_on_s': 0.1,
                                'kick_t_s': 0.2, 'kick_velocity_mm_s': 15.0}]},
        'timeline': [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0},
                     {'t_s': 0.15, 'do': 'coverage', 'value': 0.3, 'ramp_s': 0.1},
                     {'t_s': 0.4, 'do': 'plate_kick', 'velocity_mm_s': -10.0},
                     {'t_s': 0.5, 'do': 'gas', 'on': False},
                     {'t_s': 0.6, 'do': 'coverage', 'value': 1.0, 'ramp_s': 0.05}]})
    gaps, cmds = _scalar_loop(sc, ControllerParams())
    res = run_batch(sc, LADRC.batch([ControllerParams()]), 1)
    assert np.array_equal(res.true_gap_mm[:, 0], gaps)
    assert np.array_equal(res.command_mm_s[:, 0], cmds)
    assert res.coverage.min() == pytest.approx(0.3)
    # a row that starts over the edge starts where its reading is the target, not its gap
    sensor_sc = load_scenario('edge_step_3_1')
    res = run_batch(sensor_sc, LADRC.batch([ControllerParams()]), 1)
    assert res.true_gap_mm[0, 0] < 3.0 - 0.3


def test_each_plate_couples_to_its_own_row():
    """Two sets on the thin sheet: each plate is pushed by its own nozzle's gap."""
    sets = [ControllerParams(), replace(ControllerParams(), law=LawParams(kp=4.0))]
    res = run_batch(replace(load_scenario('thin_sheet'), duration_s=2.0), LADRC.batch(sets), 2)
    for j, p in enumerate(sets):
        one = run_batch(replace(load_scenario('thin_sheet'), duration_s=2.0),
                        LADRC.batch([p]), 1)
        assert np.array_equal(res.true_gap_mm[:, j], one.true_gap_mm[:, 0])
    assert not np.array_equal(res.true_gap_mm[:, 0], res.true_gap_mm[:, 1])


def test_scenarios_the_batch_does_not_model_are_refused_with_the_reason():
    with pytest.raises(BatchUnsupported, match='approach from 10 mm'):
        run_batch('edge_open_10_1', LADRC.batch([ControllerParams()]), 1)
    with pytest.raises(BatchUnsupported, match='miss-panel'):
        run_batch('faults', LADRC.batch([ControllerParams()]), 1)
    with pytest.raises(BatchUnsupported, match='machining'):
        run_batch('showcase', LADRC.batch([ControllerParams()]), 1)
    # everything else of the library that starts followed is modelled
    assert {'thin_sheet', 'edge_step_2_5', 'edge_step_3_1', 'sine_5hz'} <= set(
        batchable_scenarios())
