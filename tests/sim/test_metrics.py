"""Metrics on synthetic series with known answers."""

import math

from ladrc_sim.headless.metrics import (
    compute_metrics,
    count_rising,
    followed_index,
    itae,
    limit_hits,
    settling_and_overshoot,
)
import numpy as np
import pytest

H = 0.0005


def test_first_order_approach_settles_at_tau_ln_step_over_tol():
    tau, step, tol = 0.05, 2.0, 0.05
    t = np.arange(4000) * H
    target = np.full(t.size, 3.0)
    gap = 3.0 - step * np.exp(-t / tau)  # approach from 1 mm to the 3 mm target
    settle, over, pct = settling_and_overshoot(gap, target, H, tol)
    assert settle == pytest.approx(tau * math.log(step / tol), abs=H)
    assert over == 0.0 and pct == 0.0
    i = followed_index(gap, target, H, tol, 0.05)
    assert t[i] == pytest.approx(tau * math.log(step / tol) + 0.05, abs=2 * H)


def test_overshoot_of_an_underdamped_step():
    zeta, wn = 0.3, 40.0
    t = np.arange(4000) * H
    wd = wn * math.sqrt(1 - zeta ** 2)
    y = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta ** 2)
                                      * np.sin(wd * t))
    target = np.full(t.size, 1.0)
    target[:100] = np.nan  # step commanded at tick 100 from gap 0 to 1 mm
    gap = np.concatenate((np.zeros(100), y[:-100]))
    _, over, pct = settling_and_overshoot(gap, target, H)
    expect = math.exp(-zeta * math.pi / math.sqrt(1 - zeta ** 2))
    assert over == pytest.approx(expect, rel=1e-3) and pct == pytest.approx(100 * expect, 1e-3)


def test_itae_of_a_constant_error_is_e_t_squared_over_two():
    n = 2001
    target = np.ones(n)
    gap = target + 0.1
    assert itae(gap, target, H) == pytest.approx(0.1 * ((n - 1) * H) ** 2 / 2, rel=1e-3)


def test_rising_edges_and_limits_by_value():
    assert count_rising(np.array([0, 1, 1, 0, 1, 0, 0, 1], bool)) == 3
    assert count_rising(np.array([1, 1, 0], bool)) == 1
    u = np.array([0.0, 2.5, 5.0, 200.0, 200.0, -200.0])
    nv, na = limit_hits(u, H, 200.0, 5000.0)
    assert nv == 3 and na == 4  # du >= 2.5 mm/s per tick, the first step from 0 counts


def test_never_followed_gives_nan_and_collisions_counted():
    t = np.arange(100) * H
    gap = np.linspace(1.0, -1.0, 100)
    m = compute_metrics(t, gap, np.full(100, 5.0), gap <= 0, np.zeros(100), h_s=H,
                        v_max_mm_s=200, a_max_mm_s2=5000)
    assert math.isnan(m.followed_at_s) and math.isnan(m.error_rms_mm)
    assert m.collisions == 1
    assert set(m.as_dict()) >= {'error_rms_mm', 'itae_mm_s2', 'time_to_follow_s'}


def test_error_statistics_after_followed():
    t = np.arange(2000) * H
    target = np.full(2000, 1.0)
    gap = 1.0 + 0.01 * np.sin(2 * np.pi * 10 * t)
    m = compute_metrics(t, gap, target, gap <= 0, np.zeros(2000), h_s=H, v_max_mm_s=200,
                        a_max_mm_s2=5000)
    assert m.followed_at_s == pytest.approx(0.05, abs=H)
    assert m.error_max_mm == pytest.approx(0.01, rel=1e-3)
    assert m.error_p2p_mm == pytest.approx(0.02, rel=1e-3)
    assert m.error_rms_mm == pytest.approx(0.01 / math.sqrt(2), rel=1e-2)


def test_limit_flags_bitmask_from_internals():
    flags = np.array([0, 1, 2, 3, 0, 1], dtype=float)
    nv, na = limit_hits(np.zeros(6), H, 200.0, 5000.0, {'limit_flags': flags})
    assert (nv, na) == (3, 2)


def test_travel_ratio_is_one_when_calibrated_and_below_at_the_edge():
    from ladrc_sim.headless.metrics import travel_ratio
    from ladrc_sim.models.sensor import edge_reading_mm
    g = np.linspace(10.0, 1.0, 200)
    np.testing.assert_allclose(travel_ratio(g, g)[2:], 1.0)  # nan until 0.05 mm of travel
    ratio = travel_ratio(g, edge_reading_mm(g, 0.5))
    assert math.isnan(ratio[0]) and np.all(ratio[5:] < 1.0)
    assert np.all(np.diff(ratio[5:]) < 0)  # the smooth model: d1/d0 falls as the gap closes


def test_metrics_fed_in_slices_equal_the_whole_run():
    """The accumulator behind compute_metrics carries every quantity across slices.

    A run with two target segments (the last one ends before the run does), a collision
    spanning a slice boundary and limit flags: fed in uneven slices, every figure equals the
    one-slice result (sums to rounding). A carry that was forgotten (the inside-band run, the
    segment start, the previous command or collision flag) changes a figure.
    """
    from ladrc_sim.headless.metrics import MetricsAccumulator

    n = 9000
    t = np.arange(n) * H
    target = np.full(n, np.nan)
    target[200:5000] = 1.0
    target[5000:8000] = 1.4
    gap = 1.0 + 1.0 * np.exp(-t / 0.02) + 0.01 * np.sin(2 * np.pi * 50 * t)
    gap[5000:] = 1.4 - 0.4 * np.exp(-(t[5000:] - t[5000]) / 0.03)
    collision = np.zeros(n, bool)
    collision[4990:5010] = True
    u = np.sin(t * 40) * 250.0
    kw = dict(h_s=H, v_max_mm_s=200.0, a_max_mm_s2=5000.0)
    whole = compute_metrics(t, gap, target, collision, u, **kw).as_dict()
    for cuts in ([0, 1, 150, 201, 4999, 5000, 5003, 8000, n], [0, 333, 4995, 6000, n]):
        acc = MetricsAccumulator(H, v_max_mm_s=200.0, a_max_mm_s2=5000.0)
        for a, b in zip(cuts, cuts[1:], strict=False):
            acc.add(t[a:b], gap[a:b], target[a:b], collision[a:b], u[a:b])
        got = acc.result().as_dict()
        for k, v in whole.items():
            assert got[k] == pytest.approx(v, rel=1e-12, nan_ok=True), (cuts, k)
    assert whole['collisions'] == 1 and whole['limit_a_ticks'] > 0
    assert math.isfinite(whole['settling_time_s']) and whole['overshoot_mm'] == 0.0
