"""Headless closed loop with a simple PD controller defined here (the real one comes later)."""

import math

from ladrc_sim.headless.runner import Controller, TickInput, run, schedule
from ladrc_sim.headless.scenario import load_scenario, scenario_from_dict
import numpy as np
import pytest

H = 0.0005


class PD:
    """Proportional gap control with a velocity limit (enough to close the loop)."""

    def __init__(self, kp=60.0, v_max=200.0):
        self.kp, self.v_max, self.target = kp, v_max, None
        self.commands = []
        self.ticks = []
        self.u = 0.0

    def command(self, name, **kwargs):
        self.commands.append((name, kwargs))
        if name in ('start_follow', 'set_target'):
            self.target = kwargs['target_gap_mm']
        elif name == 'stop_follow':
            self.target = None

    def step(self, tick):
        self.ticks.append(tick)
        if self.target is None or not tick.gap_valid:
            self.u = 0.0
        else:
            self.u = max(-self.v_max, min(self.v_max, self.kp * (self.target - tick.gap_mm)))
        return self.u

    def internals(self):
        return {'u': self.u, 'limit_v': float(abs(self.u) >= self.v_max)}


class Down:
    """Drives down regardless (to provoke a collision)."""

    def command(self, name, **kwargs):
        pass

    def step(self, tick):
        return -20.0


def scenario(**over):
    d = {'name': 't', 'duration_s': 3.0, 'seed': 1, 'initial_gap_mm': 1.0,
         'timeline': [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}]}
    d.update(over)
    return scenario_from_dict(d)


def test_tick_input_fields_are_the_agreed_contract():
    assert TickInput._fields == ('t_s', 'gap_mm', 'gap_valid', 'gap_stamp_s', 'encoder_mm',
                                 'encoder_stamp_s', 'drive_enabled', 'drive_fault', 'gap_status')
    # the controller's own copy of the contract (the sim must not import the controller)
    from ladrc_follow.control.follow import TickInput as ControllerTickInput
    assert ControllerTickInput._fields == TickInput._fields
    assert isinstance(PD(), Controller)


def test_pd_follows_a_sine_sheet_with_the_analytic_error_amplitude():
    # error/sheet transfer of a P loop on b0/(s(T1 s+1)): s(T1 s + 1) / (T1 s^2 + s + kp b0)
    kp, t1, f, amp = 60.0, 0.008, 1.0, 0.5
    sc = scenario(sheet={'profiles': [{'kind': 'sine', 'amp_mm': amp, 'freq_hz': f}]},
                  axis={'t1_s': t1})
    r = run(sc, PD(kp))
    s = 2j * math.pi * f
    expect = amp * abs(s * (t1 * s + 1) / (t1 * s * s + s + kp))
    e = (r.true_gap_mm - r.target_gap_mm)[r.t_s > 1.0]
    assert np.max(np.abs(e)) == pytest.approx(expect, rel=0.05)
    assert r.metrics.collisions == 0
    assert r.metrics.error_max_mm < 2 * expect


def test_driving_down_is_reported_as_a_collision():
    r = run(scenario(duration_s=0.5), Down())
    hit = np.flatnonzero(r.collision)
    assert hit.size and r.true_gap_mm[hit[0]] <= 0.0 < r.true_gap_mm[hit[0] - 1]
    assert np.all(r.collision[hit[0]:])
    assert r.metrics.collisions == 1
    # time to contact: 1 mm at 20 mm/s after the T1 lag (1 mm = 20 (t - T1(1 - e^{-t/T1})))
    assert r.t_s[hit[0]] == pytest.approx(0.05 + 0.008, abs=0.002)


def test_same_seed_same_series_other_seed_other_noise():
    sc = load_scenario('showcase')
    kw = dict(duration_s=3.0)
    a = run(sc.__class__(**{**sc.__dict__, **kw}), PD())
    b = run(sc.__class__(**{**sc.__dict__, **kw}), PD())
    c = run(sc.__class__(**{**sc.__dict__, **kw, 'seed': 7}), PD())
    for k, v in a.series().items():
        np.testing.assert_array_equal(v, b.series()[k], err_msg=k)
    assert not np.array_equal(a.reading_mm, c.reading_mm)
    assert not np.array_equal(a.sheet_mm, c.sheet_mm)  # waviness drawn from the seed


