"""A cutting job, headless: the CNC runs the program, the controller follows, the sheet is cut.

Order of one tick ``i`` (``t = i h``, the scenario runner's convention): the CNC steps (XY, its
commands, its motion sample every cycle); the sheet under the nozzle gives the sensor its gap
(to the surface under the nozzle's centre) and its coverage (the nozzle face over material),
and the true gap (to the highest material under the face); the controller steps on the
reading, the encoder and the CNC's sample; the axis integrates the command; the beam lays its
kerf; a contour cut to its end drops its region (or tips it up, ``tip_parts``).

Duck-typed controller, as the scenario runner's: ``step(tick, cnc)``, ``command(name, **kw)``
(returns ``(accepted, message)``) and ``internals()`` (``FollowController``); optionally, as a
drive on the ROS graph has them (the sim node's ``JobDrive``): ``truth(t_s, true_gap_mm,
sheet_mm, nozzle_mm, coverage, plate_velocity_mm_s, x_mm, y_mm)`` before each ``step``,
``quick_stop()`` (the drive brakes at its maximum deceleration) and ``refusals()`` (commands
refused after they were sent: the CNC aborts as on a refusal at once). Same job + seed ->
identical series.

A separate CNC (``separate_cnc``; docs/job-world.md, "A separate CNC"): the CNC keeps its own
model of the sheet (:class:`~.cnc_station.CncStation`) and the world knows it only through its
motion samples (:class:`~.world.MotionView`: XY extrapolated between them, kerfs and drops from
them): what the sim node does with the CNC node on the wire, where ``cnc`` is the sim node's
link to it (``step(answers)`` -> the sample taken this tick or None, ``xy`` of that sample,
``log``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import time
from typing import Any, Callable

from ladrc_contract.codes import FollowState, Segment, SubState
from ladrc_contract.run_log import RunLog
from ladrc_contract.tick import TickInput
import numpy as np
from shapely.geometry import box

from ..headless.scenario import DRIVE_FAULT_REASON
from ..models.axis import H_S, Axis, AxisParams
from ..models.sensor import Sensor, SensorParams, oscillator_hz
from ..models.sheet_xy import SheetXY
from .cnc import Cnc
from .cnc_station import CncStation
from .world import CUT, KerfLayer, MotionView

SERIES = ('t_s', 'x_mm', 'y_mm', 'nozzle_mm', 'true_gap_mm', 'reading_mm', 'reading_valid',
          'coverage',
          'command_mm_s', 'state', 'substate', 'segment', 'contour', 'beam', 'target_gap_mm',
          'feed_mm_s', 'commanded_feed_mm_s', 'feed_override')


@dataclass
class JobResult:
    """The series of a job run, what the CNC did, and the per-job figures."""

    name: str
    series: dict[str, np.ndarray]
    figures: dict[str, Any]
    cnc_log: Any
    wall_s: float
    events: list[tuple[int, str, dict]] = field(default_factory=list)  # (tick, command, args)
    internals: dict[str, np.ndarray] | None = None  # the controller's status, every tick
    sensor: SensorParams | None = None  # the job's sensor (the raw value behind each reading)
    run: dict[str, Any] = field(default_factory=dict)  # faults, holds, states (RunLog.summary)

    def as_run(self, h_s: float = H_S) -> JobRun:
        """Return the run in the scenario runner's result layout (a bag writer's input)."""
        return JobRun(self, h_s)


@dataclass(frozen=True)
class _Command:
    """A CNC command as a scenario timeline entry (the bag writer logs it as an event)."""

    t_s: float
    name: str
    args: dict
    is_command: bool = True


class JobRun:
    """A job's result with the attributes of ``headless.runner.RunResult`` a bag needs."""

    drive_fault_reason = DRIVE_FAULT_REASON

    def __init__(self, result: JobResult, h_s: float) -> None:
        s = result.series
        self.h_s = h_s
        self.t_s = s['t_s']
        self.reading_mm = s['reading_mm']
        self.reading_valid = s['reading_valid'].astype(bool)
        self.collision = s['true_gap_mm'] <= 0.0
        self.encoder_mm = s['nozzle_mm']
        self.nozzle_mm = s['nozzle_mm']
        self.true_gap_mm = s['true_gap_mm']
        self.sheet_mm = s['nozzle_mm'] - s['true_gap_mm']
        self.coverage = s['coverage']
        self.x_mm, self.y_mm = s['x_mm'], s['y_mm']  # the nozzle in XY (SimTruth)
        self.command_mm_s = s['command_mm_s']
        self.target_gap_mm = s['target_gap_mm']
        self.internals = result.internals
        self._sensor = result.sensor
        self.scenario = _Scenario(result.name, tuple(
            _Command(k * h_s, name, dict(args)) for k, name, args in result.events))

    def raw_hz(self) -> np.ndarray:
        """Capacitive oscillator frequency (Hz) behind each reading, as the sim node sends it."""
        if self._sensor is None:
            return np.full(self.t_s.size, np.nan)
        return oscillator_hz(self.reading_mm, self._sensor)


