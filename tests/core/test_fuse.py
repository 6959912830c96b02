"""The generated (fused) tick equals the plain composition of the shared step functions.

fuse.py inlines td/eso/kalman/law step functions into one function per structure; it must
not change a single IEEE operation. Reference: the same tick template compiled as
written (``fused=False``: one call per shared step function). Compared bit for bit
(bytes, so −0.0 ≠ +0.0) over closed-loop runs that hit saturation, the acceleration
limit, target steps, sensor noise and (with the Kalman filter) encoder increments.
"""

import ast
from dataclasses import replace
import itertools

from ladrc_follow.control import fuse
from ladrc_follow.control.ladrc import LADRC
from ladrc_follow.control.params import (
    ControllerParams,
    ESOParams,
    KalmanConfig,
    LawParams,
    LimitParams,
)
from ladrc_follow.control.tick import SHARED_STEPS
import numpy as np
import pytest

ATTRS = ('u', 'td_x1', 'td_x2', 'td_ddr', 'z1', 'z2', 'z3', 'fused_gap_mm', 'kalman_p',
         'kalman_k', 'u0', 'p_term', 'd_term', 'ff_term', 'disturbance_term', 'u_unlimited',
         'saturated', 'rate_limited')


def _params(order, disc, comp, kalman, form=3, ext=0.0, ext_rate=0.0, kp=20.0, w0=None):
    if order == 1:
        eso = ESOParams(order=1, discretization=disc, gains='bandwidth',
                        w0_rad_s=w0 or 150.0, compensator=comp, disturbance_limit=ext,
                        disturbance_rate_limit=ext_rate)
        law = LawParams(form=form, kp=kp)
    else:
        eso = ESOParams(order=2, discretization=disc, gains='bandwidth', w0_rad_s=w0 or 300.0,
                        b0=1.0 / 0.008, compensator=comp, disturbance_limit=ext,
                        disturbance_rate_limit=ext_rate)
        law = LawParams(form=form, gains='bandwidth', wc_rad_s=40.0)
    # a tight acceleration limit so the rate limiter and the saturation both act
    return ControllerParams(eso=eso, law=law, kalman=KalmanConfig(enabled=kalman),
                            limits=LimitParams(v_max_mm_s=25.0, a_max_mm_s2=3000.0),
                            pid=replace(ControllerParams().pid, v_max_mm_s=25.0,
                                        a_max_mm_s2=3000.0),
                            interp=replace(ControllerParams().interp, v_max_mm_s=25.0,
                                           a_max_mm_s2=3000.0))


def _bits(x):
    return np.asarray(x, dtype=float).tobytes()


def _run_pair(make, n_ticks, rows=None):
    """Drive a fused and a plain controller with the same closed loop; compare every tick."""
    fused, plain = make(True), make(False)
    rng = np.random.default_rng(11)
    shape = () if rows is None else (rows,)
    h = 0.0005
    y = np.ones(shape)
    enc = np.zeros(shape)
    for c in (fused, plain):
        c.reset(y + 0.0, y * 0.0 + 3.0, 1.0, encoder_mm=enc + 0.0)
    t = np.arange(n_ticks) * h
    targets = (1.0 + 0.4 * (t > 0.1) - 0.3 * (t > 0.6)).tolist()
    dist = 15.0 * np.sin(2 * np.pi * 4.0 * t) + 20.0 * np.sign(np.sin(2 * np.pi * 10.0 * t))
    noise = rng.normal(0.0, 0.004, size=(n_ticks, *shape))
    if rows is None:
        y, enc, dist, noise = float(y), float(enc), dist.tolist(), noise.tolist()
    hits = np.zeros(2)
    for k in range(n_ticks):
        gap = y + noise[k]
        uf = fused.step(gap, enc, targets[k])
        up = plain.step(gap, enc, targets[k])
        if rows is None:
            assert uf == up and str(uf) == str(up), f'u differs at tick {k}'
        else:
            assert _bits(uf) == _bits(up), f'u differs at tick {k}'
        if k % 97 == 0 or k == n_ticks - 1:
            for name in ATTRS:
                assert _bits(getattr(fused, name)) == _bits(getattr(plain, name)), (name, k)
        hits += (np.any(fused.saturated), np.any(fused.rate_limited))
        y = y + h * (uf + dist[k])
        enc = enc + h * uf
    assert np.all(hits > 0), 'the run must exercise both output limits'
    return fused


CONFIGS = list(itertools.product((1, 2), ('euler', 'zoh'), (False, True), (False, True)))


@pytest.mark.parametrize('order,disc,comp,kalman', CONFIGS)
def test_fused_scalar_equals_plain_composition(order, disc, comp, kalman):
    p = _params(order, disc, comp, kalman)
    c = _run_pair(lambda fused: LADRC(p, fused=fused), 3000)
    # and it is really one function: no call of a shared step function or of ``ops`` is left
    calls = [n.func for n in ast.walk(ast.parse(c.step.__func__.__fused_source__))
             if isinstance(n, ast.Call)]
    assert not [f for f in calls if isinstance(f, ast.Name) and f.id in SHARED_STEPS]
    assert not [f for f in calls if isinstance(f, ast.Attribute)]


@pytest.mark.parametrize('order,disc,comp,kalman', CONFIGS)
def test_fused_batch_equals_plain_composition(order, disc, comp, kalman):
    base = _params(order, disc, comp, kalman)
    plist = [base, replace(base, law=replace(base.law, kp=7.0, wc_rad_s=25.0)),
             replace(base, eso=replace(base.eso, w0_rad_s=base.eso.w0_rad_s * 0.6))]
    _run_pair(lambda fused: LADRC.batch(plist, fused=fused), 600, rows=len(plist))


@pytest.mark.parametrize('order,form,ext,ext_rate', [(1, 2, 40.0, 0.0), (1, 1, 0.0, 0.2),
                                                     (2, 2, 4000.0, 50.0), (2, 1, 0.0, 0.0)])
def test_fused_other_forms_and_peaking_limits(order, form, ext, ext_rate):
    p = _params(order, 'euler', True, True, form=form, ext=ext, ext_rate=ext_rate)
    _run_pair(lambda fused: LADRC(p, fused=fused), 1500)
    _run_pair(lambda fused: LADRC.batch([p, p], fused=fused), 400, rows=2)


def test_plain_state_writes_are_seen_by_the_fused_tick():
    # follow.py writes ``u`` (the applied command) and tests write z2 between ticks
    p = _params(1, 'euler', False, False)
    a, b = LADRC(p), LADRC(p, fused=False)
    for c in (a, b):
        c.reset(1.0, 0.0, 1.2)
        c.step(1.01, 0.0, 1.2)
        c.u = 5.0
        c.z2 = -1.5
    assert _bits(a.step(1.02, 0.0, 1.2)) == _bits(b.step(1.02, 0.0, 1.2))
    assert _bits(a.z1) == _bits(b.z1)


def test_inliner_rejects_what_it_cannot_inline():
    def two_returns(ops, x):
        if x > 0.0:
            return x
        return -x

    def template(self, v):
        y = two_returns(ops, v)  # noqa: F821 - bound by the generated factory
        return y

    with pytest.raises(ValueError, match='only return'):
        fuse.build(template, {'two_returns': two_returns}, {}, {}, None)
