"""``ladrc identify``: recovers the sim's axis and sensor from bags.

The bags come from ``ladrc excite`` (the excitation player on the headless sim, written by the
headless bag writer), with the sim's axis b0, T1 and dead time and the sensor's lag varied
and the sensor's 5 µm noise on.
"""

import contextlib
import io
import json
import math

from ladrc_bags import BagWriter, write_run_bag
from ladrc_follow.analysis.gate import check_gate
from ladrc_follow.control.params import load_params
from ladrc_tools.cli import main
from ladrc_tools.commissioning.excitation import H_S, Excitation
from ladrc_tools.commissioning.identify import (
    AxisSeries,
    IdentifyError,
    axis_series,
    ci_contains,
    fit_axis,
    simulate_axis,
)
from ladrc_tools.commissioning.simrun import apply_overrides, run_excitation, scenario_dict
import numpy as np
import pytest

# b0, T1 (s), dead time (ticks), sensor lag (s): each of b0 0.8/1/1.3, T1 4/8/15 ms and
# dead time 0/2/6 ticks twice, sensor lag 0/0.5/1/2 ms
CASES = [(1.0, 0.008, 0, 0.0), (0.8, 0.004, 2, 0.0005), (1.3, 0.015, 6, 0.002),
         (1.0, 0.004, 6, 0.001), (1.3, 0.008, 2, 0.0), (0.8, 0.015, 0, 0.001)]
EXCITATION_S = '2.0'


def _cli(args):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(args)
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope='module')
def identified(tmp_path_factory):
    root = tmp_path_factory.mktemp('identify')
    rows = []
    for i, (b0, t1, d, lag) in enumerate(CASES):
        bag = root / f'case{i}'
        rc, out, err = _cli(['excite', '-o', str(bag), '--duration-s', EXCITATION_S,
                             '--seed', str(i), '--set', f'axis.b0={b0}',
                             '--set', f'axis.t1_s={t1}', '--set', f'axis.dead_time_ticks={d}',
                             '--set', f'sensor.lag_s={lag}', '--set', f'seed={i}'])
        assert rc == 0, err
        excite = json.loads(out.strip().splitlines()[-1])
        assert excite['finished'] and excite['sensor_noise_mm'] == 0.005
        rc, out, err = _cli(['identify', str(bag)])
        assert rc == 0, err
        rows.append(((b0, t1, d, lag), json.loads(out.strip().splitlines()[-1]),
                     root / f'case{i}_identify'))
    return rows


def test_identify_recovers_the_sims_axis_within_5_percent(identified):
    for (b0, t1, d, _), j, _ in identified:
        assert abs(j['b0'] / b0 - 1) < 0.05, (b0, j['b0'])
        assert abs(j['t1_s'] / t1 - 1) < 0.05, (t1, j['t1_s'])
        # the bar: 5 %, or one tick where 5 % of the dead time is below a tick ...
        tol = max(0.05 * d * H_S, H_S)
        assert abs(j['dead_time_s'] - d * H_S) <= tol
        # ... and stricter, so that a command joined one tick off fails: a quarter tick
        assert abs(j['dead_time_ticks'] - d) < 0.25, (d, j['dead_time_ticks'])
    # measured: b0 within 2e-4, T1 within 0.5 %, dead time within 0.02 tick (docs)
    assert max(abs(j['b0'] / c[0] - 1) for c, j, _ in identified) < 1e-3
    assert max(abs(j['t1_s'] / c[1] - 1) for c, j, _ in identified) < 0.01


def test_intervals_contain_the_truth(identified):
    """95 % intervals: nearly all contain the truth, every truth within twice the interval.

    The sim's axis is noise-free and its encoder quantized (1 µm): that error is a
    deterministic function of the path, not white noise, so the intervals of T1 and τ cover
    a little less than 95 % (docs/identification.md: measured coverage over 40 runs).
    """
    inside, total = 0, 0
    for (b0, t1, d, _), j, _ in identified:
        for key, truth in (('b0', b0), ('t1_s', t1), ('dead_time_s', d * H_S)):
            lo, hi = j[f'{key}_ci']
            assert lo <= j[key] <= hi
            inside += lo <= truth <= hi
            total += 1
            half = 0.5 * (hi - lo)
            assert abs(truth - j[key]) <= 2.0 * half + 1e-12, (key, truth, j[key], lo, hi)
    assert inside >= 0.8 * total, f'{inside} of {total} intervals contain the truth'


