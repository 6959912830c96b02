"""PID follow baseline: analytic closed-loop responses, feed-forward, suppression, limits."""

from dataclasses import replace

from hypothesis import given, settings
from hypothesis import strategies as st
from ladrc_contract.ops import ARRAY
from ladrc_follow.control.pid import (
    SUPPRESS_DEADBAND_MM,
    SUPPRESS_GAIN_SCALE,
    FollowPID,
    PIDParams,
)
import numpy as np
import pytest

H = 0.0005
P_ONLY = PIDParams(kp_1_s=30.0, kd=0.0, ki_1_s2=0.0, ff_ref_gain=0.0, ff_surface_gain=0.0,
                   v_max_mm_s=1000.0, a_max_mm_s2=1e6)


def loop(pid, n, gap0, target, v_sheet=0.0, b=1.0):
    """Ideal axis: gap' = b·u − v_sheet; encoder = nozzle position."""
    gap, enc = gap0, 0.0
    gaps = []
    for _ in range(n):
        u = pid.step(gap, enc, target)
        gap += H * (b * u - v_sheet)
        enc += H * b * u
        gaps.append(gap)
    return np.array(gaps)


def test_p_only_error_decays_geometrically():
    pid = FollowPID(P_ONLY, H)
    pid.reset(1.0, 1.0)
    gaps = loop(pid, 400, 1.0, 1.5)
    # gap' = kp·(r − gap) sampled: e(k+1) = (1 − kp·h)·e(k) exactly
    k = np.arange(1, 401)
    assert gaps == pytest.approx(1.5 - 0.5 * (1 - 30.0 * H) ** k, abs=1e-12)


def test_no_derivative_kick_on_target_step():
    pid = FollowPID(replace(P_ONLY, kd=0.5), H)
    pid.reset(1.0, 1.0)
    pid.step(1.0, 0.0, 1.0)
    pid.step(1.0, 0.0, 2.0)    # target jumps by 1 mm
    assert pid.d_term == 0.0   # derivative acts on the measurement only
    assert pid.p_term == pytest.approx(30.0)


def test_derivative_filter_is_first_order_lowpass():
    p = replace(P_ONLY, kd=1.0, d_filter_s=0.004)
    pid = FollowPID(p, H)
    pid.reset(1.0, 1.0)
    rate = 2.0            # gap ramps at 2 mm/s
    c = H / (0.004 + H)
    for k in range(1, 50):
        pid.step(1.0 + rate * H * k, None, 1.0)
        assert pid.gap_rate_mm_s == pytest.approx(rate * (1 - (1 - c) ** k), rel=1e-9)


@pytest.mark.parametrize('g_ff', [0.0, 0.2, 1.0])
def test_surface_feed_forward_ramp_error(g_ff):
    # sheet rising at 6 mm/s → gap' = u − 6; P with surface ff g: e_ss = (1 − g)·v/kp
    p = replace(P_ONLY, ff_surface_gain=g_ff, ff_delay_s=0.01)
    pid = FollowPID(p, H)
    pid.reset(1.0, 1.0, encoder_mm=0.0)
    pid.enable_feed_forward(True)
    gaps = loop(pid, 4000, 1.0, 1.0, v_sheet=6.0)
    assert 1.0 - gaps[-1] == pytest.approx((1 - g_ff) * 6.0 / 30.0, rel=1e-3, abs=1e-6)


def test_feed_forward_enable_delay():
    p = replace(P_ONLY, ff_surface_gain=1.0, ff_delay_s=0.01)   # 20 ticks
    pid = FollowPID(p, H)
    pid.reset(1.0, 1.0, encoder_mm=0.0)
    pid.enable_feed_forward(True)
    terms = []
    for k in range(40):
        pid.step(1.0, 0.1 * k, 1.0)      # surface moving at 200 mm/s
        terms.append(pid.ff_term)
    assert all(t == 0.0 for t in terms[:19]) and all(t > 0.0 for t in terms[20:])
    assert pid.is_feed_forward_enabled()


def test_integral_removes_ramp_error_and_holds_when_saturated():
    p = replace(P_ONLY, ki_1_s2=200.0, v_max_mm_s=20.0)
    pid = FollowPID(p, H)
    pid.reset(1.0, 1.0)
    gaps = loop(pid, 8000, 1.0, 1.0, v_sheet=6.0)
    assert gaps[-1] == pytest.approx(1.0, abs=1e-6)
    # far target: the output saturates, the integrator must not wind up
    pid.reset(0.0, 5.0)
    i_hist = []
    gap = 0.0
    for _ in range(200):
        u = pid.step(gap, None, 5.0)
        assert u == pytest.approx(20.0) or len(i_hist) < 1
        i_hist.append(pid.i_term)
        gap += H * u
    assert max(abs(i) for i in i_hist) < 1e-12   # conditional integration held it at 0


