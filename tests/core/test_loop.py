"""The linear loop analysis (control/loop.py) against closed forms and the simulator."""

from __future__ import annotations

import math

from ladrc_follow.analysis.loop import (
    AxisModel,
    StateSpace,
    analyse,
    analyse_params,
    axis_ss,
    controller_ss,
)
from ladrc_follow.control.params import ControllerParams
import numpy as np
import pytest

H = 0.0005


def _integrator_with_dead_time(d: int) -> StateSpace:
    """x[k+1] = x[k] + h u[k-d]; outputs reading = x - sheet, encoder = x, nozzle = x."""
    n = 1 + d
    a = np.zeros((n, n))
    b = np.zeros((n, 2))
    a[0, 0] = 1.0
    if d:
        a[0, n - 1] = H
        b[1, 0] = 1.0
        for i in range(1, n - 1):
            a[i + 1, i] = 1.0
    else:
        b[0, 0] = H
    c = np.zeros((3, n))
    c[:, 0] = 1.0
    dd = np.zeros((3, 2))
    dd[0, 1] = -1.0
    return StateSpace(a, b, c, dd, H)


def test_margins_of_a_textbook_loop_match_the_closed_forms():
    """P control of an integrator with dead time: L = kp e^(-s tau) / s (ZOH, discrete).

    Discrete (exact): |L| = kp h / (2 sin(w h / 2)), angle L = -pi/2 - w h (d + 1/2), so
    w_c = (2/h) asin(kp h / 2), PM = pi/2 - w_c h (d + 1/2), the phase crossover at
    w_180 = pi / (2 h (d + 1/2)); continuous: PM = 90 deg - kp tau, GM = pi / (2 kp tau).
    """
    kp, d = 20.0, 20
    ctrl = StateSpace(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((1, 0)),
                      np.array([[-kp, 0.0]]), H)
    an = analyse(ctrl, _integrator_with_dead_time(d))
    wc = 2 / H * math.asin(kp * H / 2)
    pm = math.degrees(math.pi / 2 - wc * H * (d + 0.5))
    w180 = math.pi / (2 * H * (d + 0.5))
    gm = -20 * math.log10(kp * H / (2 * math.sin(w180 * H / 2)))
    assert an.stable
    assert an.crossover_hz == pytest.approx(wc / (2 * math.pi), rel=1e-3)
    assert an.phase_margin_deg == pytest.approx(pm, abs=0.02)
    assert an.gain_margin_hz == pytest.approx(w180 / (2 * math.pi), rel=1e-3)
    assert an.gain_margin_db == pytest.approx(gm, abs=0.02)
    assert an.delay_margin_ms == pytest.approx(math.radians(pm) / wc * 1e3, rel=2e-3)
    tau = d * H + H / 2  # the continuous loop; the zero-order hold adds half a tick
    assert an.phase_margin_deg == pytest.approx(90 - math.degrees(kp * tau), abs=0.05)
    assert an.gain_margin_db == pytest.approx(20 * math.log10(math.pi / (2 * kp * tau)),
                                              abs=0.05)
    # a gain beyond the gain margin: unstable, and the margins say so
    ctrl.d[0, 0] = -kp * 10 ** (gm / 20) * 1.05
    high = analyse(ctrl, _integrator_with_dead_time(d))
    assert not high.stable and high.phase_margin_deg < 0


def test_controller_is_linearized_from_its_own_tick():
    """The probed LADRC replays the core's response to a small input sequence exactly."""
    from ladrc_follow.control.ladrc import LADRC

    p = ControllerParams()
    ss = controller_ss(p, 'ladrc')
    core = LADRC(p)
    rng = np.random.default_rng(1)
    w = rng.normal(scale=1e-4, size=(400, 3))  # reading, encoder, target (through the TD)
    x = np.zeros(ss.a.shape[0])
    for k in range(400):
        u_ss = float((ss.c @ x + ss.d @ w[k])[0])
        x = ss.a @ x + ss.b @ w[k]
        assert core.step(*w[k]) == pytest.approx(u_ss, rel=1e-6, abs=1e-12)


def _order2_zoh_kalman() -> ControllerParams:
    from dataclasses import replace

    from ladrc_follow.control.params import ESOParams, KalmanParams, LawParams

    return replace(ControllerParams(),
                   eso=ESOParams(order=2, discretization='zoh', gains='bandwidth',
                                 w0_rad_s=300.0, b0=1.0 / 0.008),
                   law=LawParams(form=3, gains='bandwidth', wc_rad_s=40.0),
                   kalman=KalmanParams(enabled=True))


@pytest.mark.parametrize('mode, variant', [('ladrc', 'shipped'), ('ladrc', 'order2'),
                                           ('ladrc', 'compensator'), ('pid', 'shipped')])
