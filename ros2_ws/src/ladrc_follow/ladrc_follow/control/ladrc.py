"""The composite LADRC height controller (notes §3, ``LADRC.c`` ``UpdateLADRC``).

One tick, in the seed's order, for a gap reading y, encoder position and target v:

1. optional Kalman (notes §4): fused gap from the reading and the encoder
   increment; the fused gap replaces y for the observer;
2. ESO (order 1 or 2, 'euler' = the firmware's ``EsoUpdate`` or 'zoh' current
   estimator) fed the APPLIED (limited) output of the previous tick; optional
   paper eq. 22 compensation and peaking limits (notes §3.4);
3. compound TD on the target (``CompELDTUpdate``) → r, ṙ (and r̈ = Δṙ/h);
4. law u = (u0 − z_{n+1})/b0 in the configured form (:mod:`law`);
5. saturation ±v_max and acceleration limit a_max·h (``UpdateLADRC``).

Bumpless start (:meth:`LADRC.reset`): the seed re-initialises the LADRC every
tick from the PID's output while not followed (``Follow_OnStep``:
``InitLADRC(height, height, pidOut)``). Here TD at the current gap (at rest),
ESO z1 = gap and the disturbance state z_{n+1} = −b0·u_prev, i.e. the
disturbance that makes u_prev the equilibrium command (ẏ = b0·u + f = 0); the
seed starts it at 0, which makes the first LADRC output jump to (u0 − 0)/b0
— an acceleration-limited bump. With this choice a step with the same reading
and target returns u_prev.

Scalar and batch share :meth:`LADRC.step`: built with :meth:`LADRC.batch` the
numeric parameters are numpy arrays (one row per parameter set) and the same
arithmetic runs on arrays through the ``ARRAY`` ops.

The tick is plain Python composing the step functions of :mod:`td`, :mod:`eso`,
:mod:`kalman` and :mod:`law` (one implementation of each algorithm): :meth:`LADRC.step_order1` for
order 1 and :meth:`LADRC.step_order2` for order 2, bound as ``step`` at construction. Numbers are
read once per tick into locals; nothing is generated or rewritten at run time.
"""

from __future__ import annotations

from typing import Sequence

from ladrc_contract.ops import ARRAY, SCALAR
import numpy as np

from .eso import (
    bandwidth_gains,
    compensate1,
    compensate2,
    eso1_euler_step,
    eso1_fal_step,
    eso1_zoh_step,
    eso2_euler_step,
    eso2_fal_step,
    eso2_zoh_step,
    fal_alphas,
)
from .kalman import kalman_gated_step
from .law import apply_limits, form_weights, law_order1, law_order2
from .nonlinear import LookupTable, fal
from .params import ControllerParams, check, eso_gains, law_gains
from .td import td_step_firmware

# values that must be equal in every row of a batch (they select the code path)
_STRUCTURAL = ('order', 'discretization', 'compensator', 'kalman', 'use_td', 'ext_limit',
               'ext_rate_limit', 'nonlinear', 'fal_table')


def tick_constants(p: ControllerParams) -> dict:
    """Return the per-tick constants of one parameter set, derived once (read by name).

    ``ta``/``tb``: the compound TD's two stages (k1, k2, r, alpha); ``g1..g3``: the observer
    gains; ``c1``, ``c2``: the compensator weights; ``kp``, ``kd``, ``w_rate``, ``w_acc``: the
    law; ``q``, ``r``, ``p0``, ``kgate``, ``kconfirm``: the Kalman filter. The linear analysis
    (``ladrc_follow.analysis.loop``) builds its probe controllers from the same constants.
    """
    e = p.eso
    gains = eso_gains(p)
    kp, kd = law_gains(p)
    use_td, w_rate, w_acc = form_weights(p.law.form, e.order)
    g = gains + (0.0,) * (3 - len(gains))
    fa = fal_alphas(e.order, e.nonlinear, e.fal_alpha) + (1.0,) * (2 - e.order)
    return dict(
        nonlinear=e.nonlinear, fal_table=e.fal_table, fal=(fa[0], fa[1], fa[2]),
        fal_delta=e.fal_delta_mm, fal_size=float(e.fal_table_size),
        fal_range=e.fal_table_range_mm,
        h=p.h_s,
        ta=(p.td_a.k1, p.td_a.k2, p.td_a.r_per_s, p.td_a.alpha),
        tb=(p.td_b.k1, p.td_b.k2, p.td_b.r_per_s, p.td_b.alpha),
        g1=g[0], g2=g[1], g3=g[2], b0=e.b0,
        # compensator weights are the continuous betas (paper eq. 22: D_i = β_{i−1}·e1)
        c1=(g[0] if e.discretization == 'euler' else
            _cont_betas(p)[0]),
        c2=(g[1] if e.discretization == 'euler' else _cont_betas(p)[1]),
        kp=kp, kd=kd, w_rate=w_rate, w_acc=w_acc,
        v_max=p.limits.v_max_mm_s, du_max=p.limits.a_max_mm_s2 * p.h_s,
        q=p.kalman.q_mm2, r=p.kalman.r_mm2, p0=p.kalman.p0_mm2,
        kgate=p.kalman.gate_mm, kconfirm=float(p.kalman.gate_confirm_ticks),
        order=e.order, discretization=e.discretization, compensator=e.compensator,
        kalman=p.kalman.enabled, use_td=use_td,
        ext_limit=e.disturbance_limit > 0.0, ext_rate_limit=e.disturbance_rate_limit > 0.0,
        ext_limit_v=e.disturbance_limit, ext_rate_limit_v=e.disturbance_rate_limit,
    )