def test_intervals_are_calibrated_for_white_measurement_noise():
    """With the noise the intervals assume (white, Gaussian), they cover at their level."""
    rng = np.random.default_rng(5)
    hits = np.zeros(3)
    n_runs = 10
    for i in range(n_runs):
        b0, t1, d = [(1.0, 0.008, 0), (0.8, 0.004, 2), (1.3, 0.015, 6)][i % 3]
        data = apply_overrides(scenario_dict(None), [
            f'axis.b0={b0}', f'axis.t1_s={t1}', f'axis.dead_time_ticks={d}',
            'encoder.resolution_mm=0', f'seed={i}'])
        res = run_excitation(data, Excitation(duration_s=1.5, seed=100 + i)).result
        y = res.nozzle_mm + rng.normal(0.0, 0.5e-3, res.t_s.size)
        s = axis_series({'stamp_s': res.t_s, 'velocity_mm_s': res.command_mm_s},
                        {'stamp_s': res.t_s, 'position_mm': y})
        fit = fit_axis(s)
        hits += [ci_contains(fit.b0, b0), ci_contains(fit.t1_s, t1),
                 ci_contains(fit.dead_time_s, d * H_S)]
    # 95 % intervals: 8 of 10 or more each (a wrong variance, e.g. without s², fails)
    assert np.all(hits >= 8), hits


def test_sensor_gain_lag_and_noise(identified):
    lag_inside = []
    for (_, _, _, lag), j, _ in identified:
        assert abs(j['sensor_gain'] - 1.0) < 0.005
        lo, hi = j['sensor_gain_ci']
        assert lo < j['sensor_gain'] < hi and hi - lo < 0.01
        # near 0 the lag is resolved to ~0.1 ms (α = exp(−h/τs) >= 0 is bounded there)
        assert abs(j['sensor_lag_s'] - lag) < 0.2e-3, (lag, j['sensor_lag_s'])
        lo, hi = j['sensor_lag_s_ci']
        assert lo <= j['sensor_lag_s'] <= hi
        lag_inside.append(lo <= lag <= hi)
        assert abs(j['sensor_noise_mm'] / 0.005 - 1) < 0.05
    big = [j['sensor_lag_s'] for c, j, _ in identified if c[3] >= 0.001]
    truth = [c[3] for c, _, _ in identified if c[3] >= 0.001]
    assert np.allclose(big, truth, rtol=0.1)
    assert sum(lag_inside) >= 0.8 * len(lag_inside)


def test_cli_writes_report_plot_and_a_gated_parameter_file(identified):
    for (b0, t1, d, _), j, out in identified:
        for key in ('b0', 'b0_ci', 't1_s', 't1_s_ci', 'dead_time_s', 'dead_time_s_ci',
                    'residual_rms_mm', 'sensor_gain', 'sensor_lag_s', 'sensor_noise_mm'):
            assert key in j
        assert j['residual_rms_mm'] < 0.5e-3  # the encoder's quantization, 1 µm/√12
        assert {p.name for p in out.iterdir()} == {'identification.md', 'fit.png',
                                                    'params.yaml', 'identification.json'}
        p = check_gate(load_params(out / 'params.yaml'))
        assert p.stability.axis_dead_time_ticks == d
        assert p.stability.axis_b0 == pytest.approx(b0, rel=1e-3)
        assert p.stability.axis_t1_ms == pytest.approx(t1 * 1e3, rel=0.01)
        assert p.eso.b0 == pytest.approx(b0, rel=1e-3)
        assert p.eso.gains == 'bandwidth' and p.law.gains == 'bandwidth'
        assert p.eso.w0_rad_s == j['suggested']['eso.w0_rad_s']
        # a slower axis gets a slower observer
        md = (out / 'identification.md').read_text()
        assert 'notes' in md and '16.75' in md and 'stability gate' in md
    w0 = {c: j['suggested']['eso.w0_rad_s'] for c, j, _ in identified}
    assert w0[CASES[2]] < w0[CASES[0]] < w0[CASES[1]]
    rc, out, err = _cli(['params', '--check', str(identified[0][2] / 'params.yaml')])
    assert rc == 0 and out.strip().endswith('valid'), err


