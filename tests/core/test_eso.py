"""ESO (notes §3, paper eqs. 8-9, 19, 22, 34, 38) against eigenvalues and the paper's formulas."""

from math import comb, factorial

from ladrc_contract.ops import ARRAY, SCALAR
from ladrc_follow.analysis.observers import LinearESO
from ladrc_follow.control.eso import (
    bandwidth_gains,
    compensate1,
    compensate2,
    continuous_matrices,
    eso1_euler_step,
    eso1_zoh_step,
    eso2_euler_step,
    eso2_zoh_step,
    euler_is_stable,
    zoh_gains,
)
import numpy as np
import pytest
from reference_forms import NonlinearESO, euler_stability_limit, seed_gains_order1, static_error
from scipy.linalg import expm


def c_div(a: int, b: int) -> int:
    """C99 integer division (truncates toward zero)."""
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b >= 0) else -q


def companion_error_matrix(betas):
    """A_e of paper eq. 8 written out by hand: first column −β, ones on the superdiagonal."""
    m = len(betas)
    a_e = np.zeros((m, m))
    a_e[:, 0] = -np.array(betas)
    for i in range(m - 1):
        a_e[i, i + 1] = 1.0
    return a_e


def test_bandwidth_gains_and_paper_eq36():
    assert bandwidth_gains(1, 10.0) == (20.0, 100.0)
    assert bandwidth_gains(2, 10.0) == (30.0, 300.0, 1000.0)
    assert bandwidth_gains(3, 100.0) == (400.0, 6e4, 4e6, 1e8)         # paper eq. 36
    for n in (1, 2, 3):
        poly = np.poly(companion_error_matrix(bandwidth_gains(n, 7.0)))
        np.testing.assert_allclose(poly, np.poly([-7.0] * (n + 1)), rtol=1e-9)
    with pytest.raises(ValueError, match='w0'):
        bandwidth_gains(1, 0.0)
    with pytest.raises(ValueError, match='order'):
        bandwidth_gains(0, 10.0)


def test_seed_gains_and_where_their_poles_are():
    assert seed_gains_order1(90.0) == (270.0, 24300.0)
    assert seed_gains_order1(60.0) == (180.0, 10800.0)
    poles = np.roots([1.0, *seed_gains_order1(90.0)])
    np.testing.assert_allclose(np.abs(poles), np.sqrt(3.0) * 90.0)
    np.testing.assert_allclose(-poles.real / np.abs(poles), np.sqrt(3.0) / 2.0)


@pytest.mark.parametrize('n', [1, 2, 3])
def test_zoh_error_eigenvalues_all_at_exp_minus_w0h(n):
    w0, h = 90.0, 5e-4
    beta = np.exp(-w0 * h)
    m = LinearESO(n, 2.0, h, w0_rad_s=w0, discretization='zoh').discrete_error_matrix()
    np.testing.assert_allclose(np.poly(m), np.poly([beta] * (n + 1)), rtol=0, atol=1e-12)
    # (M − βI)^(n+1) = 0: a single Jordan block at β (the eigenvalues themselves are
    # ill-conditioned for a repeated root, so also check them loosely)
    resid = np.linalg.matrix_power(m - beta * np.eye(n + 1), n + 1)
    assert np.max(np.abs(resid)) < 1e-12 * max(1.0, np.max(np.abs(m)) ** (n + 1))
    assert np.max(np.abs(np.linalg.eigvals(m) - beta)) < 1e-3


def test_zoh_gains_closed_forms():
    w0, h = 60.0, 5e-4
    b = np.exp(-w0 * h)
    np.testing.assert_allclose(zoh_gains(1, w0, h), (1 - b ** 2, (1 - b) ** 2 / h), rtol=1e-9)
    np.testing.assert_allclose(zoh_gains(2, w0, h),
                               (1 - b ** 3, 1.5 * (1 - b) ** 2 * (1 + b) / h,
                                (1 - b) ** 3 / h ** 2),
                               rtol=1e-9)


@pytest.mark.parametrize('n', [1, 2, 3])
def test_euler_error_matrix_and_stability(n):
    betas = bandwidth_gains(n, 50.0)
    eso = LinearESO(n, 1.0, 1e-3, betas=betas)
    np.testing.assert_allclose(eso.discrete_error_matrix(),
                               np.eye(n + 1) + 1e-3 * companion_error_matrix(betas))
    assert euler_stability_limit(n) == 2.0
    assert euler_is_stable(n, betas, 1.9 / 50.0)
    assert not euler_is_stable(n, betas, 2.1 / 50.0)