def test_analysis_agrees_with_the_simulated_sheet_sine(mode, variant):
    """Sheet sines in the headless simulator: nozzle/sheet gain and phase as analysed.

    A small sine (5 um: no limit is reached), no noise, no quantization, not machining (no
    suppression); the last whole periods of each run are projected on the sine. The shipped
    LADRC (order 1, Euler), an order-2 ZOH observer with the Kalman fusion, the shipped LADRC
    with the paper's eq. 22 compensator (which fails the stability gate), and the PID.
    """
    from dataclasses import replace

    from ladrc_follow.control.follow import FollowController
    from ladrc_sim.headless.runner import run
    from ladrc_sim.headless.scenario import scenario_from_dict

    p = {'shipped': ControllerParams(), 'order2': _order2_zoh_kalman(),
         'compensator': replace(ControllerParams(), eso=replace(ControllerParams().eso,
                                                                compensator=True))}[variant]
    freqs = [2.0, 8.0, 25.0]
    an = analyse_params(p, AxisModel(), mode, f_hz=freqs)
    for f, t_expected in zip(freqs, an.sheet_to_nozzle, strict=True):
        t_on = 1.0
        periods = max(4, int(round(0.6 * f)))
        dur = t_on + 1.5 + periods / f
        sc = scenario_from_dict({
            'name': 'sweep', 'duration_s': dur, 'seed': 1, 'initial_gap_mm': 1.0,
            'encoder': {'resolution_mm': 0.0},
            'sheet': {'profiles': [{'kind': 'sine', 'amp_mm': 0.005, 'freq_hz': f,
                                    't_start_s': t_on}]},
            'timeline': [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}]})
        res = run(sc, FollowController(p, mode=mode), record_internals=True)
        state = np.asarray(res.internals['state'])
        n_win = int(round(periods / f / H))
        sl = slice(res.t_s.size - n_win, res.t_s.size)
        assert np.all(state[sl] == (4 if mode == 'ladrc' else 3))
        t = res.t_s[sl]
        basis = np.exp(-2j * np.pi * f * (t - t_on))
        sheet = np.sum(res.sheet_mm[sl] * basis)
        noz = res.nozzle_mm[sl] - np.mean(res.nozzle_mm[sl])
        measured = np.sum(noz * basis) / sheet
        db = 20 * math.log10(abs(measured) / abs(t_expected))
        deg = math.degrees(np.angle(measured / t_expected))
        assert abs(db) < 0.5 and abs(deg) < 3.0, (mode, f, db, deg)


@pytest.mark.parametrize('mode, variant', [('ladrc', 'shipped'), ('ladrc', 'order2'),
                                           ('pid', 'shipped')])
def test_reference_path_through_the_td_agrees_with_a_simulated_target_sine(mode, variant):
    """A small sine on the target, the core around the simulator's axis: gap / target as analysed.

    The LADRC's compound TD (or the PID's reference filter) shapes the target; the loop then
    follows it. The time-domain run uses the core's own step and the sim's axis model.
    """
    from ladrc_follow.control.ladrc import LADRC
    from ladrc_follow.control.pid import FollowPID
    from ladrc_sim.models.axis import Axis, AxisParams

    p = {'shipped': ControllerParams(), 'order2': _order2_zoh_kalman()}[variant]
    freqs = [1.0, 5.0, 20.0]
    an = analyse_params(p, AxisModel(), mode, f_hz=freqs)
    assert an.reference_to_gap.shape == (3,)
    for f, expected in zip(freqs, an.reference_to_gap, strict=True):
        periods = max(4, int(round(0.5 * f)))
        n = int(round((1.0 + periods / f) / H))
        axis = Axis(AxisParams(), 1.0, H)
        if mode == 'ladrc':
            core = LADRC(p)
            core.reset(1.0, 0.0, 1.0, 1.0)
        else:
            core = FollowPID(p.pid, H)
            core.reset(1.0, 0.0, 1.0, 1.0)
            core.enable_feed_forward(True)
            core._ff_count = 10**9  # the feed-forward on, as once followed (controller_ss)
        t = np.arange(n) * H
        target = 1.0 + 0.002 * np.sin(2 * np.pi * f * t)
        gap = np.empty(n)
        for i in range(n):
            gap[i] = axis.position_mm
            axis.step(core.step(axis.position_mm, axis.position_mm, float(target[i])))
        sl = slice(n - int(round(periods / f / H)), n)
        basis = np.exp(-2j * np.pi * f * t[sl])
        measured = np.sum((gap[sl] - gap[sl].mean()) * basis) / np.sum(
            (target[sl] - 1.0) * basis)
        db = 20 * math.log10(abs(measured) / abs(expected))
        deg = math.degrees(np.angle(measured / expected))
        assert abs(db) < 0.3 and abs(deg) < 2.0, (mode, f, db, deg)
    assert an.reference_bandwidth_hz > 1.0


