"""Capacitive calibration, pure: the sweep on the headless sim, the table, its checks, the file.

The sweep runs the real procedure (``SweepProcedure``) against the simulator's models
(``run_headless``: axis, flat sheet, the sensor with 5 µm noise and 1 µm quantization, raw value
= the sensor model's oscillator of each reading). The truth is the sensor model itself: at full
coverage and gain 1 the reading is the gap, so the raw value of a gap g is
``oscillator_hz(g)`` and its inverse is the true table.
"""

from __future__ import annotations

import math

from ladrc_follow.control.cap_table import (
    STATUS_COLLISION,
    STATUS_FAULT,
    STATUS_OK,
    STATUS_OUT_OF_RANGE,
    CapTable,
    RawToGap,
    TableError,
    TableLimits,
    load_table,
    table_yaml,
)
from ladrc_follow.control.follow import FollowController, FollowState, TickInput
from ladrc_follow.control.params import ControllerParams, params_from_dict
from ladrc_sim.models.sensor import EPS0_PF_PER_MM, SensorParams, oscillator_hz
from ladrc_tools.commissioning.calibration import (
    CalibrationError,
    Phase,
    SweepInput,
    SweepMotion,
    SweepProcedure,
    run_headless,
    sim_scenario,
)
from ladrc_tools.commissioning.calibration_output import summary, write_calibration
from ladrc_tools.commissioning.calibration_table import build_table
import numpy as np
import pytest
from scipy.interpolate import PchipInterpolator
import yaml

NOISE_MM = 0.005  # the sim scenario's sensor noise
FAST = SweepMotion(descent_mm_s=1.0, retract_mm_s=4.0, min_start_gap_mm=1.0)


def true_gap_mm(raw_hz):
    """Return the inverse of the sim's oscillator (the exact table): f = f0 / sqrt(1 + k / g)."""
    p = SensorParams()
    k = EPS0_PF_PER_MM * math.pi * 0.25 * p.nozzle_diameter_mm ** 2 / p.parasitic_pf
    return k / ((p.osc_f0_hz / np.asarray(raw_hz, dtype=float)) ** 2 - 1.0)


@pytest.fixture(scope='module')
def sweep():
    """One headless sweep from 5 mm at 1 mm/s (0.3 s of CPU), shared by the tests below."""
    proc = run_headless(sim_scenario(5.0, FAST), FAST)
    assert proc.succeeded, proc.reason
    return proc


def _copy_record(proc, raw_fn=None):
    rec = proc.record
    out = type(rec)(rows=list(rec.rows), start_position_mm=rec.start_position_mm,
                    contact_position_mm=rec.contact_position_mm,
                    contact_kind=rec.contact_kind, contact_seq=rec.contact_seq)
    if raw_fn is not None:
        a = out.arrays()
        raw = raw_fn(a)
        out.rows = [r[:3] + (float(raw[i]),) + r[4:] for i, r in enumerate(out.rows)]
    return out


# ---- the sweep and its table ----------------------------------------------------------
def test_sweep_motion_is_bounded_and_returns_to_the_start(sweep):
    a = sweep.record.arrays()
    rec = sweep.record
    assert rec.contact_kind == 'collision status'
    # contact found at the sheet (encoder 1 µm): the flat sheet is at 0 in the sim
    assert abs(rec.contact_position_mm) <= 0.002
    assert rec.start_position_mm == pytest.approx(5.0, abs=0.002)
    # back at the start within the tolerance, at rest
    assert abs(a['position_mm'][-1] - rec.start_position_mm) <= FAST.retract_tol_mm + 0.002
    # the descent never went further below the contact than the stop needs (8 ms lag at
    # 1 mm/s: a few µm)
    assert a['position_mm'].min() > rec.contact_position_mm - 0.02
    assert sweep.phase == Phase.DONE and not sweep.enable


def test_commands_stay_within_the_motion_bounds():
    """Every command of a sweep: down at most descent_mm_s, up at most retract_mm_s."""
    from ladrc_sim.headless.runner import run
    from ladrc_sim.headless.scenario import scenario_from_dict
    from ladrc_tools.commissioning.calibration import HeadlessSweep

    m = SweepMotion(descent_mm_s=2.0, retract_mm_s=5.0, min_start_gap_mm=1.0)
    sc = scenario_from_dict(sim_scenario(2.5, m) | {'duration_s': 4.0})
    proc = SweepProcedure(m)
    r = run(sc, HeadlessSweep(proc, sc.sensor))
    assert proc.succeeded, proc.reason
    assert r.command_mm_s.min() >= -m.descent_mm_s - 1e-12
    assert r.command_mm_s.max() <= m.retract_mm_s + 1e-12
    assert r.true_gap_mm.min() > -0.02  # stopped at once on contact
    # the stop is immediate (no ramp toward the sheet): the tick after the contact sample is 0
    i = int(np.argmax(r.true_gap_mm <= 0.0))
    after = r.command_mm_s[i:i + 40]
    assert after.min() >= 0.0 and np.argmax(after == 0.0) <= 4


