"""Paper §4 (eqs. 28-32, Fig. 2): the LESO error transfer functions with and without D.

Closed forms worked by hand for n = 3 (4 states, bandwidth gains, Ω = ω/ω0, x = 1/Ω²):
  eq. 32, i = 2: |1 + 4/(jΩ)|² = 1 + 16x
  eq. 32, i = 3: |1 + 4/(jΩ) + 6/(jΩ)²|² = (1 − 6x)² + 16x
  eq. 32, i = 4: |… + 4/(jΩ)³|² = 1 + 4x + 4x² + 16x³
and the true ratio (eq. 26: e'_i = ė_{i−1}) G_D3 = jΩ(jΩ + 4)/((jΩ)² + 4jΩ + 6), whose
|G_D3|² = y(y + 16)/(y² + 4y + 36), y = Ω², peaks where y² − 6y − 48 = 0; G_D4 at Ω = √2 is √2.
"""

import math

from ladrc_tools.offline.eso_frequency import (
    PAPER,
    corrected_peak,
    error_tfs,
    figures,
    gd_closed_form,
    gd_corrected,
    gd_phase_deg,
    gd_response,
    measure_gd,
    omega_at_db,
)
import numpy as np
import pytest

N = 3
GRID = np.geomspace(0.01, 1000.0, 801)
LEVEL = 10.0 ** (0.1 / 10.0)        # |den|² at |G| = −0.1 dB


def _positive_root(coeffs):
    r = np.roots(coeffs)
    r = r[(abs(r.imag) < 1e-12) & (r.real > 0)].real
    assert r.size == 1
    return float(r[0])


def test_the_state_space_gives_eq_29_and_the_first_order_of_eq_31_32():
    tfs = error_tfs(N, w0_rad_s=1.0)
    np.testing.assert_allclose(tfs.den, [1, 4, 6, 4, 1], atol=1e-12)       # (s + ω0)^4
    # eq. 29: E_{n+1}/f = s·num/P must be (P − β_{n+1})/P: s·(s³+4s²+6s+4) = P − 1
    np.testing.assert_allclose(np.polymul([1, 0], tfs.num[N]),
                               np.polysub(tfs.den, [1.0]), atol=1e-12)
    assert np.all(tfs.num_comp[0] == 0.0)                                  # eq. 30: E'_1 = 0
    np.testing.assert_allclose(gd_response(tfs, 2, GRID), gd_closed_form(N, 2, GRID),
                               rtol=1e-10, atol=1e-12)


def test_bandwidth_scaling_makes_it_a_function_of_omega_over_w0():
    a = gd_response(error_tfs(N, w0_rad_s=100.0), 4, GRID)
    b = gd_response(error_tfs(N, w0_rad_s=1.0), 4, GRID)
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)


def test_eq_30_holds_for_i_2_only_the_true_ratio_is_s_q_over_q():
    tfs = error_tfs(N)
    for i in (3, 4):
        ss = gd_response(tfs, i, GRID)
        np.testing.assert_allclose(ss, gd_corrected(N, i, GRID), rtol=1e-10, atol=1e-12)
        assert np.max(np.abs(ss - gd_closed_form(N, i, GRID))) > 0.9   # eq. 32 as printed
    w = np.sqrt(2.0)
    assert abs(gd_corrected(N, 4, np.array([w]))[0]) == pytest.approx(math.sqrt(2.0), rel=1e-12)
    y = 3.0 + math.sqrt(57.0)                                           # y² − 6y − 48 = 0
    w_pk, db_pk = corrected_peak(N, 3)
    assert w_pk == pytest.approx(math.sqrt(y), rel=1e-6)
    assert db_pk == pytest.approx(10 * math.log10(y * (y + 16) / (y * y + 4 * y + 36)), abs=1e-9)
    assert db_pk > 1.6                          # D amplifies the z3 error near Ω = 3.2


def test_the_sampled_leso_measures_the_true_ratio_and_a_flipped_d_is_caught():
    for om in (0.5, 2.0, PAPER['omega_weak']):
        meas = measure_gd(om, N)
        true = np.array([gd_corrected(N, i, np.array([om]))[0] for i in (2, 3, 4)])
        np.testing.assert_allclose(meas, true, atol=5e-3)
        wrong = measure_gd(om, N, compensator_sign=-1.0)
        flipped = error_tfs(N, compensator_sign=-1.0)
        np.testing.assert_allclose(
            wrong, [gd_response(flipped, i, np.array([om]))[0] for i in (2, 3, 4)], atol=5e-3)
        # z − D instead of z + D: far off for every state at Ω ≤ 2, for z2 at any Ω
        assert np.min(np.abs(wrong - true)) > (0.5 if om <= 2.0 else 0.04)
        assert abs(wrong[0] - true[0]) > 1.0
    # and the flipped transfer function is far from the paper's eq. 31/32 for every i
    flipped = error_tfs(N, compensator_sign=-1.0)
    for i in (2, 3, 4):
        assert np.max(np.abs(gd_response(flipped, i, GRID) - gd_closed_form(N, i, GRID))) > 0.5


def test_omega_lost_matches_the_closed_forms_and_the_papers_13_3():
    x3 = _positive_root([36.0, 4.0, 1.0 - LEVEL])          # (1 − 6x)² + 16x = LEVEL
    x4 = _positive_root([16.0, 4.0, 4.0, 1.0 - LEVEL])     # 1 + 4x + 4x² + 16x³ = LEVEL
    x2 = (LEVEL - 1.0) / 16.0
    for i, x in ((2, x2), (3, x3), (4, x4)):
        assert omega_at_db(N, i, -0.1) == pytest.approx(1.0 / math.sqrt(x), rel=1e-9)
    fig = figures(N)
    # the paper: "Ω > 13.3: |A| < 0.1 (dB), φ < 17.52°" — the higher-order curves i = 3, 4
    for i in (3, 4):
        assert fig[f'omega_0p1db_i{i}'] == pytest.approx(PAPER['omega_lost'], rel=0.015)
        assert fig[f'phi_deg_at_13_3_i{i}'] < PAPER['phi_lost_deg']
        assert fig[f'phi_deg_at_13_3_i{i}'] == pytest.approx(PAPER['phi_lost_deg'], rel=0.02)
    # the first-order curve s/(s + 4) only gets there at Ω = 26.2 (the paper does not say)
    assert fig['omega_0p1db_i2'] == pytest.approx(4.0 / math.sqrt(10 ** 0.01 - 1), rel=1e-9)


def test_omega_weak_is_a_grid_point_and_the_phase_matches_within_1_5_percent():
    assert 10 ** 0.71 == pytest.approx(PAPER['omega_weak'], abs=5e-5)
    assert gd_phase_deg(N, 2, 5.1286)[0] == pytest.approx(math.degrees(math.atan(4 / 5.1286)))
    fig = figures(N)
    assert fig['phi_deg_at_5_1286_i4'] == pytest.approx(PAPER['phi_weak_deg'], rel=0.015)
    assert fig['omega_phi_43_5929_top'] == pytest.approx(PAPER['omega_weak'], rel=0.015)
