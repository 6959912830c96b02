"""The PREINTERPOLATE move planner: v/a limits, exact landing, re-targeting."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st
from ladrc_follow.control.interp import Interpolator, InterpParams, stop_velocity
import pytest

H = 0.0005


def run(ip, max_ticks=200000):
    vs = []
    while not ip.is_finished():
        vs.append(ip.step())
        assert len(vs) < max_ticks
    return vs


def check_limits(vs, v0, v_max, a_max):
    dv = a_max * H
    prev = v0
    for v in vs:
        assert abs(v) <= v_max * (1 + 1e-12) or abs(v) <= abs(prev)  # only braking above v_max
        assert abs(v - prev) <= dv * (1 + 1e-9)
        prev = v


@pytest.mark.parametrize('d', [0.3, 1.0, 7.0, 25.0])
def test_stop_velocity_brakes_exactly_within_distance(d):
    dv = 2000.0 * H
    v = stop_velocity(d, dv, H)
    seq, x = v, 0.0
    while seq > 0.0:
        x += seq * H
        seq -= dv
    assert x == pytest.approx(d, rel=1e-9)


@settings(max_examples=60, deadline=None)
@given(d=st.floats(-30.0, 30.0).filter(lambda x: abs(x) > 1e-6),
       v_max=st.floats(5.0, 300.0), a_max=st.floats(200.0, 20000.0))
def test_single_move_limits_landing_and_time(d, v_max, a_max):
    ip = Interpolator(InterpParams(v_max, a_max), H)
    ip.go_distance(d)
    vs = run(ip)
    check_limits(vs, 0.0, v_max, a_max)
    assert ip.position_mm == pytest.approx(d, abs=1e-9)
    assert ip.cached_length_mm == 0.0
    # continuous time-optimal trapezoid/triangle time, plus at most a few ticks of sampling
    dist = abs(d)
    if dist >= v_max * v_max / a_max:
        t_opt = dist / v_max + v_max / a_max
    else:
        t_opt = 2.0 * math.sqrt(dist / a_max)
    assert len(vs) * H <= t_opt + 3 * H
    assert len(vs) * H >= t_opt - 2 * H


@settings(max_examples=60, deadline=None)
@given(d1=st.floats(-20.0, 20.0), d2=st.floats(-20.0, 20.0),
       k_switch=st.integers(1, 3000), v_max=st.floats(10.0, 200.0),
       a_max=st.floats(500.0, 10000.0))
def test_retarget_mid_move_including_reversal(d1, d2, k_switch, v_max, a_max):
    ip = Interpolator(InterpParams(v_max, a_max), H)
    ip.go_distance(d1)
    vs = []
    for _ in range(k_switch):
        vs.append(ip.step())
    ip.go_distance(d2)          # more, less or back: the plan changes mid-move
    vs += run(ip)
    check_limits(vs, 0.0, v_max, a_max)
    assert ip.position_mm == pytest.approx(d1 + d2, abs=1e-9)


def test_seed_usage_cached_length():
    """Follow_OnStep: every tick go_distance(target − height − cached), axis follows the plan."""
    ip = Interpolator(InterpParams(100.0, 2000.0), H)
    height, target = 10.0, 1.0
    vs = []
    for _ in range(4000):
        ip.go_distance(target - height - ip.cached_length_mm)
        v = ip.step()
        vs.append(v)
        height += v * H        # an ideal axis
    check_limits(vs, 0.0, 100.0, 2000.0)
    assert height == pytest.approx(target, abs=1e-9)


def test_start_from_moving_axis():
    ip = Interpolator(InterpParams(50.0, 1000.0), H)
    ip.reset(velocity_mm_s=-40.0)      # moving down, asked to go up
    ip.go_distance(2.0)
    vs = run(ip)
    check_limits(vs, -40.0, 50.0, 1000.0)
    assert ip.position_mm == pytest.approx(2.0, abs=1e-9)


def test_bad_input():
    with pytest.raises(ValueError,
                       match=r'interp.v_max_mm_s = 0: outside its range \[0.1, 1000\] mm/s'):
        Interpolator(InterpParams(0.0, 100.0))
    ip = Interpolator()
    with pytest.raises(ValueError, match='finite distance'):
        ip.go_distance(float('nan'))
