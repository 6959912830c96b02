"""The batch closed loop (ladrc_sim/headless/batch.py): rows equal the scalar models."""

from __future__ import annotations

from dataclasses import replace

from ladrc_follow.control.ladrc import LADRC
from ladrc_follow.control.params import ControllerParams, ESOParams, LawParams
from ladrc_sim.headless.batch import BatchUnsupported, check_batchable, run_batch
from ladrc_sim.headless.scenario import load_scenario, scenario_from_dict
from ladrc_sim.models.axis import Axis
from ladrc_sim.models.encoder import Encoder
import numpy as np
import pytest

H = 0.0005


def _scalar_loop(sc, params):
    """Run the reference: the scalar models (Sheet, Sensor, Encoder, Axis), the scalar core."""
    from ladrc_sim.headless.runner import draw_world

    n = int(round(sc.duration_s / H))
    sheet, sensor = draw_world(sc, n, H)  # the scalar runner's world
    encoder = Encoder(sc.encoder, n, H, ())
    target = check_batchable(sc)
    targets = np.full(n, target)
    for e in sc.timeline:
        if e.name == 'set_target':
            targets[int(round(e.t_s / H)):] = e.args['target_gap_mm']
    axis = Axis(sc.axis, float(sheet.base_mm[0]) + target, H)
    core = LADRC(params)
    core.reset(target, 0.0, target, encoder.read(0, axis.position_mm))
    gaps, cmds = [], []
    for i in range(n):
        gap = axis.position_mm - sheet.base_mm[i]
        reading, _, _ = sensor.measure(i, gap, 1.0)
        u = core.step(reading, encoder.read(i, axis.position_mm), float(targets[i]))
        gaps.append(gap)
        cmds.append(u)
        axis.step(u)
    return np.array(gaps), np.array(cmds)


@pytest.mark.parametrize('name', ['sine_5hz', 'step', 'feedback_gain_noise'])
def test_a_batch_of_one_equals_the_scalar_models_bit_for_bit(name):
    sc = load_scenario(name)
    sc = replace(sc, duration_s=1.0,
                 timeline=tuple(e for e in sc.timeline if e.t_s < 1.0))
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


def test_scenarios_the_batch_does_not_model_are_refused_with_the_reason():
    with pytest.raises(BatchUnsupported, match='thin-sheet plate'):
        run_batch('thin_sheet', LADRC.batch([ControllerParams()]), 1)
    with pytest.raises(BatchUnsupported, match='coverage'):
        run_batch('edge_open_10_1', LADRC.batch([ControllerParams()]), 1)
