"""Capacitive calibration: the sweep to contact and the raw -> gap table.

Pure (no rclpy). Three parts in three modules, each used by the node
(``ladrc_bringup/calibrate_node.py``), the ``ladrc calibrate`` command and the tests:

1. :class:`SweepProcedure`, the motion, stepped once per 0.5 ms tick: from a start height
   (reading valid, and at least ``min_start_gap_mm`` where the driver publishes a gap) it
   rests ``settle_s``, moves down at ``descent_mm_s`` (accelerating at ``accel_mm_s2``) until
   contact (the sensor's ``STATUS_COLLISION``, or the encoder stalled against the sheet), stops
   at once, and retracts to the start position at ``retract_mm_s``. ``max_travel_mm`` below the
   start without contact ends the descent too (the sweep then fails: the table needs the
   contact position). Any surprise (drive disabled or faulted, stale or non-finite input, a
   sensor fault, readings invalid for ``invalid_timeout_s``, the axis faster than commanded
   or moving the wrong way, a timeout) aborts with zero velocity and enable false.
   :meth:`SweepProcedure.on_sample` records every sensor sample (raw value, validity, status,
   encoder position); the node re-pairs the positions by stamp afterwards.
2. :func:`~.calibration_table.build_table` (``calibration_table.py``), the processing: the
   table's points and their local fits, noise, repeatability, the error against the sim's
   truth, the controller's own checks and grade.
3. :func:`~.calibration_output.write_calibration` (``calibration_output.py``): the table file
   (``cap_table.yaml``), the samples (``sweep.csv``), a plot, Markdown and JSON.

This module holds part 1 and the settings of all three.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, fields
from enum import IntEnum
import json
import math
from typing import Any, NamedTuple

from ladrc_follow import STATUS_COLLISION, STATUS_FAULT, STATUS_OK
import numpy as np

H_S = 0.0005
WAIT_STALE_S = 2.0
"""At the start (resting, zero command) a stream that is not fresh yet is waited for this long
(the first samples of a driver that has just started come in bursts); moving, it aborts."""


class CalibrationError(ValueError):
    """The sweep or its table failed; the message is one line with the reason."""


def _bounded(obj: Any, bounds: dict[str, tuple[float, float]]) -> list[str]:
    """Reasons why the fields of ``obj`` are not finite numbers within ``bounds``."""
    out = []
    for f in fields(obj):
        lo, hi = bounds[f.name]
        v = getattr(obj, f.name)
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                and lo <= v <= hi):
            out.append(f'{f.name} = {v!r}: must be a number in [{lo:g}, {hi:g}]')
    return out


@dataclass(frozen=True)
class SweepMotion:
    """Bounds of the calibration motion (docs/calibration.md, "Procedure")."""

    descent_mm_s: float = 0.5
    retract_mm_s: float = 2.0
    accel_mm_s2: float = 50.0
    max_travel_mm: float = 15.0
    min_start_gap_mm: float = 2.0
    settle_s: float = 0.2
    stale_timeout_s: float = 0.05  # blind travel at most descent × this (25 µm)
    invalid_timeout_s: float = 0.05
    stall_window_s: float = 0.1
    stall_ratio: float = 0.25
    retract_tol_mm: float = 0.01
    beyond_reading_mm: float = 0.5  # with a published gap: descend at most reading + this
    below_zero_mm: float = 0.05     # a published gap this far below zero is contact
    frozen_travel_mm: float = 0.5   # a raw value unchanged over this much travel is frozen

    BOUNDS = {
        'descent_mm_s': (0.01, 2.0), 'retract_mm_s': (0.01, 20.0),
        'accel_mm_s2': (1.0, 1000.0), 'max_travel_mm': (0.1, 50.0),
        'min_start_gap_mm': (0.0, 50.0), 'settle_s': (0.0, 10.0),
        'stale_timeout_s': (0.001, 1.0), 'invalid_timeout_s': (0.001, 1.0),
        'stall_window_s': (0.01, 2.0), 'stall_ratio': (0.01, 0.9),
        'retract_tol_mm': (0.001, 1.0), 'beyond_reading_mm': (0.0, 5.0),
        'below_zero_mm': (0.0, 1.0),
        'frozen_travel_mm': (0.01, 5.0),
    }

    def problems(self) -> list[str]:
        """Return why this motion cannot run (empty: fine)."""
        out = _bounded(self, self.BOUNDS)
        if not out and self.min_start_gap_mm >= self.max_travel_mm:
            out.append(f'min_start_gap_mm ({self.min_start_gap_mm:g}) must be below '
                       f'max_travel_mm ({self.max_travel_mm:g}): contact could not be reached')
        return out

    def timeout_s(self) -> float:
        """Longest run: settle, descent over the whole travel, retract, plus 10 s."""
        return (self.settle_s + self.max_travel_mm / self.descent_mm_s
                + self.max_travel_mm / self.retract_mm_s + 10.0)


@dataclass(frozen=True)
class TableSettings:
    """Where the table points go and how each is fitted (docs/calibration.md, "Table")."""

    min_gap_mm: float = 0.05
    step_rel: float = 0.05
    step_min_mm: float = 0.01
    step_max_mm: float = 0.1
    window_min_mm: float = 0.02
    min_window_samples: int = 20

    BOUNDS = {
        'min_gap_mm': (0.001, 5.0), 'step_rel': (0.001, 1.0), 'step_min_mm': (0.001, 1.0),
        'step_max_mm': (0.001, 5.0), 'window_min_mm': (0.001, 5.0),
        'min_window_samples': (5, 100000),
    }

    def problems(self) -> list[str]:
        """Return why these settings cannot be used (empty: fine)."""
        out = _bounded(self, self.BOUNDS)
        if not out and self.step_min_mm > self.step_max_mm:
            out.append(f'step_min_mm ({self.step_min_mm:g}) above step_max_mm '
                       f'({self.step_max_mm:g})')
        return out

    def knots(self, top_mm: float) -> np.ndarray:
        """Table gaps from ``min_gap_mm`` up to ``top_mm``, spaced finer near the sheet."""
        g = [self.min_gap_mm]
        while True:
            step = min(max(self.step_rel * g[-1], self.step_min_mm), self.step_max_mm)
            nxt = g[-1] + step
            if nxt > top_mm + 1e-12:
                break
            g.append(nxt)
        return np.round(np.asarray(g), 9)

    def half_window_mm(self, gap_mm: np.ndarray) -> np.ndarray:
        """Half-width of the local fit at each table gap."""
        step = np.clip(self.step_rel * gap_mm, self.step_min_mm, self.step_max_mm)
        return np.maximum(step, self.window_min_mm)


class Phase(IntEnum):
    """Phases of :class:`SweepProcedure`."""

    WAIT = 0
    DESCEND = 1
    STOP = 2
    RETRACT = 3
    DONE = 4
    ABORTED = 5


class SweepInput(NamedTuple):
    """Latest inputs at a tick (receive times on the procedure's clock, seconds)."""

    t_s: float
    raw_hz: float
    gap_mm: float           # as published (NaN for a raw-only driver)
    valid: bool
    status: int
    gap_stamp_s: float      # when the latest sensor sample arrived
    position_mm: float
    enc_stamp_s: float
    drive_enabled: bool
    drive_fault: bool
    drive_reason: str = ''  # AxisFeedback.fault_reason


COLUMNS = ('t_s', 'stamp_s', 'seq', 'raw_hz', 'gap_mm', 'valid', 'status', 'position_mm',
           'phase', 'true_gap_mm')


@dataclass
class SweepRecord:
    """Samples of one sweep (one row per sensor sample) and what the procedure saw."""

    rows: list[tuple] = field(default_factory=list)
    start_position_mm: float = math.nan
    contact_position_mm: float = math.nan
    contact_kind: str = ''          # 'collision status' | 'stall' | ''
    contact_seq: int = -1

    def arrays(self) -> dict[str, np.ndarray]:
        """Return the rows as one float array per column of :data:`COLUMNS`."""
        a = np.asarray(self.rows, dtype=float).reshape(-1, len(COLUMNS))
        return {k: a[:, i] for i, k in enumerate(COLUMNS)}


class SweepProcedure:
    """The calibration motion, one :meth:`step` per tick (module docstring, part 1)."""

    def __init__(self, motion: SweepMotion | None = None) -> None:
        self.motion = motion or SweepMotion()
        reasons = self.motion.problems()
        if reasons:
            raise CalibrationError('calibration motion: ' + '; '.join(reasons))
        self.phase = Phase.WAIT
        self.reason = ''          # why it aborted, or why the sweep failed (no contact)
        self.record = SweepRecord()
        self.velocity_mm_s = 0.0  # last command
        self.enable = True
        self._t0 = math.nan
        self._t_prev = math.nan
        self._t_phase = math.nan
        self._contact = ''        # set by on_sample (collision status) or the stall check
        self._contact_pos = math.nan
        self._contact_seq = -1
        self._pos = math.nan      # latest encoder position
        self._invalid_since = math.nan
        self._window: deque[tuple[float, float]] = deque()
        self._full_speed_t = math.nan
        self._start_gap_mm = math.nan  # the published gap reading at the start (NaN: raw only)
        self._raw_last = math.nan      # the raw value and the position where it last changed
        self._raw_pos = math.nan

    # ---- state -------------------------------------------------------------------------
    @property
    def finished(self) -> bool:
        """Whether the procedure has ended (done or aborted)."""
        return self.phase in (Phase.DONE, Phase.ABORTED)

    @property
    def succeeded(self) -> bool:
        """Done, back at the start, with a contact."""
        return self.phase == Phase.DONE and not self.reason

    def abort(self, reason: str) -> tuple[float, bool]:
        """Stop for good: zero velocity, enable false, and say why (first reason kept)."""
        if not self.finished or self.phase == Phase.DONE:
            self.reason = self.reason or reason
        if self.phase != Phase.DONE:
            self.phase = Phase.ABORTED
        self.velocity_mm_s, self.enable = 0.0, False
        return 0.0, False

    # ---- inputs ------------------------------------------------------------------------
    def on_sample(self, t_s: float, stamp_s: float, seq: int, raw_hz: float, gap_mm: float,
                  valid: bool, status: int, position_mm: float) -> None:
        """Record one sensor sample (every one, not only the latest at a tick)."""
        if position_mm - position_mm == 0.0:
            self._pos = position_mm
        self.record.rows.append((t_s, stamp_s, seq, raw_hz, gap_mm, float(valid), status,
                                 self._pos, int(self.phase), math.nan))
        if status == STATUS_COLLISION and self.phase == Phase.DESCEND and not self._contact:
            self._contact = 'collision status'
            self._contact_pos = self._pos
            self._contact_seq = seq

    def set_true_gap(self, true_gap_mm: float) -> None:
        """Attach the simulator's true gap to the last recorded sample."""
        if self.record.rows:
            row = self.record.rows[-1]
            self.record.rows[-1] = row[:-1] + (true_gap_mm,)

    # ---- the tick ----------------------------------------------------------------------
    def step(self, inp: SweepInput) -> tuple[float, bool]:
        """Return ``(velocity_mm_s, enable)`` for this tick."""
        try:
            return self._step(inp)
        except Exception as exc:  # noqa: BLE001 - any surprise ends in a zero command
            return self.abort(f'calibration step failed: {type(exc).__name__}: {exc}')

    def _ramp(self, target: float, dt: float) -> float:
        dv = self.motion.accel_mm_s2 * dt
        v = self.velocity_mm_s
        v = min(target, v + dv) if target > v else max(target, v - dv)
        self.velocity_mm_s = v
        return v

    def _enter(self, phase: Phase, t: float) -> None:
        self.phase = phase
        self._t_phase = t

    def _step(self, inp: SweepInput) -> tuple[float, bool]:
        m = self.motion
        if self.finished:
            return 0.0, False
        t = inp.t_s
        if self._t0 != self._t0:
            self._t0 = self._t_phase = self._t_prev = t
        dt = min(max(t - self._t_prev, 0.0), 0.01)
        self._t_prev = t
        # ---- surprises: stop for good
        if inp.drive_fault or not inp.drive_enabled:
            why = f' ({inp.drive_reason})' if inp.drive_reason else ''
            return self.abort('drive ' + ('fault' if inp.drive_fault else 'disabled')
                              + f' in phase {self.phase.name}{why}')
        age_g, age_e = t - inp.gap_stamp_s, t - inp.enc_stamp_s
        stale = not (age_g <= m.stale_timeout_s and age_e <= m.stale_timeout_s)
        if stale and self.phase == Phase.WAIT and t - self._t0 <= m.settle_s + WAIT_STALE_S:
            # at rest (zero command): wait for a fresh stream, the settle time starts again
            self._t_phase = t
            self.velocity_mm_s = 0.0
            return 0.0, True
        if stale:
            return self.abort(f'stale input in phase {self.phase.name}: sensor '
                              f'{age_g * 1e3:.3g} ms, encoder {age_e * 1e3:.3g} ms old (limit '
                              f'{m.stale_timeout_s * 1e3:.3g} ms)')
        pos = inp.position_mm
        if not pos - pos == 0.0:
            return self.abort(f'encoder position not finite ({pos!r})')
        self._pos = pos
        if inp.status == STATUS_FAULT:
            return self.abort('the sensor reports a fault')
        if inp.valid and not inp.raw_hz - inp.raw_hz == 0.0:
            return self.abort(f'raw value not finite ({inp.raw_hz!r}) though marked valid')
        if t - self._t0 > m.timeout_s():
            return self.abort(f'timeout: {m.timeout_s():.0f} s in phase {self.phase.name}')

        if self.phase == Phase.WAIT:
            return self._wait(inp, t)
        start = self.record.start_position_mm
        if pos > start + 0.5 + m.retract_tol_mm:
            return self.abort(f'the axis is {pos - start:.3f} mm above the start: it does '
                              'not move as commanded (sign?)')
        self._window.append((t, pos))
        while self._window and self._window[0][0] < t - m.stall_window_s:
            self._window.popleft()
        if len(self._window) >= 2:
            (t_a, p_a), (t_b, p_b) = self._window[0], self._window[-1]
            if t_b - t_a > 0.5 * m.stall_window_s:
                speed = abs(p_b - p_a) / (t_b - t_a)
                limit = 2.0 * max(m.descent_mm_s, m.retract_mm_s) + 0.5
                if self.phase == Phase.DESCEND:  # the phase's own commanded speed
                    limit = 2.0 * m.descent_mm_s + 0.5
                if speed > limit:
                    return self.abort(f'the axis moves at {speed:.3g} mm/s, faster than '
                                      f'{limit:.3g} mm/s (commanded at most '
                                      f'{max(m.descent_mm_s, m.retract_mm_s):g})')
        if self.phase == Phase.DESCEND:
            return self._descend(inp, t, dt, pos)
        if self.phase == Phase.STOP:
            self.velocity_mm_s = 0.0
            if t - self._t_phase >= 0.05:
                self._enter(Phase.RETRACT, t)
            return 0.0, True
        return self._retract(t, dt, pos)

    def _wait(self, inp: SweepInput, t: float) -> tuple[float, bool]:
        m = self.motion
        if not inp.valid or inp.status != STATUS_OK:
            return self.abort(f'the reading at the start is not valid (status {inp.status}): '
                              'start above the sheet, within the sensor range')
        if inp.gap_mm == inp.gap_mm and inp.gap_mm < m.min_start_gap_mm:
            return self.abort(f'start too low: the reading is {inp.gap_mm:.3f} mm, below '
                              f'min_start_gap_mm {m.min_start_gap_mm:g}')
        self.velocity_mm_s = 0.0
        if t - self._t_phase >= m.settle_s:
            self.record.start_position_mm = inp.position_mm
            self._start_gap_mm = inp.gap_mm
            self._enter(Phase.DESCEND, t)
            self._window.clear()
        return 0.0, True

    def _descend(self, inp: SweepInput, t: float, dt: float, pos: float
                 ) -> tuple[float, bool]:
        m = self.motion
        # readings invalid for long while closing in: a surprise (near contact a few noisy
        # samples below the sensor's range are expected, contact itself is a status)
        if inp.valid and inp.status == STATUS_OK:
            self._invalid_since = math.nan
        elif inp.status != STATUS_COLLISION:
            if self._invalid_since != self._invalid_since:
                self._invalid_since = t
            elif t - self._invalid_since > m.invalid_timeout_s:
                return self._stop(t, '', f'readings invalid for {m.invalid_timeout_s * 1e3:g} '
                                  f'ms during the descent (status {inp.status}), '
                                  f'{self.record.start_position_mm - pos:.3f} mm below the '
                                  'start')
        if not self._contact and inp.status == STATUS_COLLISION:
            self._contact, self._contact_pos = 'collision status', pos
        if not self._contact and inp.gap_mm == inp.gap_mm and inp.gap_mm <= -m.below_zero_mm:
            # a backstop for a sensor that never reports the collision: its own gap reading
            # clearly below zero (beyond its noise; the status comes first on a sound sensor)
            self._contact, self._contact_pos = 'gap reading below zero', pos
        if self._contact:
            return self._stop(t, self._contact, '')
        travel = self.record.start_position_mm - pos
        if travel > self._start_gap_mm + m.beyond_reading_mm:  # NaN (raw only): never
            return self._stop(t, '', f'{travel:.3f} mm below the start without contact, more '
                              f'than the start reading {self._start_gap_mm:.3f} mm + '
                              f'{m.beyond_reading_mm:g} mm: the sensor never reported it')
        # a raw value that does not change while the axis travels is a frozen sensor
        if inp.raw_hz != self._raw_last:
            self._raw_last, self._raw_pos = inp.raw_hz, pos
        elif self._raw_pos - pos > m.frozen_travel_mm:
            return self._stop(t, '', f'raw value frozen at {inp.raw_hz!r} over '
                              f'{self._raw_pos - pos:.3f} mm of travel: a frozen sensor')
        if travel >= m.max_travel_mm:
            return self._stop(t, '', f'no contact within max_travel_mm {m.max_travel_mm:g} '
                              'mm below the start: start lower or raise the limit')
        v = self._ramp(-m.descent_mm_s, dt)
        if v <= -m.descent_mm_s and self._full_speed_t != self._full_speed_t:
            self._full_speed_t = t
        # stall: at full speed for a whole window, the encoder moved much less than commanded
        if (self._full_speed_t == self._full_speed_t
                and t - self._full_speed_t >= m.stall_window_s and len(self._window) >= 2):
            (t_a, p_a), (t_b, p_b) = self._window[0], self._window[-1]
            if t_b - t_a >= 0.9 * m.stall_window_s and (
                    p_a - p_b < m.stall_ratio * m.descent_mm_s * (t_b - t_a)):
                self._contact, self._contact_pos = 'stall', pos
                return self._stop(t, 'stall', '')
        return v, True

    def _stop(self, t: float, contact: str, failure: str) -> tuple[float, bool]:
        """Contact or the travel limit: zero at once (no ramp toward the sheet), then retract."""
        self.velocity_mm_s = 0.0
        rec = self.record
        if contact:
            rec.contact_kind = contact
            rec.contact_position_mm = self._contact_pos
            rec.contact_seq = self._contact_seq
        else:
            self.reason = failure
        self._enter(Phase.STOP, t)
        return 0.0, True

    def _retract(self, t: float, dt: float, pos: float) -> tuple[float, bool]:
        m = self.motion
        left = self.record.start_position_mm - pos
        if left <= m.retract_tol_mm:
            self.velocity_mm_s = 0.0
            self._enter(Phase.DONE, t)
            self.enable = False
            return 0.0, False
        if t - self._t_phase > m.max_travel_mm / m.retract_mm_s + 5.0:
            return self.abort(f'retract did not reach the start ({left:.3f} mm left)')
        # toward the start: at most retract speed, slowing in (5 /s) so it arrives smoothly
        target = min(m.retract_mm_s, 5.0 * left + 0.02)
        return self._ramp(target, dt), True


# ---- headless: the procedure against the simulator's models --------------------------
class HeadlessSweep:
    """The runner's controller (``ladrc_sim.headless.runner.run``) playing a sweep.

    The raw value is the simulator's oscillator of each reading (``oscillator_hz``, as the
    sim node publishes it); the truth hook attaches the true gap to each sample.
    """

    def __init__(self, procedure: SweepProcedure, sensor_params: Any) -> None:
        from ladrc_sim import oscillator_hz

        self.procedure = procedure
        self._osc = oscillator_hz
        self._sensor = sensor_params
        self._true = math.nan
        self._seq = 0

    def command(self, name: str, **kwargs: Any) -> None:
        """Ignore follow commands."""

    def truth(self, t_s: float, true_gap_mm: float, *_: Any) -> None:
        """Keep the true gap of the coming tick."""
        self._true = true_gap_mm

    def step(self, tick: Any) -> float:
        """Record this tick's sample, then step the procedure."""
        p = self.procedure
        raw = float(self._osc(tick.gap_mm, self._sensor))
        status = int(getattr(tick, 'gap_status', 0))
        p.on_sample(tick.t_s, tick.gap_stamp_s, self._seq, raw, math.nan, tick.gap_valid,
                    status, tick.encoder_mm)
        p.set_true_gap(self._true)
        self._seq += 1
        v, enable = p.step(SweepInput(tick.t_s, raw, math.nan, tick.gap_valid, status,
                                      tick.gap_stamp_s, tick.encoder_mm, tick.encoder_stamp_s,
                                      tick.drive_enabled, tick.drive_fault))
        return v if enable else 0.0


SIM_SCENARIO: dict[str, Any] = {
    'name': 'calibrate_sensor',
    'description': 'Capacitive calibration: a flat sheet under the nozzle, the shipped '
                   "scenarios' sensor noise (5 µm) and quantization (1 µm); nothing followed.",
    'seed': 1,
    'initial_gap_mm': 5.0,
    'sensor': {'noise_std_mm': 0.005, 'quant_mm': 0.001},
}
"""The simulated calibration set-up (``ladrc calibrate --sim``, the tests); ``duration_s`` is
set from the motion's timeout."""


def sim_scenario(start_gap_mm: float = 5.0, motion: SweepMotion | None = None,
                 **sensor: Any) -> dict[str, Any]:
    """Return :data:`SIM_SCENARIO` for a start gap, long enough for ``motion``."""
    d = json.loads(json.dumps(SIM_SCENARIO))
    d['initial_gap_mm'] = float(start_gap_mm)
    d['sensor'].update(sensor)
    d['duration_s'] = float(math.ceil((motion or SweepMotion()).timeout_s()))
    return d


def run_headless(scenario: dict[str, Any], motion: SweepMotion | None = None
                 ) -> SweepProcedure:
    """Play the sweep on the headless simulator; return the finished procedure."""
    from ladrc_sim import run, scenario_from_dict

    sc = scenario_from_dict(scenario)
    proc = SweepProcedure(motion)
    player = HeadlessSweep(proc, sc.sensor)

    class _Stop(Exception):
        pass

    step = player.step

    def stepping(tick: Any) -> float:
        if proc.finished:
            raise _Stop
        return step(tick)

    player.step = stepping  # end the run as soon as the sweep is over
    try:
        run(sc, player)
    except _Stop:
        pass
    return proc
