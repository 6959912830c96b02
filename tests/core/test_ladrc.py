"""The composite LADRC: seed equivalence, bumpless start, closed-loop behaviour, batch path."""

from dataclasses import replace

from ladrc_follow.control.ladrc import LADRC
from ladrc_follow.control.params import (
    ControllerParams,
    ESOParams,
    KalmanParams,
    LawParams,
    LimitParams,
)
import numpy as np
import pytest
from scipy import signal

UNIT_P_MM = 0.001           # assumed firmware position unit (docs/control-law.md)
UNIT_V_MM_S = 0.1           # 1 UnitV = b0_int (100) UnitP/s → b0 = 1


def c_div(a: int, b: int) -> int:
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b >= 0) else -q


def seed_update_ladrc(state, height, target, v_max, acc):
    """``UpdateLADRC`` (CONTROLLER_ORDER 1) with ``EsoUpdate`` and ``CompELDTUpdate`` in C ints."""
    x1, x2, trk, diff, n_ctrl = state
    beta1, beta2, b0, kp = 270, 24300, 100, 100     # InitLADRC
    k1, k2, big_r = 12, 40, 100                      # TDB of CompELDTInit (TDA is unused:
    # its feed-forward term is commented out in ELDTrackerCalc and TDB's Fc is 0)
    eps = height - x1
    x1 = x1 + c_div(x2 + beta1 * eps + b0 * n_ctrl, 2000)
    x2 = x2 + c_div(beta2 * eps, 2000)
    trk = c_div(trk * 2000 + diff, 2000)
    err = trk - target
    diff = diff + c_div((c_div(-k1 * err, 10) - c_div(c_div(k2 * diff, 10), big_r))
                        * big_r * big_r, 2000)
    u = c_div(c_div(kp * (trk - x1), 10) + diff - x2, b0)
    if u < 0 and abs(u) > v_max:
        u = -v_max
    d = u - n_ctrl
    if abs(d) > acc:
        d = (-1 if d < 0 else 1) * acc
    return (x1, x2, trk, diff, n_ctrl + d), n_ctrl + d


def with_limits(p, v_max, a_max):
    """Set the output limits; the PID and interpolator limits must not exceed them."""
    return replace(p, limits=LimitParams(v_max_mm_s=v_max, a_max_mm_s2=a_max),
                   pid=replace(p.pid, v_max_mm_s=min(v_max, p.pid.v_max_mm_s),
                               a_max_mm_s2=min(a_max, p.pid.a_max_mm_s2)),
                   interp=replace(p.interp, v_max_mm_s=min(v_max, p.interp.v_max_mm_s),
                                  a_max_mm_s2=min(a_max, p.interp.a_max_mm_s2)))


def seed_params(a_max_mm_s2=1e6):
    return with_limits(ControllerParams(eso=ESOParams(betas=(270.0, 24300.0))), 150.0,
                       a_max_mm_s2)


def test_one_tick_equals_seed_update_ladrc_by_hand():
    # by hand (C ints): ε = 1010 − 1000 = 10; x1 = 1000 + (0 + 2700 + 100·30)/2000 = 1002;
    # x2 = 24300·10/2000 = 121; TDB: trk = 1000, err = −200, diff = (240 − 0)·10⁴/2000 = 1200;
    # u = (100·(1000 − 1002)/10 + 1200 − 121)/100 = 1059/100 = 10 UnitV (unlimited)
    state, u_unl = seed_update_ladrc((1000, 0, 1000, 0, 30), 1010, 1200, 1500, 10**6)
    assert state[:4] == (1002, 121, 1000, 1200)
    assert u_unl == 10
    c = LADRC(seed_params())
    c.reset(1.0, 3.0, 1.2)
    c.z2 = 0.0                       # InitLADRC starts x2 at 0 (ours: −b0·u_prev)
    u = c.step(1.010, 0.0, 1.2)
    assert c.td_x2 == pytest.approx(1200 * UNIT_P_MM)     # exact: no truncation in the TD here
    assert c.z1 == pytest.approx(1.00285)                 # the C code truncates 2.85 → 2 UnitP
    assert c.z2 == pytest.approx(0.1215)
    assert u == pytest.approx(1.05)                       # 10.5 UnitV, C: 10 (truncated)
    assert abs(u - u_unl * UNIT_V_MM_S) <= 1.0 * UNIT_V_MM_S
    # with the acceleration limit active both are the same number: 30 − 8 = 22 UnitV
    _, u_lim = seed_update_ladrc((1000, 0, 1000, 0, 30), 1010, 1200, 1500, 8)
    c = LADRC(seed_params(a_max_mm_s2=8 * UNIT_V_MM_S / 0.0005))
    c.reset(1.0, 3.0, 1.2)
    c.z2 = 0.0
    assert c.step(1.010, 0.0, 1.2) == pytest.approx(u_lim * UNIT_V_MM_S)
    assert u_lim == 22 and c.rate_limited and not c.saturated