def test_euler_limit_for_seed_gains_is_one_over_w():
    # poles ω(−1.5 ± j0.866): −2 Re λ / |λ|² = 3ω / 3ω² = 1/ω
    assert euler_stability_limit(1, seed_gains_order1(90.0)) == pytest.approx(1 / 90.0)
    assert euler_is_stable(1, seed_gains_order1(90.0), 0.99 / 90.0)
    assert not euler_is_stable(1, seed_gains_order1(90.0), 1.01 / 90.0)


def _continuous_ramp_errors(eso, h0, t_end, comp=False):
    """Exact (expm) response of plant + continuous LESO to a disturbance ramp f = h0·t."""
    n = eso.n
    m = n + 1
    a, b, c, ell, _ = continuous_matrices(n, eso.betas, eso.b0)
    # augmented state [x (m), z (m), 1]; ẋ = A x + E h0·1; ż = A z + L (x1 − z1)
    big = np.zeros((2 * m + 1, 2 * m + 1))
    big[:m, :m] = a
    big[m - 1, 2 * m] = h0
    big[m:2 * m, m:2 * m] = a - np.outer(ell, c)
    big[m:2 * m, :m] = np.outer(ell, c)
    s = expm(big * t_end) @ np.r_[np.zeros(2 * m), 1.0]
    x, z = s[:m], s[m:2 * m]
    if comp:
        z = z + np.r_[1.0, eso.betas[:-1]] * (x[0] - z[0])       # paper eq. 22
    return x - z


@pytest.mark.parametrize('n', [1, 2, 3])
def test_static_error_eq19(n):
    w0, h0 = 50.0, 2.0
    eso = LinearESO(n, 1.0, 1e-3, w0_rad_s=w0)
    want = static_error(n, w0, h0)
    for i in range(n + 1):                                     # eq. 19 written out
        assert want[i] == pytest.approx(comb(n + 1, i) * h0 / w0 ** (n + 1 - i))
    # eq. 16: e = −A_e⁻¹ E h0
    e_vec = np.zeros(n + 1)
    e_vec[-1] = h0
    np.testing.assert_allclose(-np.linalg.solve(eso.A_e, e_vec), want, rtol=1e-10)
    # the continuous observer really settles there (t·ω0 = 60)
    np.testing.assert_allclose(_continuous_ramp_errors(eso, h0, 60.0 / w0), want, rtol=1e-8)
    # and the compensator removes it (paper §3.1, eq. 27): e1' = 0, e' → 0
    comp = _continuous_ramp_errors(eso, h0, 60.0 / w0, comp=True)
    assert comp[0] == 0.0
    assert np.all(np.abs(comp[1:]) < 1e-6 * np.abs(want[1:]))


@pytest.mark.parametrize('n', [1, 2])
def test_discrete_zoh_static_error_close_to_eq19(n):
    w0, h0, h = 100.0, 3.0, 1e-5
    eso = LinearESO(n, 1.0, h, w0_rad_s=w0, discretization='zoh')
    for k in range(int(0.25 / h) + 1):
        t = k * h
        x = [h0 * t ** (n + 2 - i) / factorial(n + 2 - i) for i in range(1, n + 2)]
        z = eso.update(x[0], 0.0)
    # the ZOH current estimator differs from the continuous one by O(ω0·h)
    np.testing.assert_allclose(np.array(x) - z, static_error(n, w0, h0), rtol=(n + 1) * w0 * h)


def test_discrete_euler_compensator_under_ramp():
    # Euler: e2 = 2h0/ω0 (eq. 19) and, from the Euler recursion, e2' = −h·h0/2, so the
    # compensator divides the x2 error by 4/(ω0 h) = 400 here
    w0, h0, h = 100.0, 3.0, 1e-4
    plain = LinearESO(1, 1.0, h, w0_rad_s=w0)
    comp = LinearESO(1, 1.0, h, w0_rad_s=w0, compensate=True)
    for k in range(20001):
        t = k * h
        x = (h0 * t * t / 2, h0 * t)
        zp = plain.update(x[0], 0.0)
        zc = comp.update(x[0], 0.0)
    assert x[0] - zc[0] == 0.0
    assert x[1] - zp[1] == pytest.approx(2 * h0 / w0, rel=1e-2)
    assert x[1] - zc[1] == pytest.approx(-h * h0 / 2, rel=1e-2)


