"""Tracking differentiator (notes §2) against its transfer function and the firmware's C."""

import math

from ladrc_contract.ops import ARRAY, SCALAR
from ladrc_follow.control.td import (
    TDA_FIRMWARE,
    TDB_FIRMWARE,
    TDParams,
    td_discrete_matrix,
    td_step_firmware,
)
import numpy as np
import pytest
from reference_forms import CompoundTD, compound_td_step, td_params_from_wn_xi, td_step

STEPS = [td_step, td_step_firmware]


def c_div(a: int, b: int) -> int:
    """C99 integer division (truncates toward zero)."""
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b >= 0) else -q


@pytest.mark.parametrize('step', STEPS)
def test_step_response_overshoot_and_peak_time(step):
    xi, wn = 0.4, 60.0
    p = td_params_from_wn_xi(wn, xi, k1=2.0)
    h = 1e-5
    x1 = x2 = 0.0
    peak, t_peak = -1.0, 0.0
    for k in range(int(0.25 / h)):
        x1, x2 = step(SCALAR, x1, x2, 1.0, 0.0, p.k1, p.k2, p.r_per_s, p.alpha, h)
        if x1 > peak:
            peak, t_peak = x1, (k + 1) * h
    wd = wn * math.sqrt(1 - xi * xi)
    assert peak - 1.0 == pytest.approx(math.exp(-math.pi * xi / math.sqrt(1 - xi * xi)),
                                       rel=2e-3)
    assert t_peak == pytest.approx(math.pi / wd, rel=5e-3)


@pytest.mark.parametrize('step', STEPS)
def test_frequency_response_matches_transfer_function(step):
    # batch rows: 3 frequencies x (α = 0, α = 40)
    w = np.tile([20.0, 50.0, 120.0], 2)                  # rad/s
    alpha = np.repeat([0.0, 40.0], 3)
    p = td_params_from_wn_xi(50.0, 0.6, k1=1.5)
    h, t_end = 4e-5, 1.4
    n = int(t_end / h)
    x1 = np.zeros(6)
    x2 = np.zeros(6)
    v_prev = np.zeros(6)
    keep = int(0.9 / h)
    tt, r1, r2 = [], [], []
    for k in range(1, n + 1):
        t = k * h
        v = np.sin(w * t)
        x1, x2 = step(ARRAY, x1, x2, v, v - v_prev, p.k1, p.k2, p.r_per_s, alpha, h)
        v_prev = v
        if k > n - keep and k % 5 == 0:
            tt.append(t)
            r1.append(x1)
            r2.append(x2)
    tt = np.array(tt)
    s = 1j * w
    den = s * s + p.k2 * p.r_per_s * s + p.k1 * p.r_per_s ** 2
    h1 = (alpha * s + p.k1 * p.r_per_s ** 2) / den
    for resp, want in ((np.array(r1), h1), (np.array(r2), s * h1)):
        for i in range(6):
            basis = np.column_stack([np.sin(w[i] * tt), np.cos(w[i] * tt)])
            a, b = np.linalg.lstsq(basis, resp[:, i], rcond=None)[0]
            got = complex(a, b)                 # a sin + b cos = Im((a + jb) e^{jwt})
            assert abs(got) == pytest.approx(abs(want[i]), rel=5e-3)
            assert abs(np.angle(got / want[i])) < 5e-3 + w[i] * h


def test_params_round_trip_and_properties():
    for wn, xi, k1 in ((44.0, 0.3, 1.0), (110.0, 1.8, 1.2), (5.0, 0.7, 4.0)):
        p = td_params_from_wn_xi(wn, xi, k1, alpha=3.0)
        assert p.natural_frequency_rad_s == pytest.approx(wn)
        assert p.damping == pytest.approx(xi)
        assert p.k1 == k1 and p.alpha == 3.0
    # the seed's TDB: ωn = 100·√1.2, ξ = 4.0 / (2√1.2)
    assert TDB_FIRMWARE.natural_frequency_rad_s == pytest.approx(109.5445, rel=1e-6)
    assert TDB_FIRMWARE.damping == pytest.approx(1.825742, rel=1e-6)
    with pytest.raises(ValueError, match='wn_rad_s'):
        td_params_from_wn_xi(-1.0, 0.5)