def _one_error_line(err):
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert 'Traceback' not in err
    return lines[0]


class _Still:
    """A controller that commands nothing."""

    def step(self, tick):
        return 0.0

    def command(self, name, **kwargs):
        pass


def test_a_bag_without_motion_is_rejected(tmp_path):
    from ladrc_sim.headless.runner import run
    from ladrc_sim.headless.scenario import scenario_from_dict

    data = dict(scenario_dict(None), duration_s=1.0)
    result = run(scenario_from_dict(data), _Still())
    bag = write_run_bag(result, tmp_path / 'still')
    rc, out, err = _cli(['identify', str(bag)])
    assert rc == 2
    assert 'no motion commanded' in _one_error_line(err)
    assert not (tmp_path / 'still_identify').exists()
    assert not any(p.name.startswith('.') for p in tmp_path.iterdir())


def test_an_axis_that_does_not_move_is_unidentifiable(tmp_path):
    rc, _, err = _cli(['excite', '-o', str(tmp_path / 'tiny'), '--amplitude-mm-s', '0.01',
                       '--max-travel-mm', '0.002', '--duration-s', '1'])
    assert rc == 0, err
    rc, out, err = _cli(['identify', str(tmp_path / 'tiny')])
    assert rc == 2 and 'did not move' in _one_error_line(err)


def test_too_little_excitation_in_noise_is_unidentifiable():
    # a single 10 µm move buried in 20 µm of noise: b0 and T1 cannot be pinned down
    n = 2000
    rng = np.random.default_rng(1)
    u = np.zeros(n)
    u[1000:1040] = 0.5
    s = AxisSeries(t_s=np.arange(n) * H_S, command_mm_s=u, position_mm=np.zeros(n),
                   h_s=H_S, command_pre_mm_s=np.zeros(42))
    s.position_mm = simulate_axis(s, 1.0, 0.008, 0.0) + rng.normal(0, 0.02, n)
    with pytest.raises(IdentifyError, match='unidentifiable'):
        fit_axis(s)
    s.command_mm_s = np.where(np.arange(n) % 400 < 200, 2.0, -2.0)
    s.position_mm = -simulate_axis(s, 1.0, 0.008, 0.0)  # an encoder counting the other way
    with pytest.raises(IdentifyError, match='against its command'):
        fit_axis(s)


def test_bad_inputs_give_one_line_and_no_output(tmp_path, identified):
    rc, _, err = _cli(['identify', str(tmp_path / 'nothing')])
    assert rc == 2 and 'nothing' in _one_error_line(err)
    # a bag without the axis topics
    bag = tmp_path / 'texts'
    with BagWriter(bag) as w:
        w.add_topic('run/scenario')
    rc, _, err = _cli(['identify', str(bag)])
    assert rc == 2 and 'axis/velocity_command' in _one_error_line(err)
    src = identified[0][0], identified[0][2]
    rc, _, err = _cli(['identify', str(src[1].with_name('case0')), '-o', str(src[1])])
    assert rc == 2 and 'exists already' in _one_error_line(err)
    for window in ('3:1', 'a:b', '5'):
        rc, _, err = _cli(['identify', str(src[1].with_name('case0')), '-o',
                           str(tmp_path / 'w'), '--flat-sheet-window', window])
        assert rc == 2 and 'flat-sheet-window' in _one_error_line(err)
    rc, _, err = _cli(['identify', str(src[1].with_name('case0')), '-o', str(tmp_path / 'w'),
                       '--flat-sheet-window', '100:200'])
    assert rc == 2 and 'too few capacitive readings' in _one_error_line(err)
    assert not (tmp_path / 'w').exists()