def test_neso_equals_scaled_leso_in_linear_zone():
    n, delta = 2, 0.05
    betas, alphas = (30.0, 300.0, 1000.0), (1.0, 0.5, 0.25)
    neso = NonlinearESO(n, 2.0, 1e-3, betas, alphas, delta, compensate=True)
    scaled = [b * delta ** (a - 1.0) for b, a in zip(betas, alphas, strict=True)]
    leso = LinearESO(n, 2.0, 1e-3, betas=scaled, compensate=False)
    rng = np.random.default_rng(5)
    for k in range(600):
        y = 0.01 * np.sin(0.005 * k) + 1e-4 * rng.normal()
        u = 0.002 * np.cos(0.003 * k)
        e1 = y - neso.z[0]
        assert abs(e1) <= delta
        zn = neso.update(y, u)
        leso.update(y, u)
        np.testing.assert_allclose(neso.z, leso.z, rtol=1e-12, atol=1e-15)
        # eq. 34 in the linear zone: D_i = β_{i−1} δ^(α_{i−1}−1) e1, D_1 = e1
        d = np.r_[e1, np.array(scaled[:-1]) * e1]
        np.testing.assert_allclose(zn, zn - d + d, rtol=1e-12)
    assert zn[0] == pytest.approx(y)            # compensated z1' = y


def _drive(n_steps=300, seed=2):
    rng = np.random.default_rng(seed)
    return rng.normal(size=n_steps), rng.normal(size=n_steps)


def test_fast_steps_equal_linear_eso():
    h, b0 = 5e-4, 3.0
    ys, us = _drive()
    b1 = bandwidth_gains(1, 90.0)
    b2 = bandwidth_gains(2, 90.0)
    l1 = zoh_gains(1, 90.0, h)
    l2 = zoh_gains(2, 90.0, h)
    cases = [
        (LinearESO(1, b0, h, betas=b1), lambda z, y, u: eso1_euler_step(SCALAR, *z, y, u, *b1,
                                                                          b0, h)),
        (LinearESO(2, b0, h, betas=b2), lambda z, y, u: eso2_euler_step(SCALAR, *z, y, u, *b2,
                                                                          b0, h)),
        (LinearESO(1, b0, h, w0_rad_s=90.0, discretization='zoh'),
         lambda z, y, u: eso1_zoh_step(SCALAR, *z, y, u, *l1, b0, h)),
        (LinearESO(2, b0, h, w0_rad_s=90.0, discretization='zoh'),
         lambda z, y, u: eso2_zoh_step(SCALAR, *z, y, u, *l2, b0, h)),
    ]
    for eso, fast in cases:
        eso.reset(0.5)
        z = tuple(eso.z)
        for y, u in zip(ys, us, strict=True):
            eso.update(y, u)
            z = fast(z, y, u)
            np.testing.assert_allclose(z, eso.z, rtol=1e-11, atol=1e-9)


def test_firmware_esoupdate_order1_by_hand():
    # EsoUpdate (CONTROLLER_ORDER 1), ints: b0=100, β=(270, 24300), x1=1000, x2=50, y=1010, u=3
    x1, x2, y, u = 1000, 50, 1010, 3
    eps = y - x1                                                    # 10
    x1 = x1 + c_div(x2 + 270 * eps + 100 * u, 2000)                 # 3050/2000 -> 1
    x2 = x2 + c_div(24300 * eps, 2000)                              # 243000/2000 -> 121
    assert (x1, x2) == (1001, 171)
    # float step in the same units (UnitP, UnitP/s, UnitV): 1001.525, 171.5
    z1, z2 = eso1_euler_step(SCALAR, 1000.0, 50.0, 1010.0, 3.0, 270.0, 24300.0, 100.0, 5e-4)
    assert (z1, z2) == pytest.approx((1001.525, 171.5))
    # ... and in mm with a UnitP of s_p mm and a UnitV of s_v mm/s: b0 → b0·s_p/s_v
    s_p, s_v = 1e-3, 0.06
    m1, m2 = eso1_euler_step(SCALAR, 1000 * s_p, 50 * s_p, 1010 * s_p, 3 * s_v, 270.0, 24300.0,
                             100.0 * s_p / s_v, 5e-4)
    assert (m1 / s_p, m2 / s_p) == pytest.approx((z1, z2))
    # the C truncation loses less than one unit in each state
    assert abs(z1 - x1) < 1 and abs(z2 - x2) < 1