@pytest.mark.parametrize('order, disc, k', [(1, 'euler', math.sqrt(math.sqrt(2) - 1)),
                                            (1, 'zoh', math.sqrt(math.sqrt(2) - 1)),
                                            (2, 'euler', math.sqrt(2 ** (1 / 3) - 1))])
def test_observer_estimates_the_disturbance_with_its_bandwidth(order, disc, k):
    """ESO alone: ẑ/f = ω0^(n+1)/(s + ω0)^(n+1) at ω0 h << 1, so −3 dB at k·ω0; poles at ω0."""
    from dataclasses import replace

    from ladrc_follow.analysis.loop import analyse_observer
    from ladrc_follow.control.params import ESOParams

    w0 = 60.0
    p = replace(ControllerParams(), eso=ESOParams(order=order, discretization=disc,
                                                  gains='bandwidth', w0_rad_s=w0))
    obs = analyse_observer(p, f_hz=np.geomspace(0.01, 100.0, 4000))
    assert abs(obs.disturbance_estimate[0]) == pytest.approx(1.0, abs=1e-4)
    assert obs.bandwidth_hz == pytest.approx(k * w0 / (2 * math.pi), rel=0.02)
    assert obs.error_poles_hz == pytest.approx([w0 / (2 * math.pi)] * (order + 1), rel=0.03)
    # the observer is its own: a faster one estimates faster
    fast = analyse_observer(replace(p, eso=replace(p.eso, w0_rad_s=2 * w0)),
                            f_hz=obs.f_hz)
    assert fast.bandwidth_hz == pytest.approx(2 * obs.bandwidth_hz, rel=0.03)


def test_axis_model_is_the_simulators_discretization():
    """axis_ss steps as ladrc_sim's first-order axis (exact ZOH), dead time included."""
    from ladrc_sim.models.axis import Axis, AxisParams

    for dead in (0, 3):
        ax = Axis(AxisParams(dead_time_ticks=dead), 0.0, H)
        ss = axis_ss(AxisModel(dead_ticks=dead), H).with_delay_states()
        x = np.zeros(ss.a.shape[0])
        rng = np.random.default_rng(2)
        for _ in range(200):
            u = float(rng.normal())
            assert float(ss.c[2] @ x) == pytest.approx(ax.position_mm, abs=1e-12)
            x = ss.a @ x + ss.b @ np.array([u, 0.0])
            ax.step(u)


def test_stability_gate_rejects_with_the_numbers_and_the_cli_too(tmp_path, capsys):
    """A valid set whose loop falls short is rejected where sets are loaded, with the numbers.

    ``params_from_dict`` validates, the gate is the loader's (``check_gate``); replay does not
    gate (it reproduces what ran); ``stability.gate: false`` switches it off; ``ladrc analyze``
    takes any set and says why the gate refuses it.
    """
    from ladrc_follow.analysis.gate import check_gate
    from ladrc_follow.control.params import ParameterError, dump_params, params_from_dict
    from ladrc_tools.cli import main as ladrc

    assert check_gate(params_from_dict({})).stability.gate  # the shipped set passes
    with pytest.raises(ParameterError) as exc:
        check_gate(params_from_dict({'law': {'kp': 60.0}}))
    text = ' '.join(exc.value.reasons)
    assert 'stability gate: the ladrc loop has a phase margin of 19.9° < 30°' in text
    assert 'sensitivity peak Ms of 3.17 > 2.5' in text
    with pytest.raises(ParameterError, match='unstable'):
        check_gate(params_from_dict({'stability': {'axis_dead_time_ticks': 30}}))
    assert params_from_dict({'law': {'kp': 60.0}}).law.kp == 60.0  # valid, not gated
    assert check_gate(params_from_dict({'law': {'kp': 60.0},
                                        'stability': {'gate': False}})).law.kp == 60.0
    bad = params_from_dict({'law': {'kp': 60.0}})
    path = tmp_path / 'p.yaml'
    path.write_text(dump_params(bad))
    for args in (['params', '--check', str(path)], ['simulate', 'step', '--params', str(path)]):
        assert ladrc(args) == 2, args
        err = capsys.readouterr().err
        assert 'stability gate' in err and err.count('\n') == 1, err
    # analyze takes it, and says why the gate refuses it
    assert ladrc(['analyze', '--params', str(path), '-o', str(tmp_path / 'a')]) == 0
    import json

    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert line['gate_passed'] is False and line['phase_margin_deg'] == pytest.approx(19.9,
                                                                                      abs=0.1)
    assert 'stability gate' in (tmp_path / 'a' / 'analysis.md').read_text()


