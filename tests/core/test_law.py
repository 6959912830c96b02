"""Control-law forms, bandwidth gains and output limits (notes §3.1, ``UpdateLADRC``)."""

from hypothesis import given, settings
from hypothesis import strategies as st
from ladrc_contract.ops import ARRAY, SCALAR
from ladrc_follow.control.law import (
    apply_limits,
    form_weights,
    gains_from_bandwidth,
    law_order1,
    law_order2,
)
import numpy as np
import pytest

# Unit mapping of the firmware (docs/control-law.md): UnitP = 1 µm (assumed; the law is
# linear, the choice only sets the size of the integer rounding), TD diff and ESO x2 in
# UnitP/s, b0_int = 100 → 1 UnitV = 100 UnitP/s = 0.1 mm/s, so b0 = 1 (mm/s)/(mm/s).
UNIT_P_MM = 0.001
UNIT_V_MM_S = 100 * UNIT_P_MM


def c_div(a: int, b: int) -> int:
    """C integer division (truncates toward zero)."""
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b >= 0) else -q


def seed_law_int(track, diff, x1, x2, kp_int, b0_int, v_max, acc, n_ctrl):
    """Evaluate the law + limits of ``UpdateLADRC`` (order 1) in C integer arithmetic."""
    n_pout = c_div(kp_int * (track - x1), 10)
    n_u0 = n_pout + diff
    u = c_div(n_u0 - x2, b0_int)
    if u < 0 and abs(u) > abs(v_max):  # the seed saturates only downwards
        u = -v_max
    d = u - n_ctrl
    sgn = -1 if d < 0 else 1
    if abs(d) > acc:
        d = sgn * acc
    return n_ctrl + d


def float_law(track_mm, diff_mm_s, z1, z2, kp, b0, v_max, du_max, u_prev):
    w_td, w_rate, _ = form_weights(3, 1)
    assert w_td
    p, ff, u0, u = law_order1(SCALAR, track_mm, diff_mm_s, z1, z2, kp, b0, w_rate)
    return apply_limits(SCALAR, u, u_prev, v_max, du_max)[0], (p, ff, u0, u)


def test_hand_computed_seed_example():
    # by hand: P = 100·(1500 − 1487)/10 = 130; u0 = 130 + 2300 = 2430;
    # u = (2430 − (−3157))/100 = 5587/100 = 55 (C truncation); Δ = 55 − 50 = 5 > 4 → 54 UnitV
    assert seed_law_int(1500, 2300, 1487, -3157, 100, 100, 2000, 4, 50) == 54
    u, (p, ff, u0, u_unl) = float_law(1.5, 2.3, 1.487, -3.157, 10.0, 1.0, 200.0, 0.4, 5.0)
    assert p == pytest.approx(0.13)
    assert u0 == pytest.approx(2.43)
    assert u_unl == pytest.approx(5.587)  # 55 UnitV truncated from 55.87
    assert u == pytest.approx(54 * UNIT_V_MM_S)


@pytest.mark.parametrize('track,diff,x1,x2,n_ctrl', [
    (1000, 0, 1000, 0, 0),
    (1500, -800, 1530, 400, -3),
    (800, 12000, 2400, -25000, 120),
    (2000, 0, 1000, 90000, -1500),     # large downward → saturation at −v_max
    (1200, 333, 1199, -77, 7),
])
def test_law_matches_seed_integer_code(track, diff, x1, x2, n_ctrl):
    kp_int, b0_int, v_max, acc = 100, 100, 2000, 40
    u_int = seed_law_int(track, diff, x1, x2, kp_int, b0_int, v_max, acc, n_ctrl)
    u, _ = float_law(track * UNIT_P_MM, diff * UNIT_P_MM, x1 * UNIT_P_MM, x2 * UNIT_P_MM,
                     kp_int / 10, b0_int / 100, v_max * UNIT_V_MM_S, acc * UNIT_V_MM_S,
                     n_ctrl * UNIT_V_MM_S)
    # the integer code truncates twice (P/10 and /b0): at most one UnitV apart
    assert abs(u - u_int * UNIT_V_MM_S) <= UNIT_V_MM_S + 1e-12