def test_flat_sheet_window_selects_the_sensor_data(identified, tmp_path):
    bag = identified[2][2].with_name('case2')
    rc, out, err = _cli(['identify', str(bag), '-o', str(tmp_path / 'win'),
                         '--flat-sheet-window', '0.5:1.5'])
    assert rc == 0, err
    j = json.loads(out.strip().splitlines()[-1])
    assert abs(j['sensor_lag_s'] - 0.002) < 0.2e-3 and abs(j['sensor_gain'] - 1) < 0.01
    assert 'Window 0.5 .. 1.5 s' in (tmp_path / 'win' / 'identification.md').read_text()


@pytest.mark.parametrize('sets, word', [
    (['axis.b0=-1'], 'axis.b0'),
    (['axis.bogus=1'], 'axis.bogus'),
    (['axis.dead_time_ticks=2.5'], 'axis.dead_time_ticks'),
    (['b0'], 'KEY=VALUE'),
])
def test_excite_overrides_are_checked(tmp_path, sets, word):
    args = ['excite', '-o', str(tmp_path / 'x')]
    for s in sets:
        args += ['--set', s]
    rc, _, err = _cli(args)
    assert rc == 2 and word in _one_error_line(err)
    assert not (tmp_path / 'x').exists()


def test_excite_refuses_an_unsafe_excitation(tmp_path):
    rc, _, err = _cli(['excite', '-o', str(tmp_path / 'x'), '--amplitude-mm-s', '50'])
    assert rc == 2 and 'amplitude_mm_s' in _one_error_line(err)


def test_dead_time_is_the_loop_delay_of_a_live_style_bag():
    """Commands stamped after their feedback sample (a live loop) join to that sample."""
    n = 3000
    t = np.arange(n) * H_S
    u = Excitation(duration_s=1.5, seed=4).velocity_mm_s()[:n]
    # the drive applies a command from the next tick on: one tick of loop delay
    pre = np.zeros(42)
    s_true = AxisSeries(t_s=t, command_mm_s=u, position_mm=np.zeros(n), h_s=H_S,
                        command_pre_mm_s=pre)
    y = simulate_axis(s_true, 1.0, 0.008, H_S)
    cmd = {'stamp_s': t + 0.3 * H_S, 'velocity_mm_s': u, 'enable': np.ones(n, bool)}
    fit = fit_axis(axis_series(cmd, {'stamp_s': t, 'position_mm': y}))
    assert math.isclose(fit.dead_time_ticks, 1.0, abs_tol=0.01)
    assert math.isclose(fit.b0.value, 1.0, rel_tol=1e-6)
    # disabled commands are zero commands: the axis did not follow them
    cmd_off = dict(cmd, enable=np.zeros(n, bool))
    with pytest.raises(IdentifyError, match='no motion commanded'):
        fit_axis(axis_series(cmd_off, {'stamp_s': t, 'position_mm': y}))


def test_lost_and_jittered_feedback_samples():
    """A live driver's feedback: 5 % of the samples lost, stamps ±20 µs off the tick."""
    data = apply_overrides(scenario_dict(None), ['axis.t1_s=0.004', 'axis.dead_time_ticks=2'])
    res = run_excitation(data, Excitation(duration_s=2.0)).result
    rng = np.random.default_rng(0)
    keep = rng.random(res.t_s.size) > 0.05
    stamps = res.t_s + rng.uniform(-20e-6, 20e-6, res.t_s.size)
    s = axis_series({'stamp_s': res.t_s, 'velocity_mm_s': res.command_mm_s},
                    {'stamp_s': stamps[keep], 'position_mm': res.encoder_mm[keep]})
    assert s.h_s == H_S  # the tick from the stamps, lost samples and jitter notwithstanding
    assert any('lost samples' in n for n in s.notes)
    fit = fit_axis(s)
    assert abs(fit.b0.value - 1.0) < 0.005
    assert abs(fit.t1_s.value / 0.004 - 1) < 0.02
    assert abs(fit.dead_time_ticks - 2) < 0.25
