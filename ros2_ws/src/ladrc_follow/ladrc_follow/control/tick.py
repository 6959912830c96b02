"""The LADRC tick written once as a template composing the shared step functions.

:mod:`ladrc` compiles these through :func:`fuse.build`: as written (``fused=False``, the
plain composition: a call per step function) or with the step functions' bodies inlined
into one function (the default; see the module doc of :mod:`fuse`). The templates are
never called from here: their free names are bound by the factory ``fuse.build``
generates: ``ops`` (SCALAR/ARRAY), the numbers of :func:`factory_consts` (scalars, or
arrays of N rows for a batch) and the structural literals of :func:`literals`
(``KALMAN``, ``EULER``, ``COMPENSATOR``, ``USE_TD``; ``ext_limit`` / ``ext_rate_limit``
= None when off). Hence the file-wide F821 exemption below.
"""
# ruff: noqa: F821

from __future__ import annotations

from .eso import (
    compensate1,
    compensate2,
    eso1_euler_step,
    eso1_zoh_step,
    eso2_euler_step,
    eso2_zoh_step,
)
from .kalman import kalman_step
from .law import apply_limits, law1, law2
from .td import td_step_firmware


def tick1(self, gap_mm, encoder_mm, target_mm):
    """Order-1 tick (seed ``CONTROLLER_ORDER 1``): Kalman, ESO, TD, law, limits."""
    u_prev = self.u
    if KALMAN:
        # notes §4: the encoder increment predicts the gap, the reading corrects it
        enc_prev = self._enc_prev
        dz = 0.0 if (enc_prev is None or encoder_mm is None) else encoder_mm - enc_prev
        self._enc_prev = encoder_mm
        y, self.kalman_p, self.kalman_k = kalman_step(ops, self.fused_gap_mm, self.kalman_p,
                                                      gap_mm, dz, q, r)
    else:
        y = gap_mm
    self.fused_gap_mm = y

    # ESO with the applied previous output (UpdateLADRC: EsoUpdate(nCtrl, height))
    z1o = self.z1
    z2o = self.z2
    if EULER:
        z1, z2 = eso1_euler_step(ops, z1o, z2o, y, u_prev, g1, g2, b0, h, ext_limit,
                                 ext_rate_limit)
    else:
        z1, z2 = eso1_zoh_step(ops, z1o, z2o, y, u_prev, g1, g2, b0, h, ext_limit,
                               ext_rate_limit)
    self.z1 = z1
    self.z2 = z2
    if COMPENSATOR:
        # paper eq. 22, measurement and estimate of the same instant
        if EULER:
            z1, z2 = compensate1(ops, z1o, z2o, y - z1o, c1)
        else:
            z1, z2 = compensate1(ops, z1, z2, y - z1, c1)

    # compound TD on the target (CompELDTUpdate): TDA, then TDB fed TDA's increment
    a1, a2, b1, b2, v_prev = self._td
    na1, na2 = td_step_firmware(ops, a1, a2, target_mm, target_mm - v_prev,
                                ak1, ak2, ar, aal, h)
    b1, b2 = td_step_firmware(ops, b1, b2, target_mm, na1 - a1, bk1, bk2, br, bal, h)
    self._td = (na1, na2, b1, b2, target_mm)
    self.td_x1 = b1
    self.td_x2 = b2
    self.target_mm = target_mm
    if USE_TD:
        p_term, ff, u0, u = law1(ops, b1, b2, z1, z2, kp, b0, w_rate)
    else:  # form 2: the raw target, no reference derivative
        p_term, ff, u0, u = law1(ops, target_mm, 0.0, z1, z2, kp, b0, w_rate)
    self.p_term = p_term
    self.ff_term = ff
    self.u0 = u0
    self.u_unlimited = u
    self.disturbance_term = -(z2 / b0)

    # saturation, then the acceleration limit against the applied previous output
    u, self.saturated, self.rate_limited = apply_limits(ops, u, u_prev, v_max, du_max)
    self.u = u
    return u