class JobEnd:
    """When a job's run ends: some ticks after the CNC's end, once the command is zero.

    :data:`AFTER_TICKS` after the CNC finished or aborted, at the first tick the controller
    commands zero (a retract or a ramp down ran to its end). One rule for the headless runner
    and the CNC node, so that a lock-step run ends at the same tick.
    """

    AFTER_TICKS = 20

    def __init__(self) -> None:
        self.tick = -1  # the tick the CNC finished or aborted

    def done(self, i: int, log: Any, answers: dict) -> bool:
        """Return whether the run ends after tick ``i`` (``answers``: that tick's status)."""
        if (log.finished or log.aborted) and self.tick < 0:
            self.tick = i
        return (self.tick >= 0 and i - self.tick >= self.AFTER_TICKS
                and answers['velocity_mm_s'] == 0.0)


@dataclass(frozen=True)
class _Scenario:
    name: str
    timeline: tuple


def run_job(job: Any, controller: Any, *, max_s: float | None = None,
            record_internals: bool = False,
            progress: Callable[[int, int], None] | None = None,
            separate_cnc: bool = False, cnc: Any = None) -> JobResult:
    """Run ``job`` (:class:`~.jobfile.Job`) with ``controller``; return its :class:`JobResult`.

    ``record_internals``: keep the controller's status of every tick (for a bag);
    ``progress(contours_cut, contours)``: called as each contour is cut to its end;
    ``separate_cnc``: the CNC apart from the world (module docstring), in this process, or
    ``cnc``: on the wire (the sim node's link to the CNC node).
    """
    h = H_S
    if getattr(job, 'gcode', None) is not None and cnc is None:
        from .jobfile import JobError

        raise JobError(f'{job.path}: a G-code job (gcode: {job.gcode.name}) runs under '
                       f'LinuxCNC only, which reads its program: bringup --cnc linuxcnc --job '
                       f'{job.path}')
    program = job.program()
    sheet = SheetXY(job.plate(), job.surface, nozzle_diameter_mm=job.sensor.nozzle_diameter_mm)
    sheet.prepare([c.region for c in program.contours])  # what drops out: cheap in the loop
    budget_s = max_s if max_s is not None else job.time_budget_s(program)
    n = int(budget_s / h)
    rng = np.random.default_rng(job.seed)
    sensor = Sensor(job.sensor, n, h, rng)
    x0, y0 = job.start_xy
    axis = Axis(AxisParams(), sheet.z_mm(x0, y0) + job.start_height_mm, h)
    events: list[tuple[int, str, dict]] = []
    tick_i = 0

    def command(name: str, **kw: Any) -> tuple[bool, str]:
        events.append((tick_i, name, kw))
        return controller.command(name, **kw)

    if cnc is None and separate_cnc:
        cnc = CncStation(job, program, command, h)
    station = cnc  # a separate CNC, seen through its samples (view); else the CNC itself
    if station is None:
        cnc = view = Cnc(program, job.cnc, command, h, (x0, y0), sheet.void_ahead_mm)
    else:
        view = MotionView(x0, y0)
    cols = {k: np.full(n, np.nan) for k in SERIES}
    answers: dict[str, Any] = controller.internals()
    kerf = KerfLayer(sheet, job.kerf_mm)
    tips = set(job.tip_parts)
    c_step, c_internals = controller.step, controller.internals
    c_truth, c_quick_stop, c_refusals = (
        getattr(controller, name, None) for name in ('truth', 'quick_stop', 'refusals'))
    last = 0
    end = JobEnd()
    run_log = RunLog(h)  # every fault with its reason (the job's inputs are fresh every tick)
    contact = job.contact
    contact_ticks = max(1, round(contact.after_s / h)) if contact is not None else 0
    contact_at = [-1, 0, 0]  # contour being cut, cuts started, its ticks cutting
    rows: list[dict] | None = [] if record_internals else None
    wall0 = time.perf_counter()
    for i in range(n):
        tick_i = i
        t = i * h
        if c_refusals is not None:
            for name, message in c_refusals():
                cnc.refused(name, message)
        sample = cnc.step(answers)
        if getattr(cnc, 'ended', False):
            break  # the CNC on the wire ended its job instead of stepping this tick
        if station is not None:
            view.see(t, sample, *station.xy)
        x, y = view.x, view.y
        for k in view.cut_done:  # a contour cut to its end: its region drops (or tips)
            if k >= len(program.contours):
                continue  # a G-code job's contour: the world has no part of it to drop
            c = program.contours[k]
            if c.part in tips and not c.inner:
                sheet.tip(c.region, job.tip_rise_mm)
            else:
                sheet.drop(c.region)
            if progress is not None:
                progress(k + 1, len(program.contours))
        if contact is not None:  # the job's injected collision (jobfile.ContactInjection)
            cutting = view.beam and view.segment == CUT
            if cutting and view.contour != contact_at[0]:
                contact_at[:] = [view.contour, contact_at[1] + 1, 0]
            if cutting and contact_at[1] == contact.nth_cut:
                contact_at[2] += 1
                if contact_at[2] == contact_ticks:
                    half = contact.size_mm / 2.0
                    sheet.tip(box(x - half, y - half, x + 0.01, y + half), contact.rise_mm)
        z = axis.position_mm
        sensed, true_gap = sheet.under_face(x, y, z)
        cov = sheet.coverage(x, y)
        reading, valid, _ = sensor.measure(i, sensed, cov)
        collision = true_gap <= 0.0  # the nozzle touches material: the sensor shorts
        if collision:
            valid = False
        status = 0 if valid else (2 if collision else 1)
        if c_truth is not None:
            c_truth(t, true_gap, z - true_gap, z, cov, math.nan, x, y)
        u = c_step(TickInput(t, reading, valid, t, z, t, True, False, status), sample)
        answers = c_internals()
        run_log.tick(t, answers['state'], answers['fault_reason'], 0.0, 0.0, answers['substate'],
                     getattr(controller, 'fault_code', 0))
        axis.step(u, True, c_quick_stop is not None and c_quick_stop())
        kerf.step(x, y, view.beam and view.segment == CUT)  # the kerf, as it is cut
        if rows is not None:  # with the drive enable the command went out with (the bag's)
            rows.append({**answers, 'command_enable': bool(getattr(controller, 'enable', True))})
        feed = (view.actual_feed_mm_s if station is not None
                else cnc.move.v if cnc.move is not None else 0.0)
        row = (t, x, y, z, true_gap, reading, valid, cov, u, answers['state'], answers['substate'],
               view.segment, view.contour, view.beam, answers['target_gap_mm'], feed,
               view.feed_mm_s, answers['feed_override_request'])
        for key, value in zip(SERIES, row, strict=True):
            cols[key][i] = value
        last = i
        if end.done(i, cnc.log, answers):
            break
    else:
        if not cnc.log.finished:
            cnc.log.aborted = (cnc.log.aborted
                               or f'not done within its time budget ({budget_s:g} s)')
    wall = time.perf_counter() - wall0
    series = {k: v[:last + 1] for k, v in cols.items()}
    lock_ratio = getattr(getattr(controller, 'params', None), 'cnc', None)
    lock_ratio = lock_ratio.corner_lock_ratio if lock_ratio is not None else 0.8
    internals = None
    if rows:
        internals = {k: np.array([r[k] for r in rows], dtype=object if isinstance(v, str)
                                 else None) for k, v in rows[0].items()}
    figures = job_figures(series, h, cnc.log, len(program.contours), lock_ratio)
    figures['locked_contours'] = getattr(cnc.log, 'locked', 0)
    if program.reading is not None:
        figures['drawing'] = program.reading
    return JobResult(job.name, series, figures, cnc.log, wall, events, internals, job.sensor,
                     run_log.summary())


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Return the (start, stop) index pairs of the True runs of ``mask``."""
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(),
                    strict=True))


CORNER_AFTER_S = 0.05
"""A corner's excursion is counted until this long after the feed is back."""