def test_problems():
    assert TDA_FIRMWARE.problems() == [] and TDB_FIRMWARE.problems(h_s=5e-4) == []
    bad = TDParams(k1=0.0, k2=-1.0, r_per_s=0.0, alpha=-2.0).problems()
    assert len(bad) == 4 and any('k2' in m for m in bad)
    assert 'finite' in TDParams(k1=float('nan'), k2=1, r_per_s=1).problems()[0]
    # firmware order: det = 1 − h k2 R; k2 R h > 2 makes it unstable
    fast = TDParams(k1=1.0, k2=5.0, r_per_s=1000.0)
    assert any('unstable' in m for m in fast.problems(h_s=5e-4))


def test_firmware_order_is_more_stable_than_explicit_euler():
    # lightly damped: explicit Euler det = 1 − b + a h > 1, firmware det = 1 − b < 1
    p = TDParams(k1=1.0, k2=0.02, r_per_s=400.0)
    h = 5e-4
    assert max(abs(np.linalg.eigvals(td_discrete_matrix(p, h, False)))) > 1.0
    assert max(abs(np.linalg.eigvals(td_discrete_matrix(p, h, True)))) < 1.0
    assert np.linalg.det(td_discrete_matrix(p, h, True)) == pytest.approx(1 - h * 400 * 0.02)


def test_eldtrackercalc_by_hand():
    # ELDTrackerCalc with TDB ints k1=12, k2=40, R=100; nTracker=1000, nDiff=4000, v=1200
    k1, k2, r = 12, 40, 100
    tracker, diff, v = 1000, 4000, 1200
    tracker = c_div(tracker * 2000 + diff, 2000)              # 2004000/2000 = 1002
    err = tracker - v                                          # -198
    term1 = c_div(-k1 * err, 10)                               # 2376/10 -> 237
    term2 = c_div(c_div(k2 * diff, 10), r)                     # 16000/100 = 160
    diff = diff + c_div((term1 - term2) * r * r, 2000)         # 770000/2000 = 385
    assert (tracker, diff) == (1002, 4385)
    # float step with k1 = 12/10, k2 = 40/10, R = 100, h = 1/2000: x2 = 4000 + 5·(237.6 − 160)
    x1, x2 = td_step_firmware(SCALAR, 1000.0, 4000.0, 1200.0, 0.0, 1.2, 4.0, 100.0, 0.0, 5e-4)
    assert x1 == pytest.approx(1002.0)
    assert x2 == pytest.approx(4388.0)
    # the C result differs only by its truncations: ≤ (1 + 1)·R²/2000 + 1 = 11 units
    assert abs(x2 - diff) <= 2 * r * r / 2000 + 1


def test_compound_ramp_lag_matches_feedforward_formula():
    # steady ramp lag of TDB: x1 − v = V (α_b − k2 R) / (k1 R²) (ẋ2 = 0 in the continuous form)
    pa = TDParams(2.2, 1.3, 30.0, 15.0)
    pb = TDParams(1.5, 2.0, 60.0, 60.0)
    h, vel = 1e-4, 3.0
    td = CompoundTD(pa, pb, h_s=h)
    td.reset(0.0)
    for k in range(1, int(1.5 / h) + 1):
        x1, x2 = td.step(vel * k * h)
    lag = x1 - vel * k * h
    want = vel * (pb.alpha - pb.k2 * pb.r_per_s) / (pb.k1 * pb.r_per_s ** 2)
    assert lag == pytest.approx(want, rel=1e-2, abs=vel * h)
    assert x2 == pytest.approx(vel, rel=1e-6)
    # with α_b = k2 R the ramp is tracked without lag (to O(h))
    pz = TDParams(1.5, 2.0, 60.0, 120.0)
    td = CompoundTD(pa, pz, h_s=h)
    td.reset(0.0)
    for k in range(1, int(1.5 / h) + 1):
        x1, _ = td.step(vel * k * h)
    assert abs(x1 - vel * k * h) < 5 * vel * h


