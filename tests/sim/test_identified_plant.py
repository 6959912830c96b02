"""The identified plant of notes §1.2: library scenarios, interval ends, the linear loop on it."""

import dataclasses

from ladrc_follow.control.follow import FollowController
from ladrc_follow.control.params import ControllerParams, params_from_dict
from ladrc_sim.headless.batch import BatchUnsupported, check_batchable
from ladrc_sim.headless.runner import run
from ladrc_sim.headless.scenario import list_scenarios, load_scenario
from ladrc_sim.models.axis import Axis, AxisParams
from ladrc_tools.offline.identified_plant import (
    GAIN_B0_1,
    INTERVALS,
    Coeffs,
    identified_axis_ss,
    interval_cases,
    loop_figures,
)
import numpy as np
import pytest
from scipy import signal

H = 0.0005
NAMES = ('identified_plant', 'identified_step')


def _with_b0(b0):
    d = dataclasses.asdict(ControllerParams())
    d['eso']['b0'] = b0
    return params_from_dict(d)


def test_library_scenarios_use_the_identified_model_and_the_batch_refuses_them():
    names = {p.stem for p in list_scenarios()}
    for name in NAMES:
        assert name in names
        sc = load_scenario(name)
        assert sc.axis.model == 'identified'
        assert sc.axis.identified_gain == pytest.approx(1 / 16.75)
        with pytest.raises(BatchUnsupported, match='axis model identified'):
            check_batchable(sc)


def test_eleven_cases_each_coefficient_at_each_end():
    cases = dict(interval_cases())
    assert len(cases) == 11
    assert cases['d0-'].d0 == pytest.approx(0.06028 - 0.3627)
    assert cases['n0+'].zero_rad_s() < 0 < cases['nominal'].zero_rad_s()
    assert max(p.real for p in cases['d0-'].poles_rad_s()) > 0.4      # an unstable pole


@pytest.mark.parametrize('label', ['nominal', 'd0-', 'n0+', 'all-'])
def test_the_sim_axis_and_the_loop_plant_are_the_interval_model(label):
    coeffs = dict(interval_cases())[label]
    gain = 0.3
    axis = Axis(AxisParams(model='identified', identified_gain=gain, **coeffs.axis_kwargs()),
                2.0, H)
    u = list(np.sin(np.arange(3000) * 0.01) * 40.0)
    x = np.array([axis.step(v)[0] for v in u])
    # the continuous model (scipy) at the tick ends, ZOH input
    t = H * np.arange(len(u) + 1)
    _, y, _ = signal.lsim(((coeffs.n1, coeffs.n0), (1.0, coeffs.d1, coeffs.d0)),
                          np.concatenate((np.array(u) * gain, [0.0])), t, interp=False)
    np.testing.assert_allclose(x, 2.0 + y[1:], atol=1e-7)
    # the loop's plant: nozzle output, state after each command
    ss = identified_axis_ss(coeffs, gain, H)
    s = np.zeros(ss.a.shape[0])
    noz = []
    for v in u:
        s = ss.a @ s + ss.b[:, 0] * v
        noz.append(float(ss.c[2] @ s))
    np.testing.assert_allclose(2.0 + np.array(noz), x, atol=1e-9)


def test_the_loop_on_the_identified_plant():
    base = ControllerParams()
    nominal = loop_figures(base, Coeffs(), GAIN_B0_1)
    # integral action in the loop: the slowest closed-loop pole sits on the plant's zero
    assert nominal['slow_pole_rad_s'] == pytest.approx(Coeffs().zero_rad_s(), rel=0.01)
    assert loop_figures(base, dict(interval_cases())['n0+'], GAIN_B0_1)['slow_pole_rad_s'] < 0
    # gain 1 (16.75 read as mm/s per mm/s): crossover ×7, delay margin under 2 ticks
    hot = loop_figures(base, Coeffs(), 1.0)
    assert hot['phase_margin_deg'] < 30.0 and hot['delay_margin_ms'] < 2 * H * 1e3
    assert hot['crossover_hz'] > 5 * nominal['crossover_hz']
    # the ESO's b0 set to the plant's gain gives back the nominal loop exactly
    matched = loop_figures(_with_b0(16.75), Coeffs(), 1.0)
    assert matched['phase_margin_deg'] == pytest.approx(nominal['phase_margin_deg'], abs=0.05)
    assert matched['crossover_hz'] == pytest.approx(nominal['crossover_hz'], rel=1e-3)
    # the interval ends move the margin by less than half a degree
    pms = [loop_figures(base, c, GAIN_B0_1)['phase_margin_deg'] for _, c in interval_cases()]
    assert max(pms) - min(pms) < 0.5
    assert set(INTERVALS) == set(Coeffs().axis_kwargs())


@pytest.mark.parametrize('mode', ['ladrc', 'pid'])
@pytest.mark.parametrize('verify', [False, True])
def test_the_shipped_controller_follows_the_identified_plant(mode, verify):
    sc = load_scenario('identified_plant')
    params = ControllerParams() if verify else params_from_dict(
        {'edge': {'verify_sink': 0.0, 'verify_start_mm': 0.0}})
    ctrl = FollowController(params, mode=mode)
    res = run(sc, ctrl, record_internals=True)
    assert ctrl.fault_reason in (None, '')
    assert res.metrics.collisions == 0
    # the law alone; with the edge verification's ~0.1 mm moves up on the falling stretches
    # of the wavy sheet (docs/safety.md) the RMS error grows by about 0.02 mm
    bound = (0.02 if mode == 'ladrc' else 0.06) + (0.025 if verify else 0.0)
    assert res.metrics.error_rms_mm < bound


def test_a_matched_b0_runs_the_gain_1_step_as_the_nominal_one():
    sc = load_scenario('identified_step')
    ref = run(sc, FollowController(ControllerParams(), mode='ladrc'), record_internals=True)
    hot = dataclasses.replace(sc, axis=dataclasses.replace(sc.axis, identified_gain=1.0))
    ctrl = FollowController(_with_b0(16.75), mode='ladrc')
    res = run(hot, ctrl, record_internals=True)
    assert ctrl.fault_reason in (None, '') and res.metrics.collisions == 0
    assert res.metrics.settling_time_s == pytest.approx(ref.metrics.settling_time_s, rel=0.25)
    assert res.metrics.overshoot_mm < 0.01
