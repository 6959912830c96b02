"""Gap Kalman filter (notes §4) against the scalar Riccati equation."""

import math

from ladrc_contract.ops import ARRAY, SCALAR
from ladrc_follow.control.kalman import KalmanParams
import numpy as np
import pytest
from reference_forms import HeightKalman, kalman_step, steady_state_gain
from scipy.linalg import solve_discrete_are


@pytest.mark.parametrize('q,r', [(1e-6, 1e-4), (1e-3, 1e-3), (0.5, 1e-4)])
def test_gain_converges_to_riccati_solution(q, r):
    pm = solve_discrete_are(np.array([[1.0]]), np.array([[1.0]]), np.array([[q]]),
                            np.array([[r]]))[0, 0]          # prior covariance P⁻
    k_are = pm / (pm + r)
    assert steady_state_gain(q, r) == pytest.approx(k_are, rel=1e-9)
    # the Riccati fixed point: P⁻ = P⁻R/(P⁻ + R) + Q
    assert pm == pytest.approx(pm * r / (pm + r) + q, rel=1e-9)
    x, p = 0.0, 1.0
    for _ in range(5000):
        x, p, k = kalman_step(SCALAR, x, p, 0.0, 0.0, q, r)
    assert k == pytest.approx(k_are, rel=1e-9)


def test_prediction_uses_encoder_increment_with_gap_sign():
    # sensor ignored (huge R): the gap follows the encoder; moving up (+) opens the gap
    x, p = 1.0, 0.0
    for _ in range(10):
        x, p, k = kalman_step(SCALAR, x, p, 0.0, +0.01, 0.0, 1e30)
    assert x == pytest.approx(1.1)
    # with a trusted sensor the estimate converges to a constant reading
    x, p = 0.0, 1.0
    for _ in range(200):
        x, p, k = kalman_step(SCALAR, x, p, 0.8, 0.0, 1e-4, 1e-4)
    assert x == pytest.approx(0.8)


def test_batch_equals_scalar():
    rng = np.random.default_rng(4)
    zs, dz = rng.normal(size=300), 0.01 * rng.normal(size=300)
    q = np.array([1e-6, 1e-4, 1e-2])
    r = np.array([1e-4, 1e-3, 1e-2])
    xb, pb = np.zeros(3), np.full(3, 1e-3)
    x1, p1 = np.zeros(1), np.full(1, 1e-3)
    xs = [(0.0, 1e-3)] * 3
    for z, d in zip(zs, dz, strict=True):
        xb, pb, kb = kalman_step(ARRAY, xb, pb, z, d, q, r)
        x1, p1, _ = kalman_step(ARRAY, x1, p1, np.array([z]), np.array([d]), q[:1], r[:1])
        xs = [kalman_step(SCALAR, *xs[i], z, d, float(q[i]), float(r[i]))[:2] for i in range(3)]
    np.testing.assert_array_equal(xb, [s[0] for s in xs])
    np.testing.assert_array_equal(pb, [s[1] for s in xs])
    assert x1[0] == xs[0][0] and p1[0] == xs[0][1]


def test_params_problems():
    assert KalmanParams().problems() == []
    bad = KalmanParams(q_mm2=0.0, r_mm2=-1.0, p0_mm2=-1.0).problems()
    assert len(bad) == 3 and 'q_mm2' in bad[0]
    assert 'finite' in KalmanParams(q_mm2=math.inf).problems()[0]
    with pytest.raises(ValueError, match='r_mm2'):
        HeightKalman(KalmanParams(r_mm2=0.0))


def test_height_kalman_rules():
    kf = HeightKalman(KalmanParams(q_mm2=1e-6, r_mm2=1e-4, p0_mm2=1e-2), gate_mm=0.5,
                      max_coast_ticks=3)
    assert kf.update(1.0, 0.0) == 1.0                 # first valid reading initialises
    assert kf.p == 1e-2
    x = kf.update(1.1, 0.0)
    k = (1e-2 + 1e-6) / (1e-2 + 1e-6 + 1e-4)
    assert x == pytest.approx(1.0 + k * 0.1)
    # a jump beyond the gate re-initialises on the reading
    resets = kf.resets
    assert kf.update(2.0, 0.0) == 2.0 and kf.resets == resets + 1
    # ... unless the encoder explains it (moved up by 0.9 mm)
    assert abs(kf.update(2.9, 0.9) - 2.9) < 0.01
    # invalid readings coast on the encoder, then the next valid one restarts the filter
    x0 = kf.x
    assert kf.update(float('nan'), 0.05) == pytest.approx(x0 + 0.05)
    assert kf.update(5.0, 0.05, valid=False) == pytest.approx(x0 + 0.1)
    assert kf.update(3.3, 0.0) == 3.3 and kf.p == 1e-2
    # too many invalid ticks in a row: uninitialised, estimate nan
    for _ in range(4):
        out = kf.update(0.0, 0.0, valid=False)
    assert math.isnan(out) and not kf.initialised
    assert kf.update(1.2, 0.0) == 1.2