def test_peaking_limits():
    z1, z2 = eso1_euler_step(SCALAR, 0.0, 0.0, 1.0, 0.0, 270.0, 24300.0, 1.0, 5e-4,
                             ext_limit=5.0)
    assert z2 == 5.0                                   # unlimited: 12.15
    z1, z2 = eso1_euler_step(SCALAR, 0.0, 1.0, 1.0, 0.0, 270.0, 24300.0, 1.0, 5e-4,
                             ext_rate_limit=0.5)
    assert z2 == 1.5
    *_, z3 = eso2_euler_step(SCALAR, 0.0, 0.0, -2.0, 1.0, 0.0, 1.0, 1.0, 1e6, 1.0, 1e-3,
                             ext_limit=10.0, ext_rate_limit=3.0)
    assert z3 == 1.0                                   # −2 + min(1000, 3)
    *_, z3 = eso2_zoh_step(SCALAR, 0.0, 0.0, 0.0, -1.0, 0.0, 0.1, 1.0, 1e5, 1.0, 1e-3,
                           ext_limit=7.0)
    assert z3 == -7.0


def test_compensators():
    assert compensate1(SCALAR, 1.0, 2.0, 0.5, 10.0) == (1.5, 7.0)
    assert compensate2(SCALAR, 1.0, 2.0, 3.0, 0.5, 10.0, 100.0) == (1.5, 7.0, 53.0)


def test_batch_equals_scalar_eso_steps():
    h = 5e-4
    ys, us = _drive(200, seed=9)
    b0 = np.array([1.0, 3.0, 10.0])
    ws = (30.0, 60.0, 90.0)

    def cols(rows):
        return [np.array(c) for c in zip(*rows, strict=True)]

    g1 = cols(bandwidth_gains(1, w) for w in ws)
    g2 = cols(bandwidth_gains(2, w) for w in ws)
    z1 = cols(zoh_gains(1, w, h) for w in ws)
    z2 = cols(zoh_gains(2, w, h) for w in ws)
    lim = dict(ext_limit=np.array([50.0, 100.0, 1e9]), ext_rate_limit=np.array([1.0, 2.0, 3.0]))
    for fn, gains, m in ((eso1_euler_step, g1, 2), (eso2_euler_step, g2, 3),
                         (eso1_zoh_step, z1, 2), (eso2_zoh_step, z2, 3)):
        for kw in ({}, lim):
            zb = tuple(np.zeros(3) for _ in range(m))
            zs = [tuple(0.0 for _ in range(m)) for _ in range(3)]
            z_one = tuple(np.zeros(1) for _ in range(m))
            for y, u in zip(ys, us, strict=True):
                zb = fn(ARRAY, *zb, y, u, *gains, b0, h, **kw)
                kw0 = {k: v[:1] for k, v in kw.items()}
                z_one = fn(ARRAY, *z_one, np.array([y]), np.array([u]),
                           *[g[:1] for g in gains], b0[:1], h, **kw0)
                zs = [fn(SCALAR, *zs[i], y, u, *[float(g[i]) for g in gains], float(b0[i]), h,
                         **{k: float(v[i]) for k, v in kw.items()}) for i in range(3)]
            for j in range(m):
                np.testing.assert_array_equal(zb[j], [s[j] for s in zs])
                np.testing.assert_array_equal(z_one[j], [zs[0][j]])
    c_b = compensate2(ARRAY, *(np.array([1.0, 2.0]),) * 3, np.array([0.1, -0.2]),
                      np.array([3.0, 4.0]), np.array([5.0, 6.0]))
    for i in range(2):
        assert tuple(c[i] for c in c_b) == compensate2(SCALAR, *(float(i + 1),) * 3,
                                                       (0.1, -0.2)[i], (3.0, 4.0)[i],
                                                       (5.0, 6.0)[i])


def test_bad_input_messages():
    with pytest.raises(ValueError, match='exactly one'):
        LinearESO(1, 1.0, 1e-3)
    with pytest.raises(ValueError, match='needs 3 gains'):
        LinearESO(2, 1.0, 1e-3, betas=(1.0, 2.0))
    with pytest.raises(ValueError, match='discretization'):
        LinearESO(1, 1.0, 1e-3, w0_rad_s=10.0, discretization='tustin')
    with pytest.raises(ValueError, match='alphas'):
        NonlinearESO(1, 1.0, 1e-3, (1.0, 2.0), (0.5,), 0.1)
    with pytest.raises(ValueError, match='not stable'):
        euler_stability_limit(2, (1.0, 1.0, 5.0))          # s³ + s² + s + 5: Routh fails
