"""The seeds' experiments as the seeds ran them: target wave, seed-faithful steps."""

from __future__ import annotations

import math

from ladrc_follow.analysis.loop import td_ss
from ladrc_follow.control.follow import FollowController
from ladrc_follow.control.params import ControllerParams, params_from_dict
from ladrc_sim.headless.runner import run
from ladrc_sim.headless.scenario import scenario_from_dict
import numpy as np
import pytest

H = 0.0005


def _phasor(x: np.ndarray, t: np.ndarray, f: float) -> complex:
    """One DFT bin of ``x`` (mean removed) at ``f`` over whole periods."""
    return complex(np.sum((x - x.mean()) * np.exp(-2j * np.pi * f * t)))


def test_target_sine_as_sin_gen_through_the_td_matches_its_transfer_function():
    """SIN_GEN: a 5 Hz sine on the target once followed; the TD output's amplitude ratio.

    The firmware TDB alone (notes §2.4: its Fc is commented out) is 12000/(s² + 400 s + 12000):
    0.718 at 5 Hz. The measured ratio of the TD output matches the tick's own discrete TD
    within 0.1 % and the continuous one within 2 %.
    """
    sc = scenario_from_dict({
        'name': 'sin_gen', 'duration_s': 4.0, 'seed': 1, 'initial_gap_mm': 1.0,
        'timeline': [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0},
                     {'t_s': 0.5, 'do': 'target_wave', 'amp_mm': 0.05, 'freq_hz': 5.0}]})
    c = FollowController()
    res = run(sc, c, record_internals=True)
    state = np.asarray(res.internals['state'])
    td = np.asarray(res.internals['td_x1_mm'])
    followed = np.asarray(res.internals['followed'], dtype=bool)
    i_on = int(np.argmax(followed & (np.arange(td.size) >= 1000)))  # applied once followed
    assert np.all(state[i_on:] == 4)  # the LADRC runs it, as in the seed
    # ten periods (2 s) from i_on; measure periods 3..9
    sl = slice(i_on + 2 * 400, i_on + 9 * 400)
    t = (np.arange(td.size)[sl] - i_on) * H
    wave = 0.05 * np.sin(2 * np.pi * 5.0 * t)
    ratio = _phasor(td[sl], t, 5.0) / _phasor(wave, t, 5.0)
    discrete = td_ss(ControllerParams()).response([5.0])[0, 0, 0]
    s = 2j * math.pi * 5.0
    firmware = 12000 / (s * s + 400 * s + 12000)
    assert abs(ratio) == pytest.approx(abs(discrete), rel=1e-3)
    assert abs(ratio) == pytest.approx(abs(firmware), rel=0.02)
    assert abs(firmware) == pytest.approx(0.718, abs=5e-4)
    # after ten periods the wave ends: the TD settles back on the plain target
    assert np.max(np.abs(td[-2000:] - 1.0)) < 1e-3
    assert np.max(np.abs(td[i_on + 400:i_on + 1600] - 1.0)) > 0.03


def test_a_wave_is_refused_with_the_reason_when_it_cannot_run():
    c = FollowController()
    assert c.command('target_wave', amp_mm=0.1, freq_hz=5.0) == (
        False, 'target_wave: not following (IDLE)')
    c.command('start_follow', target_gap_mm=0.5)
    ok, why = c.command('target_wave', amp_mm=0.3, freq_hz=5.0)
    assert not ok and 'outside the allowed 0.3..20 mm' in why  # 0.5 − 0.3 < min gap
    ok, why = c.command('target_wave', kind='triangle', amp_mm=0.1, freq_hz=math.inf)
    assert not ok and 'kind must be one of sine, chirp, square' in why and 'freq_hz' in why


@pytest.mark.parametrize('reinterpolate', [True, False])
def test_seed_faithful_mode_sends_a_step_straight_to_the_ladrc(reinterpolate):
    """1→10 mm once followed: re-interpolated by default, straight to the LADRC as in the seed."""
    p = params_from_dict({'follow': {'reinterpolate': reinterpolate}})
    sc = scenario_from_dict({
        'name': 'high_step', 'duration_s': 2.0, 'seed': 1, 'initial_gap_mm': 1.0,
        'timeline': [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0},
                     {'t_s': 1.0, 'do': 'set_target', 'target_gap_mm': 10.0}]})
    res = run(sc, FollowController(p), record_internals=True)
    state = np.asarray(res.internals['state'])[2000:]
    assert bool(np.any(state == 2)) is reinterpolate  # PREINTERPOLATE after the step
    if not reinterpolate:
        assert np.all(state == 4)  # the LADRC and its TD ran the whole step
    assert res.true_gap_mm[-1] == pytest.approx(10.0, abs=0.05)


def _sine5(params: dict, seconds: float = 2.0):
    sc = scenario_from_dict({
        'name': 'fal', 'duration_s': seconds, 'seed': 5, 'initial_gap_mm': 1.0,
        'sensor': {'noise_std_mm': 0.005, 'quant_mm': 0.001},
        'sheet': {'profiles': [{'kind': 'sine', 'amp_mm': 0.2, 'freq_hz': 5.0,
                                't_start_s': 0.5}]},
        'timeline': [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}]})
    return run(sc, FollowController(params_from_dict(params)), record_internals=True)