def test_seed_integer_loop_tracks_float_loop():
    """20 ticks of seed ints vs floats on the same plant agree within the integer truncation.

    Longer runs part: the firmware's ``nTracker = (nTracker*2000 + nDiff)/2000`` drops up to
    one UnitP per tick and stalls completely once |nDiff| < 2000 UnitP/s (docs/control-law.md).
    """
    c = LADRC(seed_params(a_max_mm_s2=4000.0))
    c.reset(1.0, 0.0, 1.5)
    c.z2 = 0.0
    st = (1000, 0, 1000, 0, 0)
    y_f, y_i = 1.0, 1.0
    h = 0.0005
    for k in range(20):
        u_f = c.step(y_f, 0.0, 1.5)
        st, u_i = seed_update_ladrc(st, round(y_i / UNIT_P_MM), 1500, 1500, 20)
        y_f += h * u_f
        y_i += h * u_i * UNIT_V_MM_S
        assert abs(u_f - u_i * UNIT_V_MM_S) <= 2 * UNIT_V_MM_S + 0.02 * abs(u_f), k
    assert abs(y_f - y_i) < 3 * UNIT_P_MM


@pytest.mark.parametrize('order,disc,kalman', [(1, 'euler', False), (1, 'zoh', True),
                                               (2, 'euler', False), (2, 'zoh', True)])
def test_bumpless_reset(order, disc, kalman):
    p = _params(order, disc, kalman)
    c = LADRC(p)
    c.reset(1.3, -7.5, 1.3, encoder_mm=10.0)
    # same reading and target as at the reset: the first command is the previous one
    assert c.step(1.3, 10.0, 1.3) == pytest.approx(-7.5, rel=1e-12)
    assert not c.rate_limited


def _params(order, disc='euler', kalman=False, compensator=False, **eso_kw):
    if order == 1:
        eso = ESOParams(order=1, discretization=disc, gains='bandwidth', w0_rad_s=150.0,
                        compensator=compensator, **eso_kw)
        law = LawParams(form=3, kp=20.0)
    else:
        eso = ESOParams(order=2, discretization=disc, gains='bandwidth', w0_rad_s=300.0,
                        b0=1.0 / 0.008, compensator=compensator, **eso_kw)
        law = LawParams(form=3, gains='bandwidth', wc_rad_s=40.0)
    return ControllerParams(eso=eso, law=law, kalman=KalmanParams(enabled=kalman),
                            limits=LimitParams(v_max_mm_s=150.0, a_max_mm_s2=4000.0))


def _run_integrator(c, d_fn, n, target, y0=1.0, b=1.0):
    h = 0.0005
    y = y0
    ys = np.empty(n)
    for k in range(n):
        u = c.step(y, 0.0, target)
        y = y + h * (b * u + d_fn(k * h))
        ys[k] = y
    return ys


def test_constant_disturbance_zero_steady_error():
    p = ControllerParams()   # the seed-faithful defaults
    c = LADRC(p)
    c.reset(1.0, 0.0, 1.0)
    ys = _run_integrator(c, lambda t: 8.0, 8000, 1.0)
    assert abs(ys[-1] - 1.0) < 1e-9
    assert c.z2 == pytest.approx(8.0, abs=1e-6)     # the ESO found the disturbance
    assert c.disturbance_term == pytest.approx(-8.0, abs=1e-6)


def _closed_loop_tf(kp, b1, b2):
    # order-1 LADRC with a continuous ESO on ẏ = b0·u + d (r constant):
    # Y/D = s(s + β1 + kp) / ((s + kp)(s² + β1 s + β2))  (derivation in docs/control-law.md)
    return signal.TransferFunction(np.polymul([1.0, 0.0], [1.0, b1 + kp]),
                                   np.polymul([1.0, kp], [1.0, b1, b2]))


def test_disturbance_step_response_matches_analytic():
    kp, w0 = 20.0, 150.0
    p = replace(_params(1), law=LawParams(form=3, kp=kp))
    c = LADRC(p)
    c.reset(1.0, 0.0, 1.0)
    n = 1200
    ys = _run_integrator(c, lambda t: 5.0, n, 1.0) - 1.0
    t = np.arange(n + 1) * 0.0005     # lsim starts at T[0]; ys[k] is y at (k + 1)·h
    _, y_ref = signal.step(_closed_loop_tf(kp, 2 * w0, w0 * w0), T=t)
    y_ref = 5.0 * y_ref[1:]
    peak = np.max(np.abs(y_ref))
    assert peak == pytest.approx(np.max(np.abs(ys)), rel=0.05)
    assert np.max(np.abs(ys - y_ref)) < 0.05 * peak
    assert abs(ys[-1]) < 0.02 * peak     # and it returns to zero (integral action of the ESO)