def test_table_from_the_sim_sweep_is_within_the_noise_of_the_truth(sweep):
    cal = build_table(sweep.record)
    assert not cal.problems, cal.problems
    f = cal.figures
    assert cal.grade == 'A'
    assert f['noise_mm'] == pytest.approx(NOISE_MM, rel=0.15)
    assert f['gap_min_mm'] == pytest.approx(0.05) and f['gap_max_mm'] > 4.5
    # each table point against the exact inverse of the sensor model
    t = cal.table
    err = np.asarray(t.gap_mm) - true_gap_mm(t.raw_hz)
    assert np.abs(err).max() < NOISE_MM, np.abs(err).max()
    # the conversion between the points (PCHIP), on noise-free raw values of a fine grid
    conv = RawToGap(t)
    g = np.linspace(t.gap_mm[0] + 0.01, t.gap_mm[-1] - 0.01, 20001)  # ends: fit noise
    between = conv.gaps_mm(oscillator_hz(g, SensorParams())) - g
    assert np.abs(between).max() < NOISE_MM, np.abs(between).max()
    # the figure the tool reports from the sim's truth agrees
    assert f['max_error_mm'] < NOISE_MM
    assert f['repeatability_mm'] < 2 * NOISE_MM
    s = summary(cal)
    assert {'points', 'range_mm', 'max_error_mm', 'grade', 'noise_mm'} <= set(s)


def test_a_contact_error_would_show(sweep):
    """A wrong contact position (20 µm) moves every point: the truth check catches it."""
    rec = _copy_record(sweep)
    rec.contact_position_mm += 0.02
    cal = build_table(rec)
    err = np.asarray(cal.table.gap_mm) - true_gap_mm(cal.table.raw_hz)
    assert np.abs(err).min() > 0.015
    assert cal.figures['max_error_mm'] > 0.015


def test_table_file_round_trip_and_outputs(sweep, tmp_path):
    cal = build_table(sweep.record, meta={'source': 'test'})
    out = write_calibration(cal, tmp_path / 'cal')
    for name in ('cap_table.yaml', 'sweep.csv', 'calibration.png', 'calibration.md',
                 'calibration.json'):
        assert (out / name).is_file(), name
    conv = load_table(out / 'cap_table.yaml')
    assert conv.grade == 'A'
    raws = np.asarray(cal.table.raw_hz)
    q = np.linspace(raws[0], raws[-1], 999)
    np.testing.assert_array_equal(conv.gaps_mm(q), RawToGap(cal.table).gaps_mm(q))
    assert yaml.safe_load((out / 'cap_table.yaml').read_text())['calibration']['source'] == 'test'
    with pytest.raises(FileExistsError):
        write_calibration(cal, out)


# ---- corrupted sweeps: rejected with the reason ---------------------------------------
def test_non_monotonic_sweep_is_rejected(sweep, tmp_path):
    # a disturbed band (2.0-2.4 mm): the raw value reads as if 1 mm lower
    def glitch(a):
        gap = a['position_mm'] - sweep.record.contact_position_mm
        band = (gap > 2.0) & (gap < 2.4)
        raw = a['raw_hz'].copy()
        raw[band] = oscillator_hz(gap[band] - 1.0, SensorParams())
        return raw
    cal = build_table(_copy_record(sweep, glitch))
    assert cal.grade == 'F'
    assert any('not monotonic' in p for p in cal.problems), cal.problems
    out = write_calibration(cal, tmp_path / 'bad')
    assert not (out / 'cap_table.yaml').exists()
    with pytest.raises(TableError, match='not monotonic'):
        load_table(out / 'cap_table.rejected.yaml')


def test_drifted_sweep_is_rejected(sweep):
    # the oscillator drifts 10 Hz/s (20 ppm/s) during the sweep: descent and retract disagree
    cal = build_table(_copy_record(sweep, lambda a: a['raw_hz'] + 10.0 * a['t_s']))
    assert any(p.startswith('drifted') for p in cal.problems), cal.problems
    assert cal.figures['repeatability_mm'] > 0.05


