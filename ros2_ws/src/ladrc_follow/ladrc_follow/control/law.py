"""LADRC control laws (notes §3.1 "控制律") and the output limits of ``UpdateLADRC``.

The ESO turns the plant into a chain of integrators by cancelling the total
disturbance: u = (u0 − z_{n+1}) / b0 (notes §3.1, ``u(k) = (u0 − x_{n+1}(k))/b0``).
The virtual control u0 is one of the notes' three forms:

========  =====================================================  ============================
form      order 2 (z1 gap, z2 gap rate, z3 disturbance)          order 1 (z1 gap, z2 dist.)
========  =====================================================  ============================
1         u0 = kp(r − z1) + kd(ṙ − z2)          (TD r, ṙ)        u0 = kp(r − z1)
2         u0 = kp(v − z1) − kd·z2               (raw target v)   u0 = kp(v − z1)
3         u0 = kp(r − z1) + kd(ṙ − z2) + r̈     (seed, current)  u0 = kp(r − z1) + ṙ
========  =====================================================  ============================

Form 3 adds the reference's highest derivative the plant model integrates as a
feed-forward: r̈ for the order-2 model (input ≈ acceleration), ṙ for the order-1
model (input = velocity). The seed's firmware (``CONTROLLER_ORDER 1``) runs
``u0 = KP·(track − x1)/10 + diff``, i.e. form 3 of the order-1 model with
kp = KP/10 = 10 /s. Form 2 regulates on the raw target without TD derivatives.

A form is reduced to weights on the reference derivatives (:func:`form_weights`)
so one arithmetic expression serves all forms, and a batch of controllers with
different forms still runs one code path.

Limits (``UpdateLADRC``): output saturation to ±v_max, then a per-tick change
limit |u(k) − u(k−1)| ≤ a_max·h against the previously APPLIED output. The seed
saturates only the downward direction (``if (_nCtrlUnitV < 0 && ...)``); this
implementation saturates both ways (a symmetric drive limit), documented in
docs/control-law.md.
"""

from __future__ import annotations


def form_weights(form: int, order: int) -> tuple[bool, float, float]:
    """Return ``(use_td, w_rate, w_acc)`` for law ``form`` of plant model ``order``.

    ``use_td``: the reference r is the TD output (True) or the raw target (False,
    form 2). ``w_rate`` multiplies ṙ: for order 2 inside ``kd(w_rate·ṙ − z2)``, for
    order 1 as the feed-forward ``+ w_rate·ṙ``. ``w_acc`` multiplies the r̈
    feed-forward (order 2 only).
    """
    if order not in (1, 2):
        raise ValueError(f'order must be 1 or 2 (plant model order), got {order!r}')
    if form == 1:
        return True, (1.0 if order == 2 else 0.0), 0.0
    if form == 2:
        return False, 0.0, 0.0
    if form == 3:
        return True, 1.0, (1.0 if order == 2 else 0.0)
    raise ValueError(f'law form must be 1, 2 or 3 (notes §3.1), got {form!r}')


def gains_from_bandwidth(order: int, wc_rad_s: float) -> tuple[float, float]:
    """Return ``(kp, kd)`` placing all closed-loop poles at −ωc.

    Order 1: s + kp → kp = ωc (kd unused, returned 0). Order 2: s² + kd·s + kp =
    (s + ωc)² → kp = ωc², kd = 2ωc.
    """
    if not wc_rad_s > 0.0:
        raise ValueError(f'controller bandwidth wc_rad_s must be > 0, got {wc_rad_s!r}')
    if order == 1:
        return float(wc_rad_s), 0.0
    if order == 2:
        return float(wc_rad_s) ** 2, 2.0 * float(wc_rad_s)
    raise ValueError(f'order must be 1 or 2 (plant model order), got {order!r}')


def law_order1(ops, r, dr, z1, z2, kp, b0, w_rate):
    """Order-1 LADRC law; returns ``(p_term, ff_term, u0, u)``.

    u0 = kp(r − z1) + w_rate·ṙ; u = (u0 − z2)/b0 (notes §3.1, ``UpdateLADRC``).
    ``z2`` is the ESO's total-disturbance estimate in mm/s.
    """
    p = kp * (r - z1)
    ff = w_rate * dr
    u0 = p + ff
    return p, ff, u0, (u0 - z2) / b0


def law_order2(ops, r, dr, ddr, z1, z2, z3, kp, kd, b0, w_rate, w_acc):
    """Order-2 LADRC law; returns ``(p_term, d_term, ff_term, u0, u)``.

    u0 = kp(r − z1) + kd(w_rate·ṙ − z2) + w_acc·r̈; u = (u0 − z3)/b0 (notes §3.1).
    """
    p = kp * (r - z1)
    d = kd * (w_rate * dr - z2)
    ff = w_acc * ddr
    u0 = p + d + ff
    return p, d, ff, u0, (u0 - z3) / b0


def apply_limits(ops, u, u_prev, v_max, du_max):
    """Saturate to ±v_max, then limit the change per tick to ±du_max (= a_max·h).

    Returns ``(u_applied, saturated, rate_limited)``: the flags tell which limit
    was active this tick (booleans, or boolean arrays on the batch path). The
    order follows ``UpdateLADRC``: saturation first, then the acceleration limit
    relative to the previously applied output ``u_prev``. With ``|u_prev| ≤ v_max``
    the result stays within ±v_max.
    """
    u_sat = ops.clip(u, -v_max, v_max)
    saturated = u_sat != u
    lo = u_prev - du_max
    hi = u_prev + du_max
    u_out = ops.clip(u_sat, lo, hi)
    return u_out, saturated, u_out != u_sat