def tick2(self, gap_mm, encoder_mm, target_mm):
    """Order-2 tick: as :func:`tick1` with z = (gap, gap rate, disturbance), r̈ = Δṙ/h."""
    u_prev = self.u
    if KALMAN:
        enc_prev = self._enc_prev
        dz = 0.0 if (enc_prev is None or encoder_mm is None) else encoder_mm - enc_prev
        self._enc_prev = encoder_mm
        y, self.kalman_p, self.kalman_k = kalman_step(ops, self.fused_gap_mm, self.kalman_p,
                                                      gap_mm, dz, q, r)
    else:
        y = gap_mm
    self.fused_gap_mm = y

    z1o = self.z1
    z2o = self.z2
    z3o = self.z3
    if EULER:
        z1, z2, z3 = eso2_euler_step(ops, z1o, z2o, z3o, y, u_prev, g1, g2, g3, b0, h,
                                     ext_limit, ext_rate_limit)
    else:
        z1, z2, z3 = eso2_zoh_step(ops, z1o, z2o, z3o, y, u_prev, g1, g2, g3, b0, h,
                                   ext_limit, ext_rate_limit)
    self.z1 = z1
    self.z2 = z2
    self.z3 = z3
    if COMPENSATOR:
        if EULER:
            z1, z2, z3 = compensate2(ops, z1o, z2o, z3o, y - z1o, c1, c2)
        else:
            z1, z2, z3 = compensate2(ops, z1, z2, z3, y - z1, c1, c2)

    a1, a2, b1, b2o, v_prev = self._td
    na1, na2 = td_step_firmware(ops, a1, a2, target_mm, target_mm - v_prev,
                                ak1, ak2, ar, aal, h)
    b1, b2 = td_step_firmware(ops, b1, b2o, target_mm, na1 - a1, bk1, bk2, br, bal, h)
    self._td = (na1, na2, b1, b2, target_mm)
    ddr = (b2 - b2o) / h
    self.td_x1 = b1
    self.td_x2 = b2
    self.td_ddr = ddr
    self.target_mm = target_mm
    if USE_TD:
        p_term, d_term, ff, u0, u = law2(ops, b1, b2, ddr, z1, z2, z3, kp, kd, b0,
                                         w_rate, w_acc)
    else:
        p_term, d_term, ff, u0, u = law2(ops, target_mm, 0.0, 0.0, z1, z2, z3, kp, kd, b0,
                                         w_rate, w_acc)
    self.p_term = p_term
    self.d_term = d_term
    self.ff_term = ff
    self.u0 = u0
    self.u_unlimited = u
    self.disturbance_term = -(z3 / b0)

    u, self.saturated, self.rate_limited = apply_limits(ops, u, u_prev, v_max, du_max)
    self.u = u
    return u


# the shared step functions a template may call (fuse.py inlines exactly these)
SHARED_STEPS = {f.__name__: f for f in (
    kalman_step, eso1_euler_step, eso1_zoh_step, eso2_euler_step, eso2_zoh_step,
    compensate1, compensate2, td_step_firmware, law1, law2, apply_limits)}


def literals(c: dict) -> dict:
    """Structural values of a parameter set: folded into the generated tick."""
    lit = dict(KALMAN=bool(c['kalman']), EULER=c['discretization'] == 'euler',
               COMPENSATOR=bool(c['compensator']), USE_TD=bool(c['use_td']))
    if not c['ext_limit']:
        lit['ext_limit'] = None
    if not c['ext_rate_limit']:
        lit['ext_rate_limit'] = None
    return lit


def factory_consts(c: dict) -> dict:
    """Return the numbers a tick template reads (scalars, or arrays of N rows for a batch)."""
    ak1, ak2, ar, aal = c['ta']
    bk1, bk2, br, bal = c['tb']
    out = dict(h=c['h'], g1=c['g1'], g2=c['g2'], g3=c['g3'], b0=c['b0'], c1=c['c1'],
               c2=c['c2'], kp=c['kp'], kd=c['kd'], w_rate=c['w_rate'], w_acc=c['w_acc'],
               v_max=c['v_max'], du_max=c['du_max'], q=c['q'], r=c['r'], ak1=ak1, ak2=ak2,
               ar=ar, aal=aal, bk1=bk1, bk2=bk2, br=br, bal=bal)
    if c['ext_limit']:
        out['ext_limit'] = c['ext_limit_v']
    if c['ext_rate_limit']:
        out['ext_rate_limit'] = c['ext_rate_limit_v']
    return out