def test_too_short_sweep_is_rejected():
    m = SweepMotion(descent_mm_s=1.0, retract_mm_s=4.0, min_start_gap_mm=0.5)
    proc = run_headless(sim_scenario(1.5, m), m)
    assert proc.succeeded, proc.reason
    cal = build_table(proc.record)
    assert any(p.startswith('too short') for p in cal.problems), cal.problems


def test_noisy_sweep_is_rejected():
    proc = run_headless(sim_scenario(4.0, FAST, noise_std_mm=0.1), FAST)
    assert proc.succeeded, proc.reason
    cal = build_table(proc.record)
    assert any(p.startswith('noisy') for p in cal.problems), cal.problems


def test_no_contact_within_the_travel_limit_retracts_and_fails():
    m = SweepMotion(descent_mm_s=2.0, retract_mm_s=5.0, max_travel_mm=1.5,
                    min_start_gap_mm=1.0)
    proc = run_headless(sim_scenario(4.0, m), m)
    assert proc.phase == Phase.DONE and not proc.succeeded
    assert 'no contact within max_travel_mm' in proc.reason
    a = proc.record.arrays()
    assert a['position_mm'].min() > 4.0 - 1.5 - 0.05  # stopped at the limit
    assert a['position_mm'][-1] == pytest.approx(4.0, abs=0.02)  # and went back
    with pytest.raises(CalibrationError, match='no contact'):
        build_table(proc.record)


# ---- the procedure's safety, tick by tick ---------------------------------------------
def _inp(t, pos, **kw):
    d = dict(t_s=t, raw_hz=480e3, gap_mm=math.nan, valid=True, status=STATUS_OK,
             gap_stamp_s=t, position_mm=pos, enc_stamp_s=t, drive_enabled=True,
             drive_fault=False)
    d.update(kw)
    return SweepInput(**d)


def _descending():
    p = SweepProcedure(SweepMotion())
    t = 0.0
    while p.phase == Phase.WAIT:
        p.step(_inp(t, 5.0))
        t += 0.0005
    return p, t


@pytest.mark.parametrize('surprise, reason', [
    ({'drive_fault': True}, 'drive fault'),
    ({'drive_enabled': False}, 'drive disabled'),
    ({'gap_stamp_s': -1.0}, 'stale input'),
    ({'position_mm': math.nan}, 'encoder position not finite'),
    ({'status': STATUS_FAULT}, 'sensor reports a fault'),
    ({'raw_hz': math.inf}, 'raw value not finite'),
])
def test_every_surprise_ends_in_zero_with_enable_false(surprise, reason):
    p, t = _descending()
    for _ in range(200):
        v, en = p.step(_inp(t, 5.0 - 0.0001))
        t += 0.0005
    assert v < 0.0 and en
    v, en = p.step(_inp(t, 4.99, **surprise))
    assert (v, en) == (0.0, False) and p.phase == Phase.ABORTED
    assert reason in p.reason
    assert p.step(_inp(t + 0.0005, 4.99)) == (0.0, False)  # for good


def test_a_stale_stream_at_rest_is_waited_for_then_aborts():
    """Resting at the start (zero command), a stream that is not fresh yet is waited for."""
    from ladrc_tools.commissioning.calibration import WAIT_STALE_S

    p = SweepProcedure()
    t = 0.0
    while t < WAIT_STALE_S:
        assert p.step(_inp(t, 5.0, gap_stamp_s=-1.0)) == (0.0, True)
        assert p.phase == Phase.WAIT
        t += 0.01
    v, en = p.step(_inp(t + 1.0, 5.0, gap_stamp_s=-1.0))
    assert (v, en) == (0.0, False) and 'stale input in phase WAIT' in p.reason
    # fresh again in time: the settle time counts from the last stale tick, then the descent
    p = SweepProcedure(SweepMotion(settle_s=0.1))
    p.step(_inp(0.0, 5.0))
    p.step(_inp(0.08, 5.0, gap_stamp_s=-1.0))
    t = 0.09
    while p.phase == Phase.WAIT:
        p.step(_inp(t, 5.0))
        t += 0.0005
    assert t == pytest.approx(0.18, abs=0.002)


def _descend_until_stop(p, t, pos, **kw):
    """Follow the procedure's commands with an ideal axis; return the lowest position."""
    low = pos
    for _ in range(200_000):
        if p.finished or p.phase != Phase.DESCEND:
            break
        v, enable = p.step(_inp(t, pos, **{k: f(pos) for k, f in kw.items()}))
        pos += (v if enable else 0.0) * 0.0005
        low = min(low, pos)
        t += 0.0005
    return low


