"""The linear follow loop in discrete time: the configured controller around the axis model.

Controller (:func:`controller_ss`): its own step function, linearized by probing (the one
implementation, not a second model of it). Holding a zero target with the TD at rest, and with
signals far inside the velocity and acceleration limits, one tick of the LADRC (ESO of order 1
or 2, Euler or ZOH, compensator, Kalman fusion with the encoder) or of the PID is linear in its
states and its two inputs, the gap reading and the encoder position. Stepping it from each
unit state and input, scaled to 1e-6, gives the columns of the state-space matrices of
exactly the arithmetic that runs (paper §4 analyses the continuous ESO; this is the discrete
one of the tick). The Kalman filter enters with its steady-state gain.

Axis (:func:`axis_ss`): ``b0 / (s (T1 s + 1))`` from the velocity command to the nozzle
position, discretized exactly under a zero-order hold as ``ladrc_sim.models.axis`` does it,
``dead_ticks`` whole ticks of command delay, and the sensor's first-order lag ``lag_s`` on the
gap reading (gap = nozzle − sheet). The tick order is the headless runner's: reading at tick k
from the position at k, command k, then the axis moves over the tick.

:func:`analyse` closes the loop (stability from the closed-loop poles) and evaluates on a
frequency grid up to Nyquist: the loop gain L at the axis input, S = 1/(1 + L), T = L/(1 + L),
the sheet-to-nozzle response and the sheet-to-gap response; gain, phase and delay margins,
the peak of |S| (Ms) and the closed-loop bandwidth. Numpy only (no scipy): the follow node's
parameter callback can afford it.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Callable, Sequence

from ladrc_contract.ops import SCALAR
import numpy as np

from ..control.eso import (
    eso1_euler_step,
    eso1_fal_step,
    eso1_zoh_step,
    eso2_euler_step,
    eso2_fal_step,
    eso2_zoh_step,
    fal_alphas,
)
from ..control.ladrc import LADRC, tick_constants
from ..control.params import ControllerParams
from ..control.pid import FollowPID

EPS = 1e-6
"""Probe size: far inside every limit (a_max·h is 2.5 mm/s per tick at the defaults)."""


@dataclass
class StateSpace:
    """x[k+1] = A x[k] + B w[k];  out[k] = C x[k] + D w[k]  (sample time ``h_s``).

    ``delay_ticks``: input 0 reaches B only that many ticks late (a dead time, kept out of
    the state so a long one costs nothing in :meth:`response`; :meth:`with_delay_states`
    writes it as a delay line for the closed loop's poles).
    """

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    h_s: float
    delay_ticks: int = 0

    def response(self, f_hz: np.ndarray) -> np.ndarray:
        """Frequency response at ``f_hz``: array (n_f, n_out, n_in), z = exp(j 2π f h)."""
        z = np.exp(2j * np.pi * np.asarray(f_hz, dtype=float) * self.h_s)
        n = self.a.shape[0]
        if n == 0:
            out = np.broadcast_to(self.d.astype(complex), (z.size,) + self.d.shape).copy()
        else:
            m = z[:, None, None] * np.eye(n) - self.a
            x = np.linalg.solve(m, np.broadcast_to(self.b.astype(complex),
                                                   (z.size,) + self.b.shape))
            out = self.c @ x + self.d
        if self.delay_ticks:
            out[:, :, 0] *= z[:, None] ** (-self.delay_ticks)
        return out

    def inputs(self, keep: Sequence[int]) -> StateSpace:
        """Return the system seen from the inputs ``keep`` only (states they miss pruned)."""
        a, b, c, d = _prune(self.a, self.b[:, list(keep)], self.c, self.d[:, list(keep)])
        return StateSpace(a, b, c, d, self.h_s,
                          self.delay_ticks if 0 in keep else 0)

    def with_delay_states(self) -> StateSpace:
        """Return the same system with the dead time as a delay line of states."""
        nd = self.delay_ticks
        if not nd:
            return self
        n, m = self.a.shape[0], self.b.shape[1]
        a = np.zeros((n + nd, n + nd))
        b = np.zeros((n + nd, m))
        a[:n, :n] = self.a
        a[:n, n + nd - 1] = self.b[:, 0]  # the oldest command in the line drives the plant
        b[:n, 1:] = self.b[:, 1:]
        b[n, 0] = 1.0
        for i in range(n, n + nd - 1):
            a[i + 1, i] = 1.0
        c = np.hstack([self.c, np.zeros((self.c.shape[0], nd))])
        if np.any(self.d[:, 0] != 0.0):
            raise ValueError('a delayed input with a direct feedthrough')
        return StateSpace(a, b, c, self.d.copy(), self.h_s)


def _linearize(get: Callable[[], np.ndarray], put: Callable[[np.ndarray], None],
               step: Callable[[np.ndarray], float], n_in: int,
               out_index: int) -> tuple[np.ndarray, ...]:
    """State-space of a linear tick by probing each state and input with :data:`EPS`.

    ``get``/``put`` read and write the state vector, ``step(inputs)`` runs one tick and
    ``out_index`` is the state that holds the tick's output (the applied command).
    """
    n = get().size
    put(np.zeros(n))
    step(np.zeros(n_in))
    base = get()
    if np.any(np.abs(base) > 1e-12):
        raise ValueError('the controller does not rest at zero: not linearizable here')
    cols_x, cols_w = [], []
    for i in range(n):
        x0 = np.zeros(n)
        x0[i] = EPS
        put(x0)
        step(np.zeros(n_in))
        cols_x.append(get() / EPS)
    for j in range(n_in):
        w = np.zeros(n_in)
        w[j] = EPS
        put(np.zeros(n))
        step(w)
        cols_w.append(get() / EPS)
    a = np.column_stack(cols_x)
    b = np.column_stack(cols_w)
    # the output is the applied command, which is also the state out_index after the tick
    c = a[out_index:out_index + 1, :].copy()
    d = b[out_index:out_index + 1, :].copy()
    return _prune(a, b, c, d)


def _prune(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray
           ) -> tuple[np.ndarray, ...]:
    """Drop states that influence nothing, or that nothing drives (held values).

    E.g. the Kalman states with the filter off, or the PID's integrator with ki = 0: they
    would put closed-loop poles at z = 1 that no signal reaches or leaves.
    """
    tol = 1e-12
    while a.shape[0]:
        n = a.shape[0]
        off = ~np.eye(n, dtype=bool)
        dead = [j for j in range(n)
                if (np.all(np.abs(a[:, j][off[:, j]]) <= tol) and np.all(np.abs(c[:, j]) <= tol))
                or (np.all(np.abs(a[j, :][off[j, :]]) <= tol) and np.all(np.abs(b[j, :]) <= tol))]
        if not dead:
            break
        keep = [j for j in range(n) if j not in dead]
        a, b, c = a[np.ix_(keep, keep)], b[keep, :], c[:, keep]
    return a, b, c, d


def controller_ss(params: ControllerParams, mode: str | None = None) -> StateSpace:
    """Linearize the controller: inputs (gap reading, encoder, target) -> command.

    ``mode`` 'ladrc' (default: ``follow.controller``) or 'pid' (feed-forward on, as once
    followed; suppression off: its deadband has no small-signal gain). The target enters
    through the compound TD (LADRC) or the reference filter (PID), whose states are part of
    the model; they do not take part in the feedback loop.
    """
    mode = mode or params.follow.controller
    h = params.h_s
    n_td = 5  # the compound TD's state (a1, a2, b1, b2, v_prev), ladrc.py ``_track``
    if mode == 'ladrc':
        # the set was validated where it was loaded: build without checking it again
        c = LADRC(params, _consts=tick_constants(params), _ops=SCALAR)
        names = ['z1', 'z2'] + (['z3'] if c.order == 2 else []) + ['u', 'fused_gap_mm']
        p_ss = params.kalman.p0_mm2
        if c.kalman_enabled:  # the steady-state covariance: the gain the filter settles to
            for _ in range(100_000):
                pp = p_ss + params.kalman.q_mm2
                p_new = (1.0 - pp / (pp + params.kalman.r_mm2)) * pp
                if abs(p_new - p_ss) <= 1e-15 * max(p_ss, 1e-300):
                    break
                p_ss = p_new

        def get() -> np.ndarray:
            return np.array([float(getattr(c, k)) for k in names] + [c._enc_prev or 0.0]
                            + [float(v) for v in c._td])

        def put(x: np.ndarray) -> None:
            for k, v in zip(names, x, strict=False):
                setattr(c, k, float(v))
            c._enc_prev = float(x[len(names)])
            c.kalman_p = p_ss
            c._td = tuple(float(v) for v in x[len(names) + 1:len(names) + 1 + n_td])

        def step(w: np.ndarray) -> float:
            return c.step(float(w[0]), float(w[1]), float(w[2]))

        a, b, cc, d = _linearize(get, put, step, 3, names.index('u'))
    elif mode == 'pid':
        pid = FollowPID(params.pid, h)
        pid.reset(0.0, 0.0, 0.0, 0.0)
        pid.enable_feed_forward(True)
        pid._ff_count = 10**9
        names = ['_gap_prev', '_surface_prev', 'gap_rate_mm_s', 'surface_rate_mm_s',
                 'i_term', 'u', '_target_prev', 'ref_rate_mm_s']

        def get() -> np.ndarray:
            return np.array([float(getattr(pid, k)) for k in names])

        def put(x: np.ndarray) -> None:
            for k, v in zip(names, x, strict=True):
                setattr(pid, k, float(v))

        def step(w: np.ndarray) -> float:
            return pid.step(float(w[0]), float(w[1]), float(w[2]))

        a, b, cc, d = _linearize(get, put, step, 3, names.index('u'))
    else:
        raise ValueError(f'unknown controller mode {mode!r}: ladrc or pid')
    return StateSpace(a, b, cc, d, h)


@dataclass(frozen=True)
class AxisModel:
    """The plant the loop is analysed against (defaults: the simulator's axis and sensor)."""

    b0: float = 1.0            # mm/s of axis velocity per mm/s of command
    t1_s: float = 0.008        # velocity-loop time constant
    dead_ticks: int = 0        # whole ticks of command delay
    lag_s: float = 0.0         # sensor first-order lag


def axis_ss(m: AxisModel, h_s: float) -> StateSpace:
    """Axis + sensor: inputs (command, sheet), outputs (reading, encoder, nozzle).

    States: velocity, position, the sensor filter's last output; the dead time is the
    command input's ``delay_ticks``.
    """
    a_ = math.exp(-h_s / m.t1_s)
    lag = m.lag_s > 0.0
    n = 3 if lag else 2
    A = np.zeros((n, n))
    B = np.zeros((n, 2))
    # velocity, position (models/axis.py, exact under a zero-order hold)
    A[0, 0] = a_
    A[1, 0] = m.t1_s * (1.0 - a_)
    A[1, 1] = 1.0
    B[0, 0] = (1.0 - a_) * m.b0
    B[1, 0] = m.b0 * (h_s - m.t1_s * (1.0 - a_))
    C = np.zeros((3, n))
    D = np.zeros((3, 2))
    alpha = math.exp(-h_s / m.lag_s) if lag else 0.0
    # reading = α·y_prev + (1 − α)(x − sheet); the filter state takes the reading
    C[0, 1], D[0, 1] = 1.0 - alpha, -(1.0 - alpha)
    if lag:
        C[0, 2] = alpha
        A[2, :] = C[0, :]
        B[2, :] = D[0, :]
    C[1, 1] = 1.0  # encoder
    C[2, 1] = 1.0  # nozzle
    return StateSpace(A, B, C, D, h_s, delay_ticks=int(m.dead_ticks))


@dataclass
class LoopAnalysis:
    """Responses on ``f_hz`` and the loop's figures (margins in dB, degrees, ms)."""

    f_hz: np.ndarray
    loop: np.ndarray           # L at the axis input (return ratio)
    sensitivity: np.ndarray    # S = 1/(1 + L)
    complementary: np.ndarray  # T = L/(1 + L)
    sheet_to_nozzle: np.ndarray
    sheet_to_gap: np.ndarray
    reference_to_gap: np.ndarray  # target -> gap through the TD (or the PID's filter)
    reference_bandwidth_hz: float
    stable: bool
    spectral_radius: float
    gain_margin_db: float
    gain_margin_hz: float
    lower_gain_margin_db: float
    phase_margin_deg: float
    crossover_hz: float
    delay_margin_ms: float
    ms_peak: float
    ms_hz: float
    bandwidth_hz: float

    def figures(self) -> dict[str, Any]:
        """Return the scalar figures (JSON-friendly)."""
        keys = ('stable', 'spectral_radius', 'gain_margin_db', 'gain_margin_hz',
                'lower_gain_margin_db', 'phase_margin_deg', 'crossover_hz', 'delay_margin_ms',
                'ms_peak', 'ms_hz', 'bandwidth_hz', 'reference_bandwidth_hz')
        return {k: getattr(self, k) for k in keys}


def frequency_grid(h_s: float, n: int = 4000, f_min_hz: float = 0.01) -> np.ndarray:
    """Log-spaced frequencies from ``f_min_hz`` to just below Nyquist."""
    return np.geomspace(f_min_hz, 0.4999 / h_s, n)


def _bandwidth(f: np.ndarray, resp: np.ndarray) -> float:
    """Return the first frequency where ``|resp|`` falls below −3 dB (NaN if never)."""
    below = np.flatnonzero(np.abs(resp) < 1 / math.sqrt(2))
    return float(f[below[0]]) if below.size else math.nan


def _crossings(x: np.ndarray) -> np.ndarray:
    """Return the indices i where ``x`` changes sign between i and i + 1."""
    s = np.sign(x)
    return np.flatnonzero(s[:-1] * s[1:] < 0)


def _at(i: int, x: np.ndarray, f: np.ndarray, *ys: np.ndarray) -> list[float]:
    """Linear interpolation of ``ys`` (and f, in log) where ``x`` crosses zero in [i, i+1]."""
    w = x[i] / (x[i] - x[i + 1])
    out = [float(np.exp(np.log(f[i]) + w * (np.log(f[i + 1]) - np.log(f[i]))))]
    out += [float(y[i] + w * (y[i + 1] - y[i])) for y in ys]
    return out


def analyse(ctrl: StateSpace, plant: StateSpace, f_hz: Sequence[float] | None = None
            ) -> LoopAnalysis:
    """Close ``ctrl`` (reading, encoder -> command) around ``plant`` (:func:`axis_ss` layout).

    Margins are read off L on the grid (crossings interpolated): the phase margin at the
    gain crossover with the least margin, the delay margin min(PM_i / ω_i) over the gain
    crossovers, the (upper) gain margin at the phase crossovers where |L| < 1 and the lower
    one where |L| > 1 (how far the gain may fall; NaN when there is none).
    """
    h = ctrl.h_s
    f = frequency_grid(h) if f_hz is None else np.asarray(f_hz, dtype=float)
    fb = ctrl.inputs((0, 1))  # the feedback part: reading, encoder (the TD is outside it)
    # closed-loop poles: u = Cc xc + Dc Cp xp (reading, encoder), the dead time as states
    full = plant.with_delay_states()
    ap, bp, cp = full.a, full.b, full.c
    ac, bc, cc, dc = fb.a, fb.b, fb.c, fb.d
    cpy, bpu = cp[:2], bp[:, 0:1]
    a_cl = np.block([[ap + bpu @ dc @ cpy, bpu @ cc], [bc @ cpy, ac]])
    rho = float(np.max(np.abs(np.linalg.eigvals(a_cl)))) if a_cl.size else 0.0
    # loop gain at the axis input: L = −K·G; the sheet reaches the loop through the reading
    pr = plant.response(f)                                                  # (n_f, 3, 2)
    g, g_sheet, g_noz = pr[:, :2, 0], pr[:, :2, 1], pr[:, 2, 0]
    kall = ctrl.response(f)[:, 0, :]                          # (n_f, 3): reading, enc, target
    k = kall[:, :2]
    k_ref = kall[:, 2] if kall.shape[1] > 2 else np.full(f.size, np.nan)  # no target input
    loop = -np.sum(k * g, axis=1)
    sens = 1.0 / (1.0 + loop)
    comp = loop / (1.0 + loop)
    # u = K (G u + G_s s)  =>  u = K G_s s / (1 + L);  nozzle = G_x u
    noz = g_noz * np.sum(k * g_sheet, axis=1) * sens
    # the reference path, TD included: u = K_r r / (1 + L); the gap = nozzle (sheet still)
    ref = g_noz * k_ref * sens
    mag = np.abs(loop)
    # gain crossovers: |L| = 1
    pm, wc, dm = math.inf, math.nan, math.inf
    pm_rad = np.angle(-loop)
    for i in _crossings(np.log(mag)):
        fc, phi = _at(i, np.log(mag), f, pm_rad)
        if math.degrees(phi) < pm:
            pm, wc = math.degrees(phi), fc
        if phi > 0:
            dm = min(dm, phi / (2 * math.pi * fc))
        else:
            dm = 0.0
    # phase crossovers: L on the negative real axis
    gm_up, f_gm, gm_low = math.inf, math.nan, math.nan
    for i in _crossings(loop.imag):
        fx, re = _at(i, loop.imag, f, loop.real)
        if re >= 0:
            continue
        gm = -20 * math.log10(-re)
        if -re < 1.0 and gm < gm_up:
            gm_up, f_gm = gm, fx
        elif -re >= 1.0:
            gm_low = gm if math.isnan(gm_low) else max(gm_low, gm)
    i_ms = int(np.argmax(np.abs(sens)))
    bw = _bandwidth(f, comp)
    return LoopAnalysis(
        f_hz=f, loop=loop, sensitivity=sens, complementary=comp, sheet_to_nozzle=noz,
        sheet_to_gap=noz - 1.0, reference_to_gap=ref,
        reference_bandwidth_hz=_bandwidth(f, ref), stable=rho < 1.0, spectral_radius=rho,
        gain_margin_db=gm_up, gain_margin_hz=f_gm, lower_gain_margin_db=gm_low,
        phase_margin_deg=pm if math.isfinite(pm) else math.nan, crossover_hz=wc,
        delay_margin_ms=dm * 1e3 if math.isfinite(dm) else math.nan,
        ms_peak=float(np.abs(sens[i_ms])), ms_hz=float(f[i_ms]), bandwidth_hz=bw)


def analyse_params(params: ControllerParams, axis: AxisModel | None = None,
                   mode: str | None = None, f_hz: Sequence[float] | None = None
                   ) -> LoopAnalysis:
    """:func:`analyse` of a parameter set against ``axis`` (default: the simulator's)."""
    return analyse(controller_ss(params, mode), axis_ss(axis or AxisModel(), params.h_s), f_hz)


@dataclass
class ObserverAnalysis:
    """The ESO alone estimating the total disturbance f of its own model (paper §4).

    ``disturbance_estimate``: ẑ_ext / f on ``f_hz`` (order 1: y' = f + b0·u, f in mm/s;
    order 2: y'' = f + b0·u, f in mm/s²); ``error_poles_hz``: the natural frequencies
    |ln λ|/(2π h) of the error dynamics' eigenvalues λ; ``bandwidth_hz``: where |ẑ/f| falls
    to −3 dB.
    """

    f_hz: np.ndarray
    disturbance_estimate: np.ndarray
    error_poles_hz: list[float]
    error_spectral_radius: float
    bandwidth_hz: float

    def figures(self) -> dict[str, Any]:
        """Return the scalar figures (JSON-friendly)."""
        return {'eso_bandwidth_hz': self.bandwidth_hz,
                'eso_error_poles_hz': self.error_poles_hz,
                'eso_error_spectral_radius': self.error_spectral_radius}


def observer_ss(params: ControllerParams) -> StateSpace:
    """Linearize the ESO's tick (as the LADRC runs it) on its own model: f -> ẑ_ext.

    The plant is the ESO's model with u = 0, exact under a hold: y' = f (order 1) or
    y'' = f (order 2); the observer is the LADRC's step function with its gains.
    """
    c = LADRC(params, _consts=tick_constants(params), _ops=SCALAR)
    n, h = c.order, params.h_s
    if c._g is not None:  # the fal-ESO: probed inside its linear zone (eso.fal_delta_mm)
        step_fn = eso1_fal_step if n == 1 else eso2_fal_step

        def eso(ops, *a):
            return step_fn(ops, *a[:-2], c._g, *a[-2:])
    elif n == 1:
        eso = eso1_euler_step if c._euler else eso1_zoh_step
    else:
        eso = eso2_euler_step if c._euler else eso2_zoh_step
    gains = c._gains[:n + 1]
    state = np.zeros(n + 1 + n)  # z1..z_{n+1}, then y (and y' for order 2)

    def get() -> np.ndarray:
        return state.copy()

    def put(x: np.ndarray) -> None:
        state[:] = x

    def step(w: np.ndarray) -> float:
        z, y = state[:n + 1], state[n + 1:]
        state[:n + 1] = eso(SCALAR, *z.tolist(), float(y[0]), 0.0, *gains, c._b0, h, *c._ext)
        f = float(w[0])
        if n == 1:
            state[n + 1] = y[0] + h * f
        else:
            state[n + 1:] = (y[0] + h * y[1] + 0.5 * h * h * f, y[1] + h * f)
        return float(state[n])

    a, b, cc, d = _linearize(get, put, step, 1, n)
    return StateSpace(a, b, cc, d, h)


def analyse_observer(params: ControllerParams, f_hz: Sequence[float] | None = None
                     ) -> ObserverAnalysis:
    """Disturbance-estimation response and error dynamics of the set's ESO."""
    from .observers import LinearESO

    h = params.h_s
    f = frequency_grid(h) if f_hz is None else np.asarray(f_hz, dtype=float)
    resp = observer_ss(params).response(f)[:, 0, 0]
    e = params.eso
    c = LADRC(params, _consts=tick_constants(params), _ops=SCALAR)
    gains = c._gains[:e.order + 1]
    if e.nonlinear != 'off':  # the fal-ESO's linear zone: gains β_i·δ^(α_i − 1)
        gains = tuple(g * e.fal_delta_mm ** (a - 1.0) for g, a in
                      zip(gains, fal_alphas(e.order, e.nonlinear, e.fal_alpha), strict=True))
    if e.discretization == 'euler':
        err = LinearESO(e.order, e.b0, h, betas=gains).discrete_error_matrix()
    else:  # the ZOH current estimator's error matrix (I − L C) Φ with the tick's gains
        m = LinearESO(e.order, e.b0, h, w0_rad_s=1.0, discretization='zoh')
        err = (np.eye(e.order + 1) - np.outer(np.asarray(gains), m.C)) @ m.phi
    lam = np.linalg.eigvals(err)
    poles = sorted(float(abs(np.log(v)) / (2 * math.pi * h)) if v != 0 else math.inf
                   for v in lam)
    return ObserverAnalysis(f, resp, poles, float(np.max(np.abs(lam))), _bandwidth(f, resp))


def td_ss(params: ControllerParams) -> StateSpace:
    """Linearize the compound TD of the tick (``LADRC._track``): target -> r (TDB's x1).

    Linear by construction (notes §2.1); probing gives its discrete form exactly as it runs.
    """
    c = LADRC(params, _consts=tick_constants(params), _ops=SCALAR)

    def get() -> np.ndarray:
        return np.array([float(v) for v in c._td])

    def put(x: np.ndarray) -> None:
        c._td = tuple(float(v) for v in x)

    def step(w: np.ndarray) -> float:
        return c._track(float(w[0]))[0]

    a, b, cc, d = _linearize(get, put, step, 1, 2)  # state 2 = b1 = r after the tick
    return StateSpace(a, b, cc, d, params.h_s)