def test_commands_are_forwarded_in_order_and_target_recorded():
    tl = [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0},
          {'t_s': 0.5, 'do': 'machining', 'on': True},
          {'t_s': 1.0, 'do': 'height_compensation', 'offset_mm': 0.2},
          {'t_s': 1.5, 'do': 'gradient_follow', 'target_gap_mm': 2.0, 'delay_s': 0.25},
          {'t_s': 2.5, 'do': 'stop_follow'}]
    pd = PD()
    r = run(scenario(timeline=tl), pd)
    assert [c[0] for c in pd.commands] == ['start_follow', 'machining', 'height_compensation',
                                           'gradient_follow', 'stop_follow']
    assert pd.commands[3][1] == {'target_gap_mm': 2.0, 'delay_s': 0.25}
    tgt = r.target_gap_mm
    i = lambda t: int(round(t / H))  # noqa: E731
    assert tgt[i(0.9)] == 1.0 and tgt[i(1.2)] == pytest.approx(1.2)
    assert tgt[i(1.74)] == pytest.approx(1.2) and tgt[i(1.76)] == pytest.approx(2.2)
    assert np.all(np.isnan(tgt[i(2.5):]))


def test_dropout_holds_the_sample_and_its_stamp():
    tl = [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0},
          {'t_s': 1.0, 'do': 'sensor_dropout', 'duration_s': 0.01},
          {'t_s': 1.5, 'do': 'encoder_dropout', 'duration_s': 0.005}]
    pd = PD()
    run(scenario(timeline=tl, duration_s=2.0), pd)
    ticks = pd.ticks
    k = int(round(1.0 / H))
    assert all(ticks[j].gap_stamp_s == ticks[k - 1].t_s for j in range(k, k + 20))
    assert ticks[k + 20].gap_stamp_s == ticks[k + 20].t_s
    k = int(round(1.5 / H))
    assert all(ticks[j].encoder_stamp_s == ticks[k - 1].t_s for j in range(k, k + 10))
    assert all(ticks[j].encoder_mm == ticks[k - 1].encoder_mm for j in range(k, k + 10))
    assert ticks[k + 10].encoder_stamp_s == ticks[k + 10].t_s
    assert all(t.gap_stamp_s == t.t_s for t in ticks[:k - 1000])


def test_drive_fault_stops_the_axis_and_is_reported():
    tl = [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0},
          {'t_s': 0.5, 'do': 'drive', 'enabled': True, 'fault': True}]
    sc = scenario(timeline=tl, duration_s=1.5,
                  sheet={'profiles': [{'kind': 'sine', 'amp_mm': 0.5, 'freq_hz': 1.0}]})
    pd = PD()
    r = run(sc, pd)
    k = int(round(0.5 / H))
    assert not pd.ticks[k - 1].drive_fault and pd.ticks[k].drive_fault
    later = r.nozzle_mm[r.t_s > 0.6]
    assert np.ptp(later) == 0.0  # stopped (braked within 0.1 s) while the sheet moves on


def test_edge_step_at_half_coverage_moves_the_axis_about_2_16_mm():
    pd = PD()
    r = run(load_scenario('edge_step_2_5'), pd)
    before = np.mean(r.nozzle_mm[(r.t_s > 0.8) & (r.t_s < 1.0)])
    after = np.mean(r.nozzle_mm[r.t_s > 2.5])
    assert after - before == pytest.approx(2.16, abs=0.1)  # notes §5.3: 2.16 mm of 3 mm
    assert np.mean(r.reading_mm[r.t_s > 2.5]) == pytest.approx(5.0, abs=0.02)


def test_miss_panel_makes_the_reading_invalid():
    tl = [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0},
          {'t_s': 0.5, 'do': 'coverage', 'value': 0.0, 'ramp_s': 0.1}]
    r = run(scenario(timeline=tl, duration_s=1.0), PD())
    assert np.all(r.reading_valid[r.t_s < 0.5]) and not np.any(r.reading_valid[r.t_s > 0.6])
    assert r.coverage[int(round(0.55 / H))] == pytest.approx(0.5, abs=0.01)


def test_internals_recorded_and_limit_flags_used():
    r = run(load_scenario('high_step_1_10'), PD(), record_internals=True)
    assert set(r.internals) == {'u', 'limit_v'}
    np.testing.assert_array_equal(r.internals['u'], r.command_mm_s)
    assert r.metrics.limit_v_ticks == int(np.sum(np.abs(r.command_mm_s) >= 200.0)) > 0


def test_schedule_ramps_linearly():
    s = schedule(10, 1.0, 1.0, [(2.0, 0.0, 4.0)])
    np.testing.assert_allclose(s, [1, 1, 0.75, 0.5, 0.25, 0, 0, 0, 0, 0])


def test_not_a_controller_is_rejected():
    with pytest.raises(ValueError, match='not a controller'):
        run(scenario(), object())