@pytest.mark.parametrize('step', STEPS)
def test_batch_equals_scalar_td_step(step):
    rng = np.random.default_rng(3)
    pars = [(2.2, 1.3, 30.0, 15.0), (1.2, 4.0, 100.0, 0.0), (1.0, 1.0, 50.0, 3.0)]
    cols = [np.array(c) for c in zip(*pars, strict=True)]
    vs = rng.normal(size=(300, 3))
    xs1, xs2 = np.zeros(3), np.zeros(3)
    one1, one2 = np.zeros(1), np.zeros(1)
    sc = [(0.0, 0.0)] * 3
    prev = np.zeros(3)
    for v in vs:
        xs1, xs2 = step(ARRAY, xs1, xs2, v, v - prev, *cols, 5e-4)
        one1, one2 = step(ARRAY, one1, one2, v[:1], v[:1] - prev[:1],
                          *[c[:1] for c in cols], 5e-4)
        sc = [step(SCALAR, a, b, float(v[i]), float(v[i] - prev[i]), *pars[i], 5e-4)
              for i, (a, b) in enumerate(sc)]
        prev = v
    np.testing.assert_array_equal(xs1, [s[0] for s in sc])
    np.testing.assert_array_equal(xs2, [s[1] for s in sc])
    np.testing.assert_array_equal(one1, [sc[0][0]])
    np.testing.assert_array_equal(one2, [sc[0][1]])


def test_batch_equals_scalar_compound():
    pa = TDParams(np.array([2.2, 1.0]), np.array([1.3, 2.0]), np.array([30.0, 80.0]),
                  np.array([15.0, 5.0]))
    pb = TDParams(np.array([1.2, 2.0]), np.array([4.0, 2.5]), np.array([100.0, 40.0]),
                  np.array([0.0, 18.0]))
    batch = CompoundTD(pa, pb, ops=ARRAY)
    batch.reset(np.array([1.0, 1.0]))
    scal = [CompoundTD(TDParams(*[float(getattr(pa, f)[i]) for f in ('k1', 'k2', 'r_per_s',
                                                                       'alpha')]),
                       TDParams(*[float(getattr(pb, f)[i]) for f in ('k1', 'k2', 'r_per_s',
                                                                       'alpha')]))
            for i in range(2)]
    for s in scal:
        s.reset(1.0)
    for k in range(400):
        v = 1.0 + 0.5 * math.sin(0.01 * k) + (0.3 if k > 100 else 0.0)
        out = batch.step(np.array([v, v]))
        for i, s in enumerate(scal):
            x1, x2 = s.step(v)
            assert out[0][i] == x1 and out[1][i] == x2
    # and the raw function with state tuples, N = 1 against scalar
    st1 = tuple(np.array([0.2]) for _ in range(5))
    st0 = (0.2,) * 5
    args = (2.2, 1.3, 30.0, 15.0, 1.2, 4.0, 100.0, 7.0, 5e-4)
    for _ in range(50):
        st1 = compound_td_step(ARRAY, st1, np.array([1.0]), *args)
        st0 = compound_td_step(SCALAR, st0, 1.0, *args)
    assert all(a[0] == b for a, b in zip(st1, st0, strict=True))


def test_firmware_defaults_output_is_tdb_alone():
    # TDB's α is 0 in CompELDTInit, so TDA cannot influence the compound output
    a = CompoundTD()
    b = CompoundTD(TDParams(1.0, 1.0, 5.0, 50.0), TDB_FIRMWARE)
    a.reset(0.0)
    b.reset(0.0)
    for k in range(200):
        assert a.step(1.0 if k > 10 else 0.0) == b.step(1.0 if k > 10 else 0.0)
