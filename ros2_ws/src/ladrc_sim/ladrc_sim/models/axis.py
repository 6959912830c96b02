"""Z axis in velocity mode: command (mm/s) -> drive -> nozzle position (mm).

Two plant models (notes §1):

* ``first_order`` (notes §1.1, mechanism): ``G(s) = b0 / (s (T1 s + 1))`` from the velocity
  command to the position: a first-order velocity loop with time constant ``T1`` followed by
  an integrator. It is discretised exactly under a zero-order-hold command (the tick is the
  step, no sub-steps needed): with ``a = exp(-h/T1)``

      v[k+1] = a v[k] + (1 - a) b0 u[k]
      x[k+1] = x[k] + T1 (1 - a) v[k] + b0 u[k] (h - T1 (1 - a))

  The drive's velocity limit clips the command (``|b0 u| <= v_max``) and its acceleration
  limit clips the velocity change per tick (``|dv| <= a_max h``); in a clipped tick the
  position integrates the constant acceleration exactly (trapezoid).
* ``identified`` (notes §1.2, system identification):
  ``G(s) = (16.75 s - 0.2331) / (s^2 + 0.3274 s + 0.06028)``, turned into a state space with
  ``scipy.signal.tf2ss`` and discretised with ``cont2discrete`` (ZOH) at the tick. Units are
  not stated in the notes; we assume time in s, output position in mm and an input in the
  firmware's velocity unit, and scale the command by ``identified_gain`` (default 1/16.75)
  so that the model's high-frequency gain (``16.75/s``) equals ``b0 = 1`` mm/s per mm/s, i.e.
  it agrees with the mechanistic model above its poles (~0.04 Hz). Its DC behaviour (finite
  gain, a right-half-plane zero at 0.014 rad/s) differs from the integrating model, so it is
  only meaningful over seconds, as the identification was. No acceleration limit applies to
  it; the command is clipped to ``+-v_max``. The four coefficients are parameters
  (``identified_n1, n0, d1, d0``, defaults the notes' values) so that a run can sit at an end
  of the notes' intervals; units and intervals: docs/identification.md.

A drive that is disabled or faulted ignores the command and decelerates to a stop at
``a_max`` (the identified model simply freezes). An optional dead time delays the command by
whole ticks before the drive sees it.

Defaults for a laser-head Z axis: ``T1 = 8 ms`` (a stiff servo velocity loop, 20 Hz
bandwidth), ``b0 = 1`` (the drive tracks mm/s in mm/s), ``v_max = 200 mm/s``,
``a_max = 5000 mm/s^2`` (about 0.5 g, typical for a light cutting head).

This module also holds the small range-check helper the other model parameter classes use.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from math import isnan
from typing import Any, NamedTuple

from ladrc_contract.ops import SCALAR
from ladrc_contract.schema import first_problem, param
import numpy as np
from scipy import signal

H_S = 0.0005  # the controller tick, 2 kHz (seed SAMPLE_PERIOD 2000)

# notes §1.2, identified transfer function (numerator, denominator in s).
IDENTIFIED_NUM = (16.75, -0.2331)
IDENTIFIED_DEN = (1.0, 0.3274, 0.06028)


class ParamError(ValueError):
    """A model parameter is out of range; ``key`` names the field."""

    def __init__(self, key: str, message: str):
        super().__init__(f'{key}: {message}')
        self.key = key
        self.reason = message


def check_fields(obj: Any) -> None:
    """Raise :class:`ParamError` for the first field of ``obj`` outside its declaration.

    The declarations are the contract's schema (``ladrc_contract.schema.param``), as the
    controller's parameters; None marks an optional value.
    """
    problem = first_problem(obj)
    if problem is not None:
        raise ParamError(*problem)


@dataclass(frozen=True)
class AxisParams:
    """Parameters of the Z drive (see the module docstring for the defaults' rationale)."""

    model: str = param('first_order', choices=('first_order', 'identified'))
    b0: float = param(1.0, '', 'plant gain, mm/s of axis speed per mm/s of command', gt=0.0)
    t1_s: float = param(0.008, '', 'velocity-loop time constant T1', gt=0.0)
    v_max_mm_s: float = param(200.0, gt=0.0)
    a_max_mm_s2: float = param(5000.0, gt=0.0)
    dead_time_ticks: int = param(0, '', 'whole ticks of command delay', ge=0, le=1000)
    identified_gain: float = param(1.0 / 16.75, '', 'command scale into the §1.2 model', gt=0.0)
    # notes §1.2 coefficients, (n1 s + n0) / (s^2 + d1 s + d0); the notes' +/- (one standard
    # deviation) lets a run sit at an interval end (docs/identification.md)
    identified_n1: float = param(IDENTIFIED_NUM[0], '', '§1.2 numerator s term, +/-0.2556', gt=0.0)
    identified_n0: float = param(IDENTIFIED_NUM[1], '', '§1.2 numerator constant, +/-1.816')
    identified_d1: float = param(IDENTIFIED_DEN[1], '', '§1.2 denominator s term, +/-0.1804')
    identified_d0: float = param(IDENTIFIED_DEN[2], '', '§1.2 denominator constant, +/-0.3627')

    def __post_init__(self) -> None:
        check_fields(self)


class FirstOrder(NamedTuple):
    """The first-order axis at tick ``h``: exact ZOH of b0/(s(T1 s + 1)) (notes §1.1), limits."""

    a: float       # exp(-h/T1)
    kv: float      # (1 - a) b0: velocity per command
    kxv: float     # T1 (1 - a): position per velocity
    kxu: float     # b0 (h - T1 (1 - a)): position per command
    u_max: float   # the command that reaches v_max
    dv_max: float  # a_max h: the largest velocity step of a tick
    half_h: float  # h/2: position over a tick at a constant acceleration


def first_order(params: AxisParams, h_s: float) -> FirstOrder:
    """Return the first-order axis of ``params`` discretised at ``h_s`` (notes §1.1)."""
    a = math.exp(-h_s / params.t1_s)
    return FirstOrder(a, (1.0 - a) * params.b0, params.t1_s * (1.0 - a),
                      params.b0 * (h_s - params.t1_s * (1.0 - a)),
                      params.v_max_mm_s / params.b0, params.a_max_mm_s2 * h_s, 0.5 * h_s)


def first_order_step(ops: Any, c: FirstOrder, x_mm: Any, v_mm_s: Any, u_mm_s: Any
                     ) -> tuple[Any, Any]:
    """One tick of the enabled first-order axis, scalar or N rows (``ops``): ``(x, v)`` after.

    The command is clipped to ±u_max (NaN fails every comparison: treated as no command rather
    than poisoning the state); a velocity step beyond a_max·h is cut to it, the position then
    moving at that constant acceleration over the tick.
    """
    u = ops.where(u_mm_s > c.u_max, c.u_max,
                  ops.where(u_mm_s < -c.u_max, -c.u_max, ops.where(u_mm_s == u_mm_s, u_mm_s, 0.0)))
    v1 = c.a * v_mm_s + c.kv * u
    dv = v1 - v_mm_s
    inside = (-c.dv_max <= dv) & (dv <= c.dv_max)
    v_lim = v_mm_s + ops.where(dv > 0.0, c.dv_max, -c.dv_max)
    return (ops.where(inside, x_mm + c.kxv * v_mm_s + c.kxu * u,
                      x_mm + c.half_h * (v_mm_s + v_lim)),
            ops.where(inside, v1, v_lim))


class Axis:
    """The simulated Z axis; ``step`` advances one tick of ``h_s``."""

    def __init__(self, params: AxisParams, position_mm: float = 0.0, h_s: float = H_S):
        if not h_s > 0.0:
            raise ValueError(f'h_s = {h_s}: the tick must be > 0 s')
        self.params = params
        self.h_s = float(h_s)
        self.position_mm = float(position_mm)
        self.velocity_mm_s = 0.0
        self._identified = params.model == 'identified'
        h = self.h_s
        self.first_order = first_order(params, h)  # notes §1.1
        self._buf = [0.0] * params.dead_time_ticks
        self._k = 0
        if self._identified:
            # notes §1.2, ZOH state space of the identified model.
            a_c, b_c, c_c, d_c = signal.tf2ss(
                (params.identified_n1, params.identified_n0),
                (1.0, params.identified_d1, params.identified_d0))
            ad, bd, cd, dd, _ = signal.cont2discrete((a_c, b_c, c_c, d_c), h, method='zoh')
            self._ad = [[float(v) for v in row] for row in ad]
            self._bd = [float(v) for v in np.ravel(bd)]
            self._cd = [float(v) for v in np.ravel(cd)]
            self._dd = float(np.ravel(dd)[0])
            self._x = [0.0, 0.0]
            self._y0 = self.position_mm

    def step(self, cmd_mm_s: float, enabled: bool = True, fault: bool = False
             ) -> tuple[float, float]:
        """Apply ``cmd_mm_s`` for one tick; return ``(position_mm, velocity_mm_s)`` after it."""
        if self._buf:
            buf = self._buf
            k = self._k
            u = buf[k]
            buf[k] = cmd_mm_s
            self._k = k + 1 if k + 1 < len(buf) else 0
        else:
            u = cmd_mm_s
        if self._identified:
            return self._step_identified(u if not isnan(u) else 0.0, enabled and not fault)
        v = self.velocity_mm_s
        if enabled and not fault:
            x1, v1 = first_order_step(SCALAR, self.first_order, self.position_mm, v, u)
        else:
            # a disabled drive brakes to a stop at a_max (module docstring).
            dv_max = self.first_order.dv_max
            v1 = v - dv_max if v > dv_max else (v + dv_max if v < -dv_max else 0.0)
            x1 = self.position_mm + self.first_order.half_h * (v + v1)
        self.position_mm = x1
        self.velocity_mm_s = v1
        return x1, v1

    def _step_identified(self, u: float, active: bool) -> tuple[float, float]:
        if not active:
            self.velocity_mm_s = 0.0
            return self.position_mm, 0.0
        vmax = self.params.v_max_mm_s
        u = (vmax if u > vmax else (-vmax if u < -vmax else u)) * self.params.identified_gain
        x0, x1 = self._x
        ad, bd, cd = self._ad, self._bd, self._cd
        n0 = ad[0][0] * x0 + ad[0][1] * x1 + bd[0] * u
        n1 = ad[1][0] * x0 + ad[1][1] * x1 + bd[1] * u
        self._x = [n0, n1]
        # the output is sampled at the end of the tick (direct term uses the held input).
        y = self._y0 + cd[0] * n0 + cd[1] * n1 + self._dd * u
        v = (y - self.position_mm) / self.h_s
        self.position_mm = y
        self.velocity_mm_s = v
        return y, v