class Script:
    """Open-loop command u(t) so a reference loop can replay the run without a controller."""

    def __init__(self):
        self.truths = []

    def command(self, name, **kwargs):
        pass

    def step(self, tick):
        return 40.0 * math.sin(7.0 * tick.t_s) + 5.0

    def truth(self, *values):
        self.truths.append(values)


def reference_run(sc):
    """Step the model classes one call at a time (no fast paths) over the same scenario."""
    from ladrc_sim.models.axis import Axis
    from ladrc_sim.models.encoder import Encoder
    from ladrc_sim.models.sensor import Sensor
    from ladrc_sim.models.sheet import Sheet

    n = int(round(sc.duration_s / H))
    rng = np.random.default_rng(sc.seed)
    sheet = Sheet(sc.sheet, n, H, rng)
    ev = sc.timeline
    cov = schedule(n, H, sc.initial_coverage, [(e.t_s, e.args['value'], e.args['ramp_s'])
                                                for e in ev if e.name == 'coverage'])
    sensor = Sensor(sc.sensor, n, H, rng, gain_schedule=sheet.feedback_gain)
    encoder = Encoder(sc.encoder, n, H)
    axis = Axis(sc.axis, sheet.base_mm[0] + sc.initial_gap_mm, H)
    script = Script()
    out = []
    for i in range(n):
        for e in ev:
            if int(round(e.t_s / H)) == i and e.name == 'plate_kick':
                sheet.plate.kick(e.args['velocity_mm_s'])
            if int(round(e.t_s / H)) == i and e.name == 'gas':
                sheet.plate.set_gas(e.args['on'])
        z = sheet.height_mm(i)
        gap = axis.position_mm - z
        reading, valid, _ = sensor.measure(i, gap, cov[i])
        enc = encoder.read(i, axis.position_mm)
        u = script.step(TickInput(i * H, 0, 0, 0, 0, 0, True, False))
        out.append((reading, valid, enc, axis.position_mm, z))
        axis.step(u)
        if sheet.plate is not None:
            sheet.plate.step(gap)
    return np.array(out, dtype=float).T


@pytest.mark.parametrize('axis', [{}, {'dead_time_ticks': 3}, {'model': 'identified'}])
def test_runner_fast_paths_equal_the_model_methods_bit_for_bit(axis):
    sc = scenario_from_dict({
        'name': 'eq', 'duration_s': 1.5, 'seed': 3, 'initial_gap_mm': 2.0, 'axis': axis,
        'sensor': {'noise_std_mm': 0.01, 'quant_mm': 0.001, 'lag_s': 0.001},
        'sheet': {'profiles': [
            {'kind': 'waviness', 'rms_mm': 0.1, 'cutoff_hz': 3.0},
            {'kind': 'ridge', 't_s': 0.3, 'gain_drop': 0.2},
            {'kind': 'plate', 'gas_on_s': 0.1, 'kick_t_s': 0.4, 'kick_velocity_mm_s': 20.0}]},
        'timeline': [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0},
                     {'t_s': 0.5, 'do': 'coverage', 'value': 0.4, 'ramp_s': 0.2},
                     {'t_s': 0.9, 'do': 'coverage', 'value': 0.02},
                     {'t_s': 1.0, 'do': 'coverage', 'value': 1.0, 'ramp_s': 0.1},
                     {'t_s': 0.7, 'do': 'plate_kick', 'velocity_mm_s': -10.0},
                     {'t_s': 1.2, 'do': 'gas', 'on': False}]})
    script = Script()
    r = run(sc, script)
    reading, valid, enc, nozzle, sheet = reference_run(sc)
    np.testing.assert_array_equal(r.reading_mm, reading)
    np.testing.assert_array_equal(r.reading_valid, valid.astype(bool))
    np.testing.assert_array_equal(r.encoder_mm, enc)
    np.testing.assert_array_equal(r.nozzle_mm, nozzle)
    np.testing.assert_array_equal(r.sheet_mm, sheet)
    np.testing.assert_array_equal(r.true_gap_mm, nozzle - sheet)
    # the truth hook saw the same truth, before each step
    truths = np.array(script.truths)
    np.testing.assert_array_equal(truths[:, 1], nozzle - sheet)
    np.testing.assert_array_equal(truths[:, 3], nozzle)
    assert np.any(truths[:, 5] != 0.0)  # plate velocity


def test_raw_oscillator_frequency_follows_the_reading():
    r = run(load_scenario('step'), PD())
    f = r.raw_hz()
    up = r.reading_mm[int(round(2.0 / H))] > r.reading_mm[int(round(0.9 / H))]
    assert up and f[int(round(2.0 / H))] > f[int(round(0.9 / H))]  # farther: less C, higher f
