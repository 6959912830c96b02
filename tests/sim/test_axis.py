"""Axis model against the analytic responses of b0 / (s (T1 s + 1)) (notes §1.1)."""

import math

from ladrc_sim.models.axis import IDENTIFIED_DEN, IDENTIFIED_NUM, Axis, AxisParams, ParamError
import numpy as np
import pytest
from scipy import signal

H = 0.0005


def step_response(t, b0, t1):
    """Position after a unit velocity command from rest: b0 (t - T1 (1 - e^{-t/T1}))."""
    return b0 * (t - t1 * (1.0 - np.exp(-t / t1)))


def run_axis(axis, cmds, enabled=True, fault=False):
    out = [axis.step(u, enabled, fault) for u in cmds]
    return np.array([o[0] for o in out]), np.array([o[1] for o in out])


def test_step_response_is_exact_at_the_ticks():
    b0, t1, u = 1.3, 0.007, 20.0
    axis = Axis(AxisParams(b0=b0, t1_s=t1, a_max_mm_s2=1e9, v_max_mm_s=1e9), 5.0)
    x, v = run_axis(axis, [u] * 200)
    t = H * np.arange(1, 201)
    np.testing.assert_allclose(x, 5.0 + u * step_response(t, b0, t1), rtol=0, atol=1e-9)
    np.testing.assert_allclose(v, b0 * u * (1.0 - np.exp(-t / t1)), rtol=0, atol=1e-9)


def test_staircase_is_the_superposition_of_step_responses():
    # a varying ZOH command is exact too: sum of shifted step responses (linearity).
    b0, t1 = 1.0, 0.005
    rng = np.random.default_rng(0)
    cmds = rng.uniform(-30, 30, 100)
    axis = Axis(AxisParams(b0=b0, t1_s=t1, a_max_mm_s2=1e9, v_max_mm_s=1e9))
    x, _ = run_axis(axis, cmds)
    du = np.diff(cmds, prepend=0.0)
    t = H * np.arange(1, 101)
    expect = sum(d * np.where(t > k * H, step_response(np.maximum(t - k * H, 0), b0, t1), 0)
                 for k, d in enumerate(du))
    np.testing.assert_allclose(x, expect, atol=1e-9)


def test_ramp_response_matches_the_continuous_ramp():
    # x(t) = b0 r (t^2/2 - T1 t + T1^2 (1 - e^{-t/T1})) for u = r t; the staircase is
    # sampled at mid-tick so it deviates only O(h^2).
    b0, t1, r = 1.0, 0.008, 200.0
    axis = Axis(AxisParams(b0=b0, t1_s=t1, a_max_mm_s2=1e9, v_max_mm_s=1e9))
    n = 1000
    x, _ = run_axis(axis, [r * (k + 0.5) * H for k in range(n)])
    t = H * np.arange(1, n + 1)
    expect = b0 * r * (t * t / 2 - t1 * t + t1 * t1 * (1 - np.exp(-t / t1)))
    np.testing.assert_allclose(x, expect, atol=2e-5)


def test_velocity_and_acceleration_limits_hold():
    p = AxisParams(v_max_mm_s=150.0, a_max_mm_s2=4000.0)
    axis = Axis(p)
    x, v = run_axis(axis, [1000.0] * 400 + [-1000.0] * 400)
    vv = np.concatenate(([0.0], v))
    assert np.max(np.abs(v)) <= 150.0 + 1e-9
    assert np.max(np.abs(np.diff(vv))) <= 4000.0 * H + 1e-9
    assert v[399] == pytest.approx(150.0, abs=1e-6)  # reached the velocity limit
    # the start is acceleration-limited: v = a t exactly over the first ticks
    np.testing.assert_allclose(v[:5], 4000.0 * H * np.arange(1, 6))
    # while limited, the position integrates the constant acceleration exactly (trapezoid)
    np.testing.assert_allclose(np.diff(x[:50]), 0.5 * H * (vv[1:] + vv[:-1])[1:50], atol=1e-12)


def test_disabled_drive_brakes_at_a_max_then_stays():
    p = AxisParams(a_max_mm_s2=5000.0)
    axis = Axis(p)
    run_axis(axis, [100.0] * 400)
    v0, x0 = axis.velocity_mm_s, axis.position_mm
    x, v = run_axis(axis, [100.0] * 100, enabled=False)
    n_stop = math.ceil(v0 / (5000.0 * H))
    assert v[n_stop - 1] == 0.0 and np.all(v[n_stop:] == 0.0)
    assert np.all(np.diff(v[:n_stop]) == pytest.approx(-5000.0 * H))
    # braking distance v0^2 / (2 a) up to one tick of discretisation
    assert x[-1] - x0 == pytest.approx(v0 * v0 / (2 * 5000.0), abs=v0 * H)
    x2, _ = run_axis(axis, [100.0] * 10, fault=True)
    assert np.all(x2 == x[-1])


def test_dead_time_shifts_the_response_by_whole_ticks():
    cmds = list(np.sin(np.arange(300) * 0.05) * 50)
    x0, _ = run_axis(Axis(AxisParams()), cmds + [0.0] * 7)
    xd, _ = run_axis(Axis(AxisParams(dead_time_ticks=7)), cmds + [0.0] * 7)
    assert np.all(xd[:7] == 0.0)
    np.testing.assert_array_equal(xd[7:], x0[:-7])


def test_identified_model_matches_the_continuous_step_response():
    gain = 1.0 / 16.75
    axis = Axis(AxisParams(model='identified', identified_gain=gain), 2.0)
    u = 10.0
    x, _ = run_axis(axis, [u] * 4000)
    t = H * np.arange(1, 4001)
    _, y = signal.step((IDENTIFIED_NUM, IDENTIFIED_DEN), T=np.concatenate(([0.0], t)))
    y = y[1:]
    np.testing.assert_allclose(x, 2.0 + gain * u * y, atol=1e-6)
    # high-frequency gain normalised to 1: the first tick moves u h
    assert x[0] - 2.0 == pytest.approx(u * H, rel=1e-3)


def test_bad_parameters_name_the_field():
    with pytest.raises(ParamError, match='t1_s'):
        AxisParams(t1_s=0.0)
    with pytest.raises(ValueError, match='model'):
        AxisParams(model='second_order')
    with pytest.raises(ValueError, match='dead_time_ticks'):
        AxisParams(dead_time_ticks=-1)