def test_fal_eso_equals_the_leso_with_its_linear_zone_gains_in_closed_loop():
    """Inside |ε| <= δ, fal(ε, α, δ) = ε·δ^(α−1): the NESO is the LESO with gains β·δ^(α−1).

    δ = 0.5 mm is far above every observer error of the run, so the closed loops agree to
    rounding; with δ = 2 µm (below the sensor noise) the nonlinearity acts and they differ.
    The firmware's table lookup agrees with the direct fal within the table's error.
    """
    betas, delta = (180.0, 10800.0), 0.5
    alphas = (0.5, 0.25)  # 'all' with α = 0.5 (paper eq. 38)
    fal_run = _sine5({'eso': {'nonlinear': 'all', 'betas': list(betas),
                              'fal_delta_mm': delta}})
    lin = [b * delta ** (a - 1.0) for b, a in zip(betas, alphas, strict=True)]
    leso = _sine5({'eso': {'betas': lin}})
    assert np.allclose(fal_run.command_mm_s, leso.command_mm_s, rtol=1e-9, atol=1e-9)
    eps = np.abs(np.asarray(fal_run.internals['fused_gap_mm'])
                 - np.asarray(fal_run.internals['eso_z1_mm']))
    assert eps[np.asarray(fal_run.internals['state']) == 4].max() < delta
    # δ = 2 µm with β2 scaled by δ^(1−α), so the linear zone is the shipped LESO's (gate)
    small = {'eso': {'nonlinear': 'disturbance', 'fal_delta_mm': 0.002,
                     'betas': [180.0, 10800.0 * 0.002 ** 0.5]}}
    direct = _sine5(small)
    assert not np.allclose(direct.command_mm_s, _sine5({}).command_mm_s, atol=1e-3)
    table = _sine5({'eso': {**small['eso'], 'fal_table': True, 'fal_table_size': 4097,
                            'fal_table_range_mm': 0.5}})
    assert np.max(np.abs(table.true_gap_mm - direct.true_gap_mm)) < 2e-3


def test_fal_settings_that_cannot_run_are_rejected_with_the_reason():
    from ladrc_follow.analysis.gate import check_gate
    from ladrc_follow.control.ladrc import LADRC
    from ladrc_follow.control.params import ParameterError

    with pytest.raises(ParameterError, match='runs on the explicit-Euler observer'):
        params_from_dict({'eso': {'nonlinear': 'all', 'discretization': 'zoh',
                                  'gains': 'bandwidth'}})
    with pytest.raises(ParameterError, match='unstable in its linear zone'):
        params_from_dict({'eso': {'nonlinear': 'all', 'fal_delta_mm': 1e-4}})
    with pytest.raises(ValueError, match='scalar path only'):
        LADRC.batch([params_from_dict({'eso': {'nonlinear': 'disturbance', 'fal_table': True,
                                               'betas': [180.0, 10800.0 * 0.05 ** 0.5]}})])
    # the shipped betas with a 50 µm linear zone: β2·δ^(α−1) = 48 300/s², refused by the gate
    with pytest.raises(ParameterError, match='stability gate'):
        check_gate(params_from_dict({'eso': {'nonlinear': 'disturbance'}}))


def _gated(kalman: dict, timeline: list) -> tuple:
    sc = scenario_from_dict({
        'name': 'kalman', 'duration_s': 1.2, 'seed': 3, 'initial_gap_mm': 1.0,
        'sensor': {'noise_std_mm': 0.002}, 'encoder': {'resolution_mm': 0.0},
        'sheet': {'profiles': [{'kind': 'sine', 'amp_mm': 0.05, 'freq_hz': 2.0,
                                't_start_s': 0.5}]},
        'timeline': [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}, *timeline]})
    p = params_from_dict({'kalman': {'enabled': True, **kalman}})
    res = run(sc, FollowController(p), record_internals=True)
    return res, np.asarray(res.internals['fused_gap_mm'])


def test_gated_kalman_rejects_an_outlier_and_coasts_through_a_dropout_in_closed_loop():
    """One reading 8 % wide (gain 1.08 for a tick) and a 5 ms sensor dropout, once followed.

    0.08 mm in one tick is below what the follow controller's fast-fall hold stops (edge.py:
    30 mm/s through a 4 ms filter), so the reading reaches the filter. Gated at 0.05 mm, the
    wide outlier leaves the fused gap where the encoder predicts it; ungated it pulls the
    estimate up by K·0.08 mm (toward a command down). A reading 8 % *close* is taken by the
    gate (one-sided: it can only send the nozzle up). During the dropout the
    fused gap moves by exactly the encoder increments (predict only): the filter is not fed
    its own prediction as a measurement.
    """
    i_spike = 2000  # 1.0 s

    def spike(gain: float) -> list:
        return [{'t_s': 1.0, 'do': 'sensor_gain', 'value': gain},
                {'t_s': 1.0005, 'do': 'sensor_gain', 'value': 1.0}]

    def jump(res, fused) -> float:  # the fused gap's step at the spike, beyond the encoder's
        enc = np.asarray(res.encoder_mm)
        return fused[i_spike] - fused[i_spike - 1] - (enc[i_spike] - enc[i_spike - 1])

    gated, fg = _gated({'gate_mm': 0.05}, spike(1.08))
    plain, fp = _gated({}, spike(1.08))
    assert np.all(np.asarray(gated.internals['state'])[1900:] == 4)
    assert abs(jump(gated, fg)) < 1e-9 and jump(plain, fp) > 0.003
    close, fc = _gated({'gate_mm': 0.05}, spike(0.92))
    assert jump(close, fc) < -0.003
    drop, fd = _gated({'gate_mm': 0.1}, [{'t_s': 1.0, 'do': 'sensor_dropout',
                                          'duration_s': 0.005}])
    assert np.all(np.asarray(drop.internals['state'])[1900:] == 4)
    enc_d = np.asarray(drop.encoder_mm)
    win = slice(i_spike, i_spike + 9)  # the 9 ticks after the last sample before the gap
    assert np.all(np.abs(np.diff(enc_d)[win]) > 1e-5)  # the axis moves meanwhile
    assert np.allclose(np.diff(fd)[win], np.diff(enc_d)[win], rtol=0, atol=1e-12)