def _cont_betas(p: ControllerParams) -> tuple[float, ...]:
    return bandwidth_gains(p.eso.order, p.eso.w0_rad_s)


class LADRC:
    """Composite LADRC: compound TD + ESO (+ Kalman) + law + limits, scalar or batch.

    Scalar: ``LADRC(params)``; batch of N parameter sets: ``LADRC.batch([p0, p1, …])``
    (inputs and outputs are then arrays of shape (N,); scalars broadcast). Parameter
    sets of a batch may differ in every number but must share the structure (ESO
    order, discretization, compensator, Kalman on/off, law form's use of the TD,
    peaking limits on/off).

    After :meth:`step` these attributes hold the internals of the tick: ``td_x1``,
    ``td_x2`` (r, ṙ), ``td_ddr`` (r̈), ``z1``, ``z2``, ``z3`` (order 2; 0 for order
    1), ``fused_gap_mm`` (= the reading without Kalman), ``kalman_p``, ``kalman_k``,
    ``u0``, ``p_term``, ``d_term``, ``ff_term``, ``disturbance_term``
    (−z_{n+1}/b0), ``u_unlimited``, ``saturated``, ``rate_limited`` and ``u`` (the
    applied output, mm/s).
    """

    def __init__(self, params: ControllerParams | None = None, *,
                 _consts=None, _ops=None, _n=None) -> None:
        if _consts is None:
            self.params = check(params if params is not None else ControllerParams())
            consts = tick_constants(self.params)
            self.ops = SCALAR
            self.n = None
        else:
            self.params = params
            consts, self.ops, self.n = _consts, _ops, _n
        c = consts
        self.order = c['order']
        self.discretization = c['discretization']
        self.compensator = c['compensator']
        self.kalman_enabled = c['kalman']
        self.use_td = c['use_td']
        self._euler = c['discretization'] == 'euler'
        self._b0 = c['b0']
        self._p0 = c['p0']
        self._h = c['h']
        self._gains = (c['g1'], c['g2'], c['g3'])
        self._comp = (c['c1'], c['c2'])
        self._law = (c['kp'], c['kd'], c['w_rate'], c['w_acc'])
        self._limits = (c['v_max'], c['du_max'])
        self._kalman_qr = (c['q'], c['r'])
        self._kalman_gate = (c['p0'], c['kgate'], c['kconfirm'])
        self._td_a = c['ta']
        self._td_b = c['tb']
        self._ext = (c['ext_limit_v'] if c['ext_limit'] else None,
                     c['ext_rate_limit_v'] if c['ext_rate_limit'] else None)
        self._g = self._fal_corrections(c)
        self.step = self.step_order1 if self.order == 1 else self.step_order2
        self.reset(0.0, 0.0, 0.0)

    def _fal_corrections(self, c: dict):
        """Return g(ε) -> (g_1..g_{n+1}) of the fal-ESO, or None for the linear ESO.

        Direct: fal(ε, α_i, δ) (paper eq. 6); table: the firmware's lookup, one odd table per
        exponent over ±``fal_table_range_mm`` (:class:`.nonlinear.LookupTable`).
        """
        if c['nonlinear'] == 'off':
            return None
        n1 = self.order + 1
        alphas, delta, ops = c['fal'][:n1], c['fal_delta'], self.ops
        if not c['fal_table']:
            return lambda e: tuple(fal(ops, e, a, delta) for a in alphas)
        if self.n is not None:
            raise ValueError('LADRC.batch: eso.fal_table (lookup tables) runs on the scalar '
                             'path only; sweep the direct fal instead')
        tables = [LookupTable(lambda x, a=a: fal(ARRAY, x, a, delta), -c['fal_range'],
                              c['fal_range'], int(c['fal_size']), odd=True,
                              extrapolate='linear') for a in alphas]
        return lambda e: tuple(t(e) for t in tables)

    @classmethod
    def batch(cls, params: Sequence[ControllerParams]) -> LADRC:
        """N controllers on numpy arrays, one row per parameter set, one code path."""
        params = [check(p) for p in params]
        if not params:
            raise ValueError('LADRC.batch needs at least one parameter set')
        rows = [tick_constants(p) for p in params]
        first = rows[0]
        for i, row in enumerate(rows[1:], start=1):
            for key in _STRUCTURAL:
                if row[key] != first[key]:
                    raise ValueError(
                        f'LADRC.batch: parameter set {i} differs from set 0 in {key!r} '
                        f'({row[key]!r} vs {first[key]!r}); a batch runs one code path, so '
                        'only numeric values may differ')
        consts = dict(first)
        for key, val in first.items():
            if key in _STRUCTURAL or key == 'discretization':
                continue
            if isinstance(val, tuple):
                consts[key] = tuple(np.array([r[key][j] for r in rows], dtype=float)
                                    for j in range(len(val)))
            else:
                consts[key] = np.array([r[key] for r in rows], dtype=float)
        return cls(params, _consts=consts, _ops=ARRAY, _n=len(rows))

    # ------------------------------------------------------------------ state
    def _vec(self, x):
        """Return a scalar as-is, or broadcast it to a fresh float array of N rows (batch)."""
        if self.n is None:
            return float(x)
        return np.zeros(self.n) + x

    def reset(self, gap_mm, u_prev_mm_s, target_mm, encoder_mm=None) -> None:
        """Bumpless (re)start at the current gap with the previously applied command.

        TD at rest on the gap (``CompELDTInit(height)``), ESO z1 = gap, gap rate 0,
        z_{n+1} = −b0·u_prev, Kalman x = gap with P = p0, previous output u_prev.
        ``encoder_mm`` (optional) is the reference for the next encoder increment.
        """
        gap = self._vec(gap_mm)
        u_prev = self._vec(u_prev_mm_s)
        zero = self._vec(0.0)
        b0 = self._b0
        self.target_mm = self._vec(target_mm)
        self._td = (gap, zero, gap, zero, gap)
        self.td_x1, self.td_x2, self.td_ddr = gap, zero, zero
        self.z1 = gap
        dist = -(b0 * u_prev)
        if self.order == 1:
            self.z2, self.z3 = dist, zero
        else:
            self.z2, self.z3 = zero, dist
        self.fused_gap_mm = gap
        self.kalman_p = self._vec(self._p0)
        self.kalman_k = zero
        self._kalman_n = zero  # outliers in a row (kalman.gate_mm)
        self._enc_prev = None if encoder_mm is None else self._vec(encoder_mm)
        self.u = u_prev
        self.u0 = self.p_term = self.d_term = self.ff_term = zero
        self.disturbance_term = -(dist / b0)
        self.u_unlimited = u_prev
        self.saturated = self.rate_limited = (zero != zero)

    # ------------------------------------------------------------------ tick
    def step(self, gap_mm, encoder_mm, target_mm, fresh=True):
        """One 0.5 ms tick; return the velocity command in mm/s (+ = up, widens the gap).

        ``encoder_mm`` is the axis position (+ up); only its increment is used, by the
        Kalman filter (ignored when the filter is off; may be None then). ``fresh`` false:
        ``gap_mm`` is not a new sample (the follow controller's encoder prediction), so the
        Kalman filter only predicts. The instance binds this name to :meth:`step_order1` or
        :meth:`step_order2` at construction.
        """
        return self.step_order1(gap_mm, encoder_mm, target_mm, fresh) if self.order == 1 else \
            self.step_order2(gap_mm, encoder_mm, target_mm, fresh)

    def _measure(self, gap_mm, encoder_mm, fresh=True):
        """Gap the observer sees: the reading, or its Kalman fusion with Δenc (notes §4)."""
        if not self.kalman_enabled:
            self.fused_gap_mm = gap_mm
            return gap_mm
        enc_prev = self._enc_prev
        dz = 0.0 if (enc_prev is None or encoder_mm is None) else encoder_mm - enc_prev
        self._enc_prev = encoder_mm
        q, r = self._kalman_qr
        p0, gate, confirm = self._kalman_gate
        y, self.kalman_p, self.kalman_k, self._kalman_n = kalman_gated_step(
            self.ops, self.fused_gap_mm, self.kalman_p, self._kalman_n, gap_mm, dz, fresh,
            q, r, p0, gate, confirm)
        self.fused_gap_mm = y
        return y

    def _track(self, target_mm):
        """Compound TD on the target (``CompELDTUpdate``): TDA, then TDB fed TDA's increment."""
        ops, h = self.ops, self._h
        a1, a2, b1, b2, v_prev = self._td
        na1, na2 = td_step_firmware(ops, a1, a2, target_mm, target_mm - v_prev,
                                    *self._td_a, h)
        nb1, nb2 = td_step_firmware(ops, b1, b2, target_mm, na1 - a1, *self._td_b, h)
        self._td = (na1, na2, nb1, nb2, target_mm)
        self.td_x1, self.td_x2 = nb1, nb2
        self.target_mm = target_mm
        return nb1, nb2, b2

    def _limit(self, u, u_prev):
        """Saturation, then the acceleration limit against the applied previous output."""
        u, self.saturated, self.rate_limited = apply_limits(self.ops, u, u_prev,
                                                            *self._limits)
        self.u = u
        return u

    def step_order1(self, gap_mm, encoder_mm, target_mm, fresh=True):
        """Order-1 tick (seed ``CONTROLLER_ORDER 1``): Kalman, ESO, TD, law, limits."""
        ops, h, b0 = self.ops, self._h, self._b0
        g1, g2, _ = self._gains
        u_prev = self.u
        y = self._measure(gap_mm, encoder_mm, fresh)
        # ESO fed the APPLIED previous output (UpdateLADRC: EsoUpdate(nCtrl, height))
        z1o, z2o = self.z1, self.z2
        if self._g is not None:  # fal-ESO (eso.nonlinear; Euler only)
            z1, z2 = eso1_fal_step(ops, z1o, z2o, y, u_prev, g1, g2, b0, h, self._g,
                                   *self._ext)
        else:
            eso_step = eso1_euler_step if self._euler else eso1_zoh_step
            z1, z2 = eso_step(ops, z1o, z2o, y, u_prev, g1, g2, b0, h, *self._ext)
        self.z1, self.z2 = z1, z2
        if self.compensator:
            # paper eq. 22: measurement and estimate of the same instant
            c1 = self._comp[0]
            if self._euler:
                z1, z2 = compensate1(ops, z1o, z2o, y - z1o, c1)
            else:
                z1, z2 = compensate1(ops, z1, z2, y - z1, c1)
        r, dr, _ = self._track(target_mm)
        kp, _, w_rate, _ = self._law
        if not self.use_td:  # form 2: the raw target, no reference derivative
            r, dr = target_mm, 0.0
        # notes §3.1: u = (kp(r − z1) + w·ṙ − z2) / b0
        self.p_term, self.ff_term, self.u0, u = law_order1(ops, r, dr, z1, z2, kp, b0, w_rate)
        self.u_unlimited = u
        self.disturbance_term = -(z2 / b0)
        return self._limit(u, u_prev)

    def step_order2(self, gap_mm, encoder_mm, target_mm, fresh=True):
        """Order-2 tick: as :meth:`step_order1` with z = (gap, gap rate, disturbance), r̈ = Δṙ/h."""
        ops, h, b0 = self.ops, self._h, self._b0
        g1, g2, g3 = self._gains
        u_prev = self.u
        y = self._measure(gap_mm, encoder_mm, fresh)
        z1o, z2o, z3o = self.z1, self.z2, self.z3
        if self._g is not None:  # fal-ESO (eso.nonlinear; Euler only)
            z1, z2, z3 = eso2_fal_step(ops, z1o, z2o, z3o, y, u_prev, g1, g2, g3, b0, h,
                                       self._g, *self._ext)
        else:
            eso_step = eso2_euler_step if self._euler else eso2_zoh_step
            z1, z2, z3 = eso_step(ops, z1o, z2o, z3o, y, u_prev, g1, g2, g3, b0, h,
                                  *self._ext)
        self.z1, self.z2, self.z3 = z1, z2, z3
        if self.compensator:
            c1, c2 = self._comp
            if self._euler:
                z1, z2, z3 = compensate2(ops, z1o, z2o, z3o, y - z1o, c1, c2)
            else:
                z1, z2, z3 = compensate2(ops, z1, z2, z3, y - z1, c1, c2)
        r, dr, dr_prev = self._track(target_mm)
        ddr = (dr - dr_prev) / h
        self.td_ddr = ddr
        kp, kd, w_rate, w_acc = self._law
        if not self.use_td:
            r, dr, ddr = target_mm, 0.0, 0.0
        # notes §3.1: u = (kp(r − z1) + kd(w·ṙ − z2) + w·r̈ − z3) / b0
        self.p_term, self.d_term, self.ff_term, self.u0, u = law_order2(
            ops, r, dr, ddr, z1, z2, z3, kp, kd, b0, w_rate, w_acc)
        self.u_unlimited = u
        self.disturbance_term = -(z3 / b0)
        return self._limit(u, u_prev)