def test_a_frozen_sensor_stops_the_descent():
    """The same raw value while the axis travels 0.5 mm: stop and retract, no contact."""
    p, t = _descending()
    low = _descend_until_stop(p, t, 5.0)
    assert 'raw value frozen' in p.reason and not p.record.contact_kind
    assert low > 5.0 - 0.5 - 0.01
    # a raw value that changes as the axis closes in goes on
    p, t = _descending()
    low = _descend_until_stop(p, t, 5.0, raw_hz=lambda pos: 480e3 + 100.0 * pos,
                              status=lambda pos: STATUS_COLLISION if pos < 4.0 else STATUS_OK)
    assert p.record.contact_kind == 'collision status' and 3.99 < low < 4.0


def test_with_a_published_gap_the_descent_ends_at_the_reading():
    """A sensor that never reports contact: stop at a reading below 0, or at start + 0.5 mm."""
    # the published gap goes below zero (no collision status): contact by the reading
    p = SweepProcedure(SweepMotion(min_start_gap_mm=1.0))
    t = 0.0
    while p.phase == Phase.WAIT:
        p.step(_inp(t, 5.0, gap_mm=3.0))
        t += 0.0005
    low = _descend_until_stop(p, t, 5.0, raw_hz=lambda pos: 480e3 + 100.0 * pos,
                              gap_mm=lambda pos: pos - 2.0)
    assert p.record.contact_kind == 'gap reading below zero' and 1.94 < low < 1.96
    # a reading that stays up while the axis goes down (a sprung nozzle, a wrong table):
    # at most the start reading + 0.5 mm, then stop and retract
    p = SweepProcedure(SweepMotion(min_start_gap_mm=1.0))
    t = 0.0
    while p.phase == Phase.WAIT:
        p.step(_inp(t, 5.0, gap_mm=3.0))
        t += 0.0005
    low = _descend_until_stop(p, t, 5.0, raw_hz=lambda pos: 480e3 + 100.0 * pos,
                              gap_mm=lambda pos: 3.0)
    assert 'without contact, more than the start reading 3.000 mm' in p.reason
    assert low > 5.0 - 3.5 - 0.01


def test_start_must_be_valid_and_high_enough():
    p = SweepProcedure(SweepMotion(min_start_gap_mm=2.0))
    assert p.step(_inp(0.0, 5.0, gap_mm=1.0)) == (0.0, False)
    assert 'start too low' in p.reason
    p = SweepProcedure()
    assert p.step(_inp(0.0, 5.0, valid=False, status=STATUS_OUT_OF_RANGE)) == (0.0, False)
    assert 'not valid' in p.reason


def test_stall_against_the_sheet_is_contact():
    """The encoder stops while commanding down (no collision status): stop, then retract."""
    p, t = _descending()
    pos = 5.0
    for _ in range(4000):  # 2 s: full speed, then the axis stops at 4.5 mm
        v, _ = p.step(_inp(t, pos))
        if p.phase != Phase.DESCEND:
            break
        pos = max(4.5, pos + v * 0.0005)
        t += 0.0005
    assert p.phase == Phase.STOP and p.record.contact_kind == 'stall'
    assert p.record.contact_position_mm == pytest.approx(4.5)
    assert p.velocity_mm_s == 0.0


def test_runaway_axis_is_a_surprise():
    p, t = _descending()
    pos = 5.0
    for _ in range(400):
        p.step(_inp(t, pos))
        pos -= 0.005  # 10 mm/s on a 0.5 mm/s command
        t += 0.0005
        if p.finished:
            break
    assert p.phase == Phase.ABORTED and 'faster than' in p.reason


def test_motion_bounds_are_checked():
    with pytest.raises(CalibrationError, match='descent_mm_s'):
        SweepProcedure(SweepMotion(descent_mm_s=5.0))
    with pytest.raises(CalibrationError, match='max_travel_mm'):
        SweepProcedure(SweepMotion(max_travel_mm=math.inf))