def test_form_weights():
    assert form_weights(3, 1) == (True, 1.0, 0.0)   # seed: kp(r − z1) + ṙ
    assert form_weights(1, 1) == (True, 0.0, 0.0)
    assert form_weights(2, 2) == (False, 0.0, 0.0)
    assert form_weights(1, 2) == (True, 1.0, 0.0)
    assert form_weights(3, 2) == (True, 1.0, 1.0)
    with pytest.raises(ValueError, match='form must be 1, 2 or 3'):
        form_weights(4, 1)
    with pytest.raises(ValueError, match='order must be 1 or 2'):
        form_weights(1, 3)


def test_law2_forms_by_hand():
    r, dr, ddr, z1, z2, z3 = 1.0, 0.5, -2.0, 0.9, 0.3, 4.0
    kp, kd, b0 = 100.0, 20.0, 50.0
    _, w1, a1 = form_weights(1, 2)
    _, _, _, u0, u = law_order2(SCALAR, r, dr, ddr, z1, z2, z3, kp, kd, b0, w1, a1)
    assert u0 == pytest.approx(100 * 0.1 + 20 * (0.5 - 0.3))
    _, w3, a3 = form_weights(3, 2)
    p, d, ff, u0, u = law_order2(SCALAR, r, dr, ddr, z1, z2, z3, kp, kd, b0, w3, a3)
    assert (p, d, ff) == pytest.approx((10.0, 4.0, -2.0))
    assert u == pytest.approx((12.0 - 4.0) / 50.0)
    _, w2, a2 = form_weights(2, 2)
    _, _, _, u0, _ = law_order2(SCALAR, r, dr, ddr, z1, z2, z3, kp, kd, b0, w2, a2)
    assert u0 == pytest.approx(100 * 0.1 - 20 * 0.3)


@pytest.mark.parametrize('wc', [5.0, 60.0, 400.0])
def test_bandwidth_gains_place_poles(wc):
    kp, kd = gains_from_bandwidth(1, wc)
    assert np.roots([1.0, kp]) == pytest.approx([-wc])
    kp, kd = gains_from_bandwidth(2, wc)
    assert np.roots([1.0, kd, kp]) == pytest.approx([-wc, -wc], rel=1e-6)
    with pytest.raises(ValueError, match='wc_rad_s must be > 0'):
        gains_from_bandwidth(1, 0.0)


finite = st.floats(-1e6, 1e6, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(u=finite, frac=st.floats(-1.0, 1.0), v_max=st.floats(1e-3, 1e4),
       du=st.floats(1e-6, 1e3))
def test_limits_never_exceeded(u, frac, v_max, du):
    u_prev = frac * v_max
    out, sat, rate = apply_limits(SCALAR, u, u_prev, v_max, du)
    tol = 1e-12 * max(1.0, v_max)
    assert abs(out) <= v_max + tol
    assert abs(out - u_prev) <= du + tol
    assert sat == (abs(u) > v_max)
    if not sat and not rate:
        assert out == u
    if rate:
        assert abs(out - u_prev) == pytest.approx(du, rel=1e-9, abs=tol)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(finite, st.floats(-1.0, 1.0)), min_size=1, max_size=20))
def test_limits_batch_equals_scalar(rows):
    u = np.array([r[0] for r in rows])
    u_prev = np.array([r[1] * 50.0 for r in rows])
    out, sat, rate = apply_limits(ARRAY, u, u_prev, 50.0, 2.0)
    for i in range(len(rows)):
        o, s, r = apply_limits(SCALAR, float(u[i]), float(u_prev[i]), 50.0, 2.0)
        assert (out[i], sat[i], rate[i]) == (o, s, r)
