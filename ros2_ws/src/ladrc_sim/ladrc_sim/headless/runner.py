"""Headless closed-loop runner: any controller against the models at 2 kHz, no ROS.

The controller is duck-typed (:class:`Controller`):

* ``controller.step(tick: TickInput) -> float`` returns the velocity command (mm/s,
  positive up). ``tick`` carries the latest samples and their sample times; the runner
  passes fresh samples every tick unless a ``sensor_dropout`` / ``encoder_dropout`` event
  holds them (then the stamps stop advancing and the controller sees the input age);
* ``controller.command(name, **kwargs)`` receives the scenario's follow commands
  (``start_follow``, ``set_target``, ``stop_follow``, ``reset_fault``, ``machining``,
  ``height_compensation``, ``gradient_follow``, ``target_wave``) at their tick, before that
  tick's ``step``;
* optionally ``controller.internals() -> Mapping[str, float]``, recorded every tick when
  ``run(..., record_internals=True)``;
* optionally ``controller.truth(t_s, true_gap_mm, sheet_mm, nozzle_mm, coverage,
  plate_velocity_mm_s)``, called every tick just before ``step`` with the simulated truth
  (the sim node publishes it as ``sim/truth``; a real controller has no such method);
* optionally ``controller.wind_down()``, called once right after the last tick, before the
  series and metrics are built (the sim node's bridge stops the controller there while its
  inputs are still live).

Order of one tick ``i`` (``t = i h``): apply the events due; sheet height (precomputed part
+ plate); true gap; sensor and encoder samples; ``step``; the axis integrates the command
over ``[t, t + h)``; the plate integrates with the gas push at this tick's gap.
Same scenario + seed -> identical series (all randomness is drawn from one
``numpy.random.Generator`` up front).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from math import isnan
from pathlib import Path
import time
from typing import Any, ClassVar, Mapping, Protocol, runtime_checkable

from ladrc_contract.tick import TickInput
import numpy as np

from ..models.axis import H_S, Axis
from ..models.encoder import Encoder, Glitch
from ..models.sensor import Sensor, oscillator_hz
from ..models.sheet import Sheet
from .metrics import HOLD_S, TOL_MM, Metrics, compute_metrics
from .scenario import DRIVE_FAULT_REASON, Scenario, load_scenario


@runtime_checkable
class Controller(Protocol):
    """What the runner needs from a controller (``internals()`` is optional)."""

    def step(self, tick: TickInput) -> float:
        """Return the velocity command (mm/s) for this tick."""
        ...

    def command(self, name: str, **kwargs: Any) -> None:
        """Handle a follow command of the scenario timeline."""
        ...


SERIES = ('t_s', 'true_gap_mm', 'reading_mm', 'reading_valid', 'encoder_mm', 'nozzle_mm',
          'sheet_mm', 'coverage', 'command_mm_s', 'target_gap_mm', 'collision')


@dataclass
class RunResult:
    """Series of one run (numpy arrays, one sample per tick) and its metrics."""

    scenario: Scenario
    h_s: float
    t_s: np.ndarray
    true_gap_mm: np.ndarray
    reading_mm: np.ndarray
    reading_valid: np.ndarray
    encoder_mm: np.ndarray
    nozzle_mm: np.ndarray
    sheet_mm: np.ndarray
    coverage: np.ndarray
    command_mm_s: np.ndarray
    target_gap_mm: np.ndarray
    collision: np.ndarray
    metrics: Metrics
    internals: dict[str, np.ndarray] = field(default_factory=dict)
    wall_s: float = 0.0
    # velocity of the (thin) sheet surface per tick (sim/truth's plate_velocity_mm_s); 0 without
    # a plate
    plate_velocity_mm_s: np.ndarray | None = None

    @property
    def realtime_x(self) -> float:
        """Simulated time over wall-clock time of the loop."""
        return self.scenario.duration_s / self.wall_s if self.wall_s > 0 else math.inf

    drive_fault_reason: ClassVar[str] = DRIVE_FAULT_REASON  # what a drive fault's feedback says

    def raw_hz(self) -> np.ndarray:
        """Capacitive oscillator frequency (Hz) behind each reading (models/sensor.py)."""
        return oscillator_hz(self.reading_mm, self.scenario.sensor)

    def series(self) -> dict[str, np.ndarray]:
        """Return the recorded series by name (internals prefixed ``internals.``)."""
        out = {k: getattr(self, k) for k in SERIES}
        out.update({f'internals.{k}': v for k, v in self.internals.items()})
        return out


def schedule(n: int, h_s: float, initial: float, events: list[tuple[float, float, float]]
             ) -> np.ndarray:
    """Piecewise-linear per-tick schedule from ``(t_s, value, ramp_s)`` events."""
    out = np.full(n, float(initial))
    for t_s, value, ramp_s in sorted(events, key=lambda e: e[0]):
        i0 = min(n, int(round(t_s / h_s)))
        if i0 >= n:
            continue
        k = min(n - i0, int(round(ramp_s / h_s)))
        if k > 0:
            out[i0:i0 + k] = np.linspace(out[i0 - 1] if i0 else out[0], value, k + 1)[1:]
        out[i0 + k:] = value
    return out


def _column(values: list) -> np.ndarray:
    """Numbers (and bools) as a float array; anything else (e.g. reason strings) as objects."""
    try:
        return np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        return np.asarray(values, dtype=object)


def _held(n: int, h_s: float, spans: list[tuple[float, float]]) -> list[bool]:
    held = np.zeros(n, dtype=bool)
    for t_s, dur in spans:
        i0 = int(round(t_s / h_s))
        held[i0:i0 + max(1, int(round(dur / h_s)))] = True
    return held.tolist()


def draw_world(sc: Scenario, n: int, h_s: float) -> tuple[Sheet, Sensor]:
    """Draw the scenario's sheet and sensor for ``n`` ticks from its seed.

    One Generator, always drawn in the same order: sheet, sensor (determinism); the batch
    loop (:mod:`.batch`) draws the same world.
    """
    rng = np.random.default_rng(sc.seed)
    sheet = Sheet(sc.sheet, n, h_s, rng)
    gain = schedule(n, h_s, 1.0, [(e.t_s, e.args['value'], e.args['ramp_s'])
                                  for e in sc.timeline if e.name == 'sensor_gain']
                    ) * sheet.feedback_gain
    return sheet, Sensor(sc.sensor, n, h_s, rng, gain_schedule=gain)


def run(scenario: Scenario | str | Path, controller: Any, *, record_internals: bool = False,
        h_s: float = H_S, tol_mm: float = TOL_MM, hold_s: float = HOLD_S) -> RunResult:
    """Run ``controller`` through ``scenario`` (object, file path or shipped name)."""
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    if not (callable(getattr(controller, 'step', None))
            and callable(getattr(controller, 'command', None))):
        raise ValueError(f'{type(controller).__name__} is not a controller: it needs '
                         'step(tick) -> float and command(name, **kwargs)')
    n = int(round(sc.duration_s / h_s))
    sheet, sensor = draw_world(sc, n, h_s)
    ev = sc.timeline
    cov = schedule(n, h_s, sc.initial_coverage,
                   [(e.t_s, e.args['value'], e.args['ramp_s']) for e in ev
                    if e.name == 'coverage'])
    glitches = tuple(Glitch('jump', e.t_s, e.args['duration_s'], e.args['size_mm'])
                     for e in ev if e.name == 'encoder_jump')
    glitches += tuple(Glitch('stuck', e.t_s, e.args['duration_s']) for e in ev
                      if e.name == 'encoder_stuck')
    encoder = Encoder(sc.encoder, n, h_s, glitches)
    gap_held = _held(n, h_s, [(e.t_s, e.args['duration_s']) for e in ev
                              if e.name == 'sensor_dropout'])
    enc_held = _held(n, h_s, [(e.t_s, e.args['duration_s']) for e in ev
                              if e.name == 'encoder_dropout'])
    # sensor_freeze: the value is held but each sample is stamped afresh (a frozen sensor
    # behind a driver that re-stamps, as the live sim does on a dropout)
    gap_frozen = _held(n, h_s, [(e.t_s, e.args['duration_s']) for e in ev
                                if e.name == 'sensor_freeze'])
    plate = sheet.plate
    axis = Axis(sc.axis, float(sheet.base_mm[0]) + sc.initial_gap_mm, h_s)

    # events due at a tick: commands and world events handled inside the loop.
    pending: dict[int, list] = {}
    for e in ev:
        if e.name in ('coverage', 'sensor_gain', 'sensor_dropout', 'sensor_freeze',
                      'encoder_dropout', 'encoder_jump', 'encoder_stuck'):
            continue  # laid out in the schedules above
        pending.setdefault(min(n - 1, int(round(e.t_s / h_s))), []).append(e)
    due = sorted(pending)
    due.append(n)  # sentinel

    base = sheet.base_mm.tolist()
    cov_l = cov.tolist()
    t_l = (np.arange(n) * h_s).tolist()
    r_read = [0.0] * n
    r_valid = [False] * n
    r_enc = [0.0] * n
    r_noz = [0.0] * n
    r_sheet = [0.0] * n
    r_cmd = [0.0] * n
    r_target = [math.nan] * n
    r_pv = [0.0] * n
    rec_int = record_internals and callable(getattr(controller, 'internals', None))
    internals: dict[str, list] = {}

    # Fast paths (speed, see docs/simulator.md): the common configurations of the models are
    # inlined below with the models' own precomputed coefficients; everything else calls the
    # model methods. tests/sim/test_runner.py checks both give bit-identical series.
    ap = sc.axis
    fast_axis = ap.model == 'first_order' and ap.dead_time_ticks == 0
    ax_a, ax_kv, ax_kxv, ax_kxu, ax_umax, ax_dvm, ax_hh = axis.first_order
    x, v = axis.position_mm, axis.velocity_mm_s
    s_gain, s_noise, s_alpha, s_y = sensor._gain, sensor._noise, sensor._alpha, sensor._y
    s_q, s_rmax, s_rmin = sc.sensor.quant_mm, sc.sensor.range_max_mm, sc.sensor.range_min_mm
    fast_enc = not encoder._any
    e_res = sc.encoder.resolution_mm
    has_plate = plate is not None
    if has_plate:
        p00, p01, p10, p11, pg0, pg1 = plate.coefficients()
        p_y, p_v, p_k, p_g0 = plate.y_mm, plate.v_mm_s, plate.gas_k, plate.gas_g0
        gas_on, gas_auto, i_gas, i_kick = plate.gas_on, plate.gas_auto, plate.i_gas, plate.i_kick
        kick_v = plate.params.kick_velocity_mm_s
    else:
        p_y = p_v = 0.0

    measure = sensor.measure
    enc_read = encoder.read
    axis_step = axis.step
    c_step = controller.step
    c_command = controller.command
    c_truth = getattr(controller, 'truth', None)
    c_truth = c_truth if callable(c_truth) else None
    c_internals = controller.internals if rec_int else None
    # optional: a controller that stands for a drive (the sim node's bridge) can order a quick
    # stop, e.g. from its command watchdog; the axis then brakes at a_max as when faulted
    c_quick_stop = getattr(controller, 'quick_stop', None)
    c_quick_stop = c_quick_stop if callable(c_quick_stop) else None
    # optional: a drive on a bus takes the scenario's drive events with their error code
    c_drive_event = getattr(controller, 'drive_event', None)
    c_drive_event = c_drive_event if callable(c_drive_event) else None
    # optional: a controller on the ROS graph (the sim node's bridge) stops the follow at once
    # after the last tick, while its inputs are still live
    c_wind_down = getattr(controller, 'wind_down', None)
    c_wind_down = c_wind_down if callable(c_wind_down) else None
    new_tick = tuple.__new__
    enabled, fault = True, False
    target = math.nan
    offset = 0.0
    target_rec = math.nan
    gradient: list[tuple[int, float]] = []  # (tick, target) of delayed gradient follows
    reading, valid, gap_stamp, status = math.nan, False, -math.inf, 1
    enc, enc_stamp = math.nan, -math.inf
    next_due = due[0]
    k_due = 0

    wall0 = time.perf_counter()
    for i in range(n):
        t = t_l[i]
        if i == next_due:
            for e in pending[i]:
                name, a = e.name, e.args
                if e.is_command:
                    c_command(name, **a)
                    if name in ('start_follow', 'set_target'):
                        target = a['target_gap_mm']
                    elif name == 'pierce':  # the follow's target once the pierce is done
                        target = a['cut_gap_mm']
                    elif name == 'stop_follow':
                        target = math.nan
                        gradient = []
                    elif name == 'height_compensation':
                        offset = a['offset_mm']
                    elif name == 'gradient_follow':
                        gradient.append((i + int(round(a['delay_s'] / h_s)),
                                         a['target_gap_mm']))
                elif name == 'drive':
                    enabled, fault = a['enabled'], a['fault']
                    if c_drive_event is not None:
                        c_drive_event(**a)
                elif name == 'plate_kick':
                    p_v += a['velocity_mm_s']  # Plate.kick
                elif name == 'gas':
                    gas_on, gas_auto = a['on'], False  # Plate.set_gas
            target_rec = target + offset
            k_due += 1
            next_due = due[k_due]
        if gradient and gradient[0][0] <= i:
            target = gradient.pop(0)[1]
            target_rec = target + offset
        z = base[i] + p_y if has_plate else base[i]
        gap = x - z
        if gap_frozen[i]:
            gap_stamp = t
        elif not gap_held[i]:
            c = cov_l[i]
            if c >= 1.0:
                # Sensor.measure at full coverage (models/sensor.py).
                r = gap * s_gain[i]
                if s_alpha != 0.0:
                    r = r if s_y is None else s_alpha * s_y + (1.0 - s_alpha) * r
                    s_y = r
                r += s_noise[i]
                if s_q > 0.0:
                    r = round(r / s_q) * s_q
                if r > s_rmax:
                    reading, valid = s_rmax, False
                elif r < s_rmin:
                    reading, valid = s_rmin, False
                else:
                    reading, valid = r, True
            else:
                sensor._y = s_y
                reading, valid, _ = measure(i, gap, c)
                s_y = sensor._y
            gap_stamp = t
        if not enc_held[i]:
            if fast_enc:
                enc = round(x / e_res) * e_res if e_res > 0.0 else x  # Encoder.read
            else:
                enc = enc_read(i, x)
            enc_stamp = t
        if c_truth is not None:
            c_truth(t, gap, z, x, cov_l[i], p_v)
        if not (gap_held[i] or gap_frozen[i]):
            # the sensor reports contact as contact (models/sensor.py: collision at gap <= 0);
            # a held or frozen sample keeps the status it was sent with
            status = 0 if valid else (2 if gap <= 0.0 else 1)
        u = c_step(new_tick(TickInput, (t, reading, valid, gap_stamp, enc, enc_stamp,
                                        enabled, fault, status)))
        r_read[i] = reading
        r_valid[i] = valid
        r_enc[i] = enc
        r_noz[i] = x
        r_sheet[i] = z
        r_cmd[i] = u
        r_target[i] = target_rec
        r_pv[i] = p_v
        drive_ok = enabled and not fault and not (c_quick_stop is not None and c_quick_stop())
        if c_internals is not None:
            for key, val in c_internals().items():
                col = internals.get(key)
                if col is None:
                    col = internals[key] = [math.nan] * n
                col[i] = val
        if fast_axis:
            # Axis.step, first-order model without dead time (models/axis.py).
            if drive_ok:
                u = ax_umax if u > ax_umax else (-ax_umax if u < -ax_umax else
                                                 (u if not isnan(u) else 0.0))
                v1 = ax_a * v + ax_kv * u
                dv = v1 - v
                if -ax_dvm <= dv <= ax_dvm:
                    x = x + ax_kxv * v + ax_kxu * u
                else:
                    v1 = v + (ax_dvm if dv > 0.0 else -ax_dvm)
                    x = x + ax_hh * (v + v1)
            else:
                v1 = v - ax_dvm if v > ax_dvm else (v + ax_dvm if v < -ax_dvm else 0.0)
                x = x + ax_hh * (v + v1)
            v = v1
        else:
            x = axis_step(u, drive_ok)[0]
        if has_plate:
            # Plate.step (models/sheet.py): gas push held at this tick's gap.
            if gas_auto and not gas_on and i >= i_gas:
                gas_on = True
            if i == i_kick:
                p_v += kick_v
            pa = -p_k / ((gap if gap > 0.0 else 0.0) + p_g0) if gas_on else 0.0
            p_y, p_v = p00 * p_y + p01 * p_v + pg0 * pa, p10 * p_y + p11 * p_v + pg1 * pa
    wall = time.perf_counter() - wall0
    if c_wind_down is not None:  # before the series are built: the inputs are still live
        c_wind_down()
    if fast_axis:
        axis.position_mm, axis.velocity_mm_s = x, v
    sensor._y = s_y
    if has_plate:
        plate.y_mm, plate.v_mm_s, plate.k = p_y, p_v, n
        plate.gas_on, plate.gas_auto = gas_on, gas_auto

    noz_a = np.asarray(r_noz)
    sheet_a = np.asarray(r_sheet)
    gap_a = noz_a - sheet_a  # the same subtraction as in the loop: bit-identical
    target_a = np.asarray(r_target)
    cmd_a = np.asarray(r_cmd, dtype=float)
    coll_a = gap_a <= 0.0
    t_a = np.asarray(t_l)
    int_a = {k: _column(v) for k, v in internals.items()}
    metrics = compute_metrics(t_a, gap_a, target_a, coll_a, cmd_a, h_s=h_s,
                              v_max_mm_s=sc.axis.v_max_mm_s, a_max_mm_s2=sc.axis.a_max_mm_s2,
                              internals=int_a, tol_mm=tol_mm, hold_s=hold_s)
    return RunResult(scenario=sc, h_s=h_s, t_s=t_a, true_gap_mm=gap_a,
                     reading_mm=np.asarray(r_read), reading_valid=np.asarray(r_valid),
                     encoder_mm=np.asarray(r_enc), nozzle_mm=noz_a,
                     sheet_mm=sheet_a, coverage=cov, command_mm_s=cmd_a,
                     target_gap_mm=target_a, collision=coll_a, metrics=metrics,
                     internals=int_a, wall_s=wall, plate_velocity_mm_s=np.asarray(r_pv))


def summary(result: RunResult) -> Mapping[str, Any]:
    """Scenario name, realtime factor and metrics as a JSON-friendly dict."""
    return {'scenario': result.scenario.name, 'duration_s': result.scenario.duration_s,
            'realtime_x': result.realtime_x, **result.metrics.as_dict()}