def job_figures(series: dict[str, np.ndarray], h_s: float, log: Any, n_contours: int,
                corner_ratio: float = 0.8) -> dict[str, Any]:
    """Per-job figures: times, pierces, holds, faults, contacts, min true gap per contour.

    ``corner_max_down_mm``: the largest excursion of the nozzle below its target gap while
    cutting at a corner (actual feed below ``corner_ratio`` x the commanded one, and
    :data:`CORNER_AFTER_S` after), the figure corner lock is judged by.
    """
    seg = series['segment']
    sub = series['substate'].astype(int)
    state = series['state'].astype(int)
    gap = series['true_gap_mm']
    cutting = (seg == int(Segment.CUT)) & (series['beam'] > 0)
    holds = {}
    for s in (SubState.CORNER_LOCK, SubState.VOID_LOCK, SubState.HOLD, SubState.EDGE_AHEAD):
        runs = _runs(sub == int(s))
        holds[s.name.lower()] = {'count': len(runs),
                                 'seconds': round(sum(b - a for a, b in runs) * h_s, 4)}
    per_contour = {}
    contour = series['contour'].astype(int)
    for k in range(1, n_contours + 1):
        m = cutting & (contour == k)
        if m.any():
            per_contour[k] = round(float(np.min(gap[m])), 4)
    target = series['target_gap_mm']
    ratio = gap[cutting] / target[cutting] if cutting.any() else np.array([np.nan])
    cmd_feed = series['commanded_feed_mm_s']
    slow = cutting & (series['feed_mm_s'] < corner_ratio * cmd_feed)
    after = int(CORNER_AFTER_S / h_s)
    corner = np.convolve(slow.astype(np.int8), np.ones(after + 1, dtype=np.int8))[:len(slow)]
    corner = (corner > 0) & cutting
    down = target[corner] - gap[corner]
    faults = _runs(state == int(FollowState.FAULT))
    contacts = _runs(gap <= 0.0)
    return {
        'job_time_s': round(len(seg) * h_s, 4),
        'cutting_s': round(float(cutting.sum()) * h_s, 4),
        'rapid_s': round(float((seg == int(Segment.RAPID)).sum()) * h_s, 4),
        'pierce_s': round(float((seg == int(Segment.PIERCE)).sum()) * h_s, 4),
        'pierces': log.pierces,
        'holds': holds,
        'faults': len(faults),
        'contacts': len(contacts),
        'min_true_gap_cutting_mm': round(float(np.nanmin(gap[cutting])), 4) if cutting.any()
        else None,
        'min_gap_over_target_cutting': round(float(np.nanmin(ratio)), 4),
        'min_true_gap_per_contour_mm': per_contour,
        'feed_hold_s': round(log.feed_hold_ticks * h_s, 4),
        'feed_override_s': round(float((cutting & (series['feed_override'] < 1.0)).sum()) * h_s,
                                 4),
        'feed_override_min': round(float(np.min(series['feed_override'][cutting])), 3)
        if cutting.any() else 1.0,
        'corner_s': round(float(slow.sum()) * h_s, 4),
        # (a tick whose target is NaN: the follow stopped while the CNC's sample still said
        # cut, a cycle late; live or with a separate CNC)
        'corner_max_down_mm': round(float(np.nanmax(down)), 4) if np.isfinite(down).any()
        else 0.0,
        'finished': log.finished,
        'aborted': log.aborted,
    }