# ---- the table type (the controller's side) -------------------------------------------
def test_interpolation_equals_scipy_pchip():
    rng = np.random.default_rng(4)
    gap = np.cumsum(rng.uniform(0.01, 0.3, 40))
    raw = np.cumsum(rng.uniform(1.0, 500.0, 40)) + 4e5
    limits = TableLimits(max_first_gap_mm=1.0, max_roughness_mm=1e9)
    conv = RawToGap(CapTable(tuple(raw), tuple(gap), 0.001), limits)  # random: not smooth
    ref = PchipInterpolator(raw, gap)
    q = np.linspace(raw[0], raw[-1], 5001)
    np.testing.assert_allclose(conv.gaps_mm(q), ref(q), rtol=0, atol=1e-12)
    for r in q[::97]:
        assert conv.gap_mm(float(r)) == pytest.approx(float(ref(r)), abs=1e-12)
    assert np.all(np.diff(conv.gaps_mm(q)) >= 0)  # monotone
    # the same table with the raw values the other way round (a vendor mix-up: it would
    # read "far" at contact) is refused: the contract's frequency rises with the gap
    with pytest.raises(TableError, match='raw falls with the gap'):
        RawToGap(CapTable(tuple(2 * 4e5 - raw), tuple(gap), 0.001), limits)


def _sim_table(step=0.02, top=6.0, noise=0.004) -> CapTable:
    g = np.round(np.arange(0.05, top + 1e-9, step), 9)
    return CapTable(tuple(oscillator_hz(g, SensorParams())), tuple(g), noise)


def test_out_of_range_raw_is_invalid_never_extrapolated():
    conv = RawToGap(_sim_table())
    lo, hi = conv.raw_min_hz, conv.raw_max_hz
    # wider than calibrated: the widest gap, invalid, out of range
    assert conv.convert(hi + 1.0, True, STATUS_OK) == (conv.gap_max_mm, False,
                                                       STATUS_OUT_OF_RANGE)
    # closer than calibrated: the smallest gap, invalid, a collision whatever the driver sent
    # (an out-of-range status would read as miss-panel: no retract), never below the table
    assert conv.convert(lo - 1.0, True, STATUS_OK) == (conv.gap_min_mm, False,
                                                       STATUS_COLLISION)
    assert conv.convert(lo - 1.0, False, STATUS_OUT_OF_RANGE) == (conv.gap_min_mm, False,
                                                                  STATUS_COLLISION)
    assert math.isnan(conv.gap_mm(lo - 1e-6)) and math.isnan(conv.gap_mm(hi + 1e-6))
    assert conv.convert(math.nan, True, STATUS_OK)[1:] == (False, STATUS_FAULT)
    # the sensor's own status passes, even in range
    mid = float(oscillator_hz(1.0, SensorParams()))
    g, ok, st = conv.convert(mid, True, STATUS_COLLISION)
    assert not ok and st == STATUS_COLLISION and g == pytest.approx(1.0, abs=1e-4)
    assert conv.convert(mid, True, STATUS_OK)[1:] == (True, STATUS_OK)
    assert conv.out_of_range == 3


def test_closer_than_the_table_is_a_collision_for_the_controller():
    conv = RawToGap(_sim_table())
    gap, valid, status = conv.convert(conv.raw_min_hz - 100.0, True, STATUS_OK)
    c = FollowController(ControllerParams())
    c.command('start_follow', target_gap_mm=1.0)
    u = c.step(TickInput(0.0, gap, valid, 0.0, 5.0, 0.0, True, False, status))
    assert c.state == FollowState.FAULT and 'collision' in c.fault_reason
    assert u >= 0.0


@pytest.mark.parametrize('change, reason', [
    (lambda d: d.update(points=d['points'][:5]), 'too few points'),
    (lambda d: d['points'].__setitem__(3, [math.nan, 0.1]), 'non-finite'),
    (lambda d: d['points'].__setitem__(10, [d['points'][20][0], d['points'][10][1]]),
     'not monotonic'),
    (lambda d: d['points'].__setitem__(10, [d['points'][10][0], 5.0]),
     'gaps not strictly increasing'),
    (lambda d: d.update(points=d['points'][:60]), 'too short'),
    (lambda d: d.update(points=d['points'][40:]), 'starts at'),
    (lambda d: d.update(noise_mm=0.2), 'noisy'),
    (lambda d: d.update(repeatability_mm=0.08), 'drifted'),
    (lambda d: d.pop('noise_mm'), 'noise_mm missing'),
    (lambda d: d.update(format='other/1'), 'format'),
    (lambda d: d.update(points='none'), 'points must be a list'),
    (lambda d: d.update(repeatability_mm=float('inf')), 'repeatability_mm'),
    (lambda d: d.update(repeatability_mm=-5.0), 'repeatability_mm'),
    (lambda d: d.update(noise_mm=10 ** 400), 'noise_mm missing or not a number'),
    (lambda d: d.update(points=[[2 * d['points'][0][0] - r, g] for r, g in d['points']]),
     'raw falls with the gap'),
])
def test_broken_table_files_are_rejected_with_the_reason(tmp_path, change, reason):
    d = yaml.safe_load(table_yaml(_sim_table()))
    load_table_ok = tmp_path / 'ok.yaml'
    load_table_ok.write_text(yaml.safe_dump(d))
    assert load_table(load_table_ok).grade == 'A'
    change(d)
    bad = tmp_path / 'bad.yaml'
    bad.write_text(yaml.safe_dump(d))
    with pytest.raises(TableError, match=reason):
        load_table(bad)