@pytest.mark.parametrize('level', [0, 3, 5])
def test_suppression_gain_and_deadband(level):
    p = replace(P_ONLY, suppress_level=level)
    pid = FollowPID(p, H)
    pid.reset(1.0, 1.0)
    pid.set_suppress(True)
    db = SUPPRESS_DEADBAND_MM[level]
    pid.step(1.0 - 0.8 * db, None, 1.0)          # inside the deadband: no P action
    assert pid.p_term == 0.0
    pid.step(1.0 - 0.2, None, 1.0)               # outside: scaled gain on (e − db)
    assert pid.p_term == pytest.approx(SUPPRESS_GAIN_SCALE[level] * 30.0 * (0.2 - db))
    pid.set_suppress(False)
    pid.step(1.0 - 0.2, None, 1.0)
    assert pid.p_term == pytest.approx(30.0 * 0.2)


def test_has_followed_needs_hold_time():
    p = replace(P_ONLY, followed_tol_mm=0.05, followed_hold_s=0.01)   # 20 ticks
    pid = FollowPID(p, H)
    pid.reset(1.0, 1.0)
    for _ in range(19):
        pid.step(1.02, None, 1.0)
    assert not pid.has_followed()
    pid.step(1.02, None, 1.0)
    assert pid.has_followed()
    pid.step(1.2, None, 1.0)                     # leaving the band resets the count
    assert not pid.has_followed()


def test_set_pre_out_is_bumpless():
    p = replace(P_ONLY, a_max_mm_s2=2000.0)
    pid = FollowPID(p, H)
    pid.reset(3.0, 1.0)
    pid.set_pre_out(-40.0)                       # the interpolator was moving down at 40
    u = pid.step(3.0, None, 1.0)
    assert u == pytest.approx(-40.0 - 2000.0 * H)   # P wants −60: rate-limited from −40


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(0, 20)),
                min_size=1, max_size=30))
def test_limits_never_exceeded(rows):
    p = PIDParams(ki_1_s2=50.0, v_max_mm_s=60.0, a_max_mm_s2=3000.0)
    pid = FollowPID(p, H)
    pid.reset(1.0, 1.0, encoder_mm=0.0)
    pid.enable_feed_forward(True)
    pid.set_suppress(True)
    prev = 0.0
    for gap, enc, target in rows:
        u = pid.step(gap, enc, target)
        assert abs(u) <= 60.0 and abs(u - prev) <= 3000.0 * H * (1 + 1e-12)
        prev = u


def test_batch_rows_equal_scalar_runs():
    kps = [10.0, 20.0, 45.0]
    ps = [replace(PIDParams(), kp_1_s=k) for k in kps]
    rng = np.random.default_rng(1)
    gaps = 1.0 + 0.1 * rng.standard_normal((300, 1))
    # a batch over rows with the same params but different inputs, then per-kp scalar runs
    pid_b = FollowPID(ps[1], H, ops=ARRAY)
    pid_b.reset(np.ones(3), np.ones(3), encoder_mm=np.zeros(3))
    pid_b.enable_feed_forward(True)
    scal = [FollowPID(ps[1], H) for _ in range(3)]
    for s in scal:
        s.reset(1.0, 1.0, encoder_mm=0.0)
        s.enable_feed_forward(True)
    offsets = np.array([0.0, 0.05, -0.05])
    for k in range(300):
        ub = pid_b.step(gaps[k] + offsets, 0.001 * k + offsets, 1.0)
        for i, s in enumerate(scal):
            assert ub[i] == s.step(float(gaps[k, 0] + offsets[i]), 0.001 * k + offsets[i], 1.0)


def test_bad_params_rejected():
    with pytest.raises(ValueError, match=r'pid.kp_1_s = 0: outside its range \(0, 1000\] 1/s'):
        FollowPID(replace(PIDParams(), kp_1_s=0.0))
    with pytest.raises(ValueError, match=r'pid.suppress_level = 7: outside its range \[0, 5\]'):
        FollowPID(replace(PIDParams(), suppress_level=7))