def test_the_controller_runs_what_it_is_given_and_the_gate_is_the_callers():
    """The control core does not gate (the analysis stays off the tick path); its callers do.

    The headless runner as a library and replay run a set as it is; the node gates at start-up
    and on a change (tests/ros), the CLI where it loads a file (above).
    """
    from dataclasses import replace

    from ladrc_follow.analysis.gate import check_gate, stability_reasons
    from ladrc_follow.control.follow import FollowController
    from ladrc_follow.control.params import ControllerParams, LawParams, ParameterError

    bad = replace(ControllerParams(), law=LawParams(kp=60.0))
    with pytest.raises(ParameterError, match='phase margin of 19.9° < 30°'):
        check_gate(bad)
    assert any('sensitivity peak Ms of 3.17 > 2.5' in r for r in stability_reasons(bad))
    assert FollowController(bad).params.law.kp == 60.0
    ctl = FollowController()
    ctl.set_params(bad)  # queued: the caller decided
    with pytest.raises(ParameterError):
        ctl.set_params(replace(bad, law=LawParams(kp=-1.0)))  # an invalid set never runs


def test_tune_on_a_tiny_grid_writes_a_set_that_loads_and_beats_the_worst(tmp_path, capsys):
    """`ladrc tune` writes a set that loads and beats the worst grid point.

    A gated-out point is reported with its reason and not run; the chosen set is a parameter
    file the loaders accept, on the Pareto front, with a better score than the worst point.
    """
    import json

    from ladrc_follow.control.params import load_params
    from ladrc_tools.cli import main as ladrc

    out = tmp_path / 'tune'
    assert ladrc(['tune', '--w0', '40:120:3', '--kp', '5:60:2', '--td-r', '100',
                  '--scenarios', 'sine_5hz', '-o', str(out)]) == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    table = json.loads((out / 'tune.json').read_text())
    rejected = [r for r in table['grid_points'] if r['rejected']]
    assert rejected and all(r['kp'] == 60.0 and 'stability gate' in r['rejected']
                            and r['error_rms_mm'] is None for r in rejected)
    assert line['gated_in'] == 6 - len(rejected) >= 2 and line['front'] >= 1
    tuned = load_params(out / 'tuned.yaml')  # gated again on loading: it passes
    assert tuned.eso.w0_rad_s == line['chosen']['w0_rad_s']
    assert line['chosen_score'] < line['worst_score']
    assert sorted(p.name for p in out.iterdir()) == ['pareto.png', 'tune.json', 'tune.md',
                                                     'tuned.yaml']
    assert ladrc(['tune', '--w0', 'x', '-o', str(tmp_path / 'b')]) == 2
    assert ladrc(['tune', '--scenarios', 'faults', '-o', str(tmp_path / 'c')]) == 2
    assert 'miss-panel' in capsys.readouterr().err


def test_tune_scores_each_class_of_scenario_and_drops_sets_that_touch_the_sheet():
    """Tracking, rejection and edge scenarios give their own scores; a contact rules a set out.

    On an edge the reading is not the gap, so an edge scenario adds only its chatter (and the
    closest approach), never a gap error; a set that touches the sheet leaves the front.
    """
    from dataclasses import replace

    from ladrc_follow.control.params import ControllerParams
    from ladrc_sim.headless.scenario import scenario_from_dict
    from ladrc_tools.offline.tune import OBJECTIVES, sweep

    cands = sweep(ControllerParams(), [40.0, 120.0], [10.0], [1.0],
                  ['step', 'sine_5hz', 'edge_step_3_1'])
    assert all(set(c.scores) == set(OBJECTIVES) for c in cands)
    slow, fast = cands
    # the faster observer rejects the 5 Hz sheet better and chatters more at the edge
    assert fast.scores['rejection_rms_mm'] < slow.scores['rejection_rms_mm']
    assert fast.scores['edge_chatter_mm_s'] > slow.scores['edge_chatter_mm_s']
    assert 0.0 < slow.edge_min_gap_mm < 1.0  # half off the sheet, 1 mm read is < 1 mm true
    # a sheet shaken ±1 mm at 3 Hz under a nozzle 1 mm above it: the slow observer touches it
    shake = scenario_from_dict({
        'name': 'shake', 'duration_s': 1.0, 'seed': 2, 'initial_gap_mm': 1.0,
        'sheet': {'profiles': [{'kind': 'sine', 'amp_mm': 1.0, 'freq_hz': 3.0}]},
        'timeline': [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}]})
    slow_law = replace(ControllerParams().law, kp=1.0)
    slow, fast = sweep(replace(ControllerParams(), law=slow_law), [10.0, 150.0], [1.0], [1.0],
                       [shake])
    assert slow.rejected.startswith('contact with the sheet in shake at 0.')
    assert slow.params is None and not slow.front
    assert not fast.rejected and fast.front