def test_a_kinked_table_is_not_smooth():
    """Monotone but kinked: one point's raw value moved next to its neighbour's."""
    g = np.round(np.concatenate([np.arange(0.05, 1.0, 0.01), np.arange(1.0, 6.01, 0.2)]), 9)
    t = CapTable(tuple(oscillator_hz(g, SensorParams())), tuple(g), 0.004)
    k = len(g) - 10  # a point of the coarse part (0.2 mm apart)
    raw = list(t.raw_hz)
    raw[k] = raw[k - 1] + 0.05 * (raw[k] - raw[k - 1])
    kinked = CapTable(tuple(raw), t.gap_mm, t.noise_mm)
    assert not kinked.structure_problems()
    assert kinked.roughness_mm() > 0.1
    with pytest.raises(TableError, match='not smooth'):
        RawToGap(kinked)
    # the same table without the kink: smooth, and a slightly rough one grades lower
    assert t.roughness_mm() < 0.01 and t.grade() == 'A'
    raw[k] = t.raw_hz[k] - 0.1 * (t.raw_hz[k] - t.raw_hz[k - 1])
    assert CapTable(tuple(raw), t.gap_mm, t.noise_mm).grade() in ('B', 'C')


def test_unreadable_table_files(tmp_path):
    with pytest.raises(TableError, match='cannot read'):
        load_table(tmp_path / 'missing.yaml')
    (tmp_path / 'x.yaml').write_text('points: [1, 2\n')
    with pytest.raises(TableError, match='not valid YAML'):
        load_table(tmp_path / 'x.yaml')


def test_the_table_parameter_is_declared_once():
    p = params_from_dict({'sensor': {'table_file': '/tmp/t.yaml'}})
    assert p.sensor.table_file == '/tmp/t.yaml'
    assert ControllerParams().sensor.table_file == ''
    with pytest.raises(ValueError, match='sensor.table_file'):
        params_from_dict({'sensor.table_file': 3})


# ---- the controller with the table: follows as with the published gap -----------------
class _ViaTable:
    """The follow controller fed through the table: raw value of each reading -> gap."""

    def __init__(self, controller, conv, sensor):
        self.c, self.conv, self.sensor = controller, conv, sensor

    def command(self, name, **kwargs):
        return self.c.command(name, **kwargs)

    def step(self, tick):
        raw = float(oscillator_hz(tick.gap_mm, self.sensor))
        gap, valid, status = self.conv.convert(raw, tick.gap_valid, tick.gap_status)
        return self.c.step(tick._replace(gap_mm=gap, gap_valid=valid, gap_status=status))


@pytest.mark.parametrize('name', ['sine_1hz', 'step'])
def test_headless_follow_through_the_table_equals_the_gap_run(name):
    from ladrc_sim.headless.runner import run
    from ladrc_sim.headless.scenario import load_scenario

    sc = load_scenario(name)
    m = SweepMotion(descent_mm_s=1.0, retract_mm_s=5.0, min_start_gap_mm=1.0)
    proc = run_headless(sim_scenario(12.0, m, noise_std_mm=sc.sensor.noise_std_mm,
                                     quant_mm=sc.sensor.quant_mm), m)
    conv = RawToGap(build_table(proc.record).table)
    # the laws alone: the edge verification's yes/no decisions would turn the table's
    # sub-micrometre differences into a different number of moves up
    law = params_from_dict({'edge': {'verify_sink': 0.0, 'verify_start_mm': 0.0}})
    plain = run(sc, FollowController(law)).metrics
    table = run(sc, _ViaTable(FollowController(law), conv, sc.sensor)).metrics
    assert table.collisions == plain.collisions == 0
    assert table.error_rms_mm == pytest.approx(plain.error_rms_mm, rel=0.02)