def test_ramp_disturbance_steady_error_matches_final_value():
    kp, w0, c_ramp = 20.0, 150.0, 50.0   # d = 50 mm/s² · t
    p = replace(_params(1), law=LawParams(form=3, kp=kp))
    c = LADRC(p)
    c.reset(1.0, 0.0, 1.0)
    ys = _run_integrator(c, lambda t: c_ramp * t, 3000, 1.0) - 1.0
    b1, b2 = 2 * w0, w0 * w0
    expected = c_ramp * (b1 + kp) / (kp * b2)        # final value theorem on Y/D·c/s²
    assert ys[-1] == pytest.approx(expected, rel=0.03)


def test_order2_on_first_order_lag_plant_converges():
    p = _params(2, 'zoh')
    c = LADRC(p)
    c.reset(1.0, 0.0, 1.0)
    h, t1, v_sheet = 0.0005, 0.008, 3.0
    pos, vel, sheet = 1.0, 0.0, 0.0
    for _ in range(6000):
        u = c.step(pos - sheet, 0.0, 1.4)
        a = np.exp(-h / t1)           # exact ZOH of the velocity loop T1·v' + v = u
        pos += h * u + (vel - u) * t1 * (1.0 - a)
        vel = u + (vel - u) * a
        sheet += h * v_sheet
    assert pos - sheet == pytest.approx(1.4, abs=1e-6)


def test_form2_uses_raw_target():
    p = replace(ControllerParams(), law=LawParams(form=2, kp=10.0))
    c = LADRC(p)
    c.reset(1.0, 0.0, 1.0)
    c.step(1.0, 0.0, 1.5)
    assert c.p_term == pytest.approx(10.0 * 0.5, rel=1e-3)  # kp(v − z1), v the raw target
    assert c.ff_term == 0.0


def test_limits_hold_in_closed_loop():
    c = LADRC(ControllerParams())
    c.reset(1.0, 0.0, 1.0)
    rng = np.random.default_rng(3)
    u_prev = 0.0
    du = 4000.0 * 0.0005
    for k in range(3000):
        u = c.step(1.0 + rng.normal(0, 2.0), 0.0, 1.0 + 5.0 * np.sin(k * 0.01))
        assert abs(u) <= 150.0 and abs(u - u_prev) <= du + 1e-9
        u_prev = u


# --------------------------------------------------------------------------- batch
def _closed_loop_batch_vs_scalar(plist, n=2000):
    rng = np.random.default_rng(7)
    noise = rng.normal(0.0, 0.003, size=n)
    h = 0.0005
    batch = LADRC.batch(plist)
    scal = [LADRC(p) for p in plist]
    nb = len(plist)
    y = np.full(nb, 1.0)
    enc = np.zeros(nb)
    batch.reset(y, np.full(nb, 2.0), np.full(nb, 1.0), encoder_mm=enc)
    for s in scal:
        s.reset(1.0, 2.0, 1.0, encoder_mm=0.0)
    ys = [1.0] * nb
    encs = [0.0] * nb
    for k in range(n):
        t = k * h
        target = 1.0 + 0.3 * (t > 0.2)
        d = 4.0 * np.sin(2 * np.pi * 3.0 * t)
        ub = batch.step(y + noise[k], enc, target)
        y = y + h * (ub + d)
        enc = enc + h * ub
        for i, s in enumerate(scal):
            us = s.step(ys[i] + float(noise[k]), encs[i], target)
            ys[i] = ys[i] + h * (us + float(d))
            encs[i] = encs[i] + h * us
            assert ub[i] == us, f'row {i} differs at tick {k}'
    for i, s in enumerate(scal):
        for name in ('z1', 'z2', 'z3', 'td_x1', 'td_x2', 'fused_gap_mm', 'u0', 'u_unlimited'):
            assert getattr(batch, name)[i] == getattr(s, name), name


@pytest.mark.parametrize('order,disc,kalman,comp,lim', [
    (1, 'euler', False, False, 0.0),
    (1, 'zoh', True, True, 3.0),
    (2, 'euler', True, True, 0.0),
    (2, 'zoh', False, False, 5000.0),
])
def test_batch_of_one_equals_scalar_bit_for_bit(order, disc, kalman, comp, lim):
    p = _params(order, disc, kalman, comp, disturbance_limit=lim)
    _closed_loop_batch_vs_scalar([p])


def test_batch_rows_are_independent():
    base = _params(1, 'euler', True, False)
    plist = [base,
             replace(base, eso=replace(base.eso, w0_rad_s=90.0, b0=1.3),
                     law=LawParams(form=1, kp=15.0)),
             replace(with_limits(base, 20.0, 900.0), kalman=replace(base.kalman, r_mm2=1e-3))]
    _closed_loop_batch_vs_scalar(plist, n=1500)


def test_batch_rejects_mixed_structure():
    with pytest.raises(ValueError, match="differs from set 0 in 'order'"):
        LADRC.batch([_params(1), _params(2)])
