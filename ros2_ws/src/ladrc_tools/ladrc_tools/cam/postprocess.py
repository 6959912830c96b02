"""Post-processor: a job's part program as G-code for the LADRC laser's LinuxCNC.

``ladrc post JOB -o FILE.ngc`` (and ``bringup --cnc linuxcnc``) write the program a laser or
plasma CAM writes for LinuxCNC (plasmac's conventions), from the job's part program
(``ladrc_sim/job/program.py``: contours in cut order, kerf side, lead-ins, micro-joints):

* **Pre-offset path.** The program's contours are already kerf-compensated (half a kerf into
  the scrap: outside an outline, inside a hole), so the path is written as it is, with G40 (no
  cutter compensation): the same path the simulated CNC cuts. (G41/G42 on the drawing's path
  would have LinuxCNC offset it, with its own rules at concave corners and lead-ins; a
  pre-offset path keeps one geometry for both CNCs.)
* **Moves.** ``G0`` to each pierce point, ``M3 $0 S1`` (the beam's request: the height
  controller pierces; LinuxCNC waits for ``spindle.0.at-speed`` before the first feed move),
  ``G1`` along the lead-in and the contour at the job's feed, ``M5 $0``. The contours are
  polylines (flattened to the program's chord tolerance), so every segment is a ``G1``.
* **Blending.** ``G64 P`` (the path may leave the programmed one by at most P at a corner) with
  ``blend_mm``; ``blend_mm`` 0 writes ``G61`` (exact stop at every segment's end).
* **Holds.** Where the simulated CNC's edge-ahead rule would hold the height (a void within
  the controller's ``cnc.edge_ahead_hold_mm`` ahead: the sheet's outline, a hole, a kerf cut
  earlier, the contour's own start at its end; held until ``cnc.edge_release_mm`` after it),
  the segment is split and ``M62 P2`` / ``M63 P2`` (synchronised with the next move: plasmac's
  THC off) are written around the stretch; the bridge turns them into ``follow/hold``. Found on
  the CNC's own model of the sheet (``ladrc_sim.job.cnc_station``'s: the plate, the kerfs laid
  along the path so far, the contours cut before dropped), walked in ``step_mm`` steps.
* **Micro-joints.** ``M62 P3`` / ``M63 P3`` around each beam-off gap (plasmac's torch off).
* **Adaptive feed.** ``M52 P1`` (the height controller's feed request applies).

Each contour is preceded by a comment naming it (``(contour 3 of 12: hole of part 1, ...)``);
:class:`PostResult` has the line numbers of each contour's ``M3`` and its hold stretches.

Plain Python (numpy, the sim's sheet model); the bridge (``ladrc_linuxcnc``) never imports it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import Any

from ladrc_contract.schema import Section, param
import numpy as np


@dataclass(frozen=True)
class PostSettings(Section):
    """How the program is written (``ladrc post``'s options)."""

    blend_mm: float = param(0.05, 'mm', 'G64 P: the largest deviation at a blended corner; 0 '
                            'writes G61 (exact stop)', ge=0.0, le=5.0)
    naive_cam_mm: float = param(0.0, 'mm', "G64 Q: LinuxCNC's naive CAM detector merges "
                                'collinear segments within this (0: off)', ge=0.0, le=1.0)
    holds: bool = param(True, '', 'write M62/M63 P2 around the stretches the edge-ahead rule '
                        'holds')
    edge_ahead_hold_mm: float = param(-1.0, 'mm', 'hold from this far before a void (-1: the '
                                      "job's controller cnc.edge_ahead_hold_mm)", ge=-1.0,
                                      le=100.0)
    edge_release_mm: float = param(-1.0, 'mm', "hold this far after it (-1: the job's "
                                   'controller cnc.edge_release_mm)', ge=-1.0, le=100.0)
    step_mm: float = param(0.2, 'mm', "the walk along the path on the CNC's sheet model",
                           gt=0.0, le=2.0)
    digits: int = param(4, '', 'decimals of the coordinates', ge=2, le=6)


@dataclass
class PostResult:
    """The program and where its contours and holds are."""

    text: str
    contour_lines: list[int] = field(default_factory=list)  # the line of each contour's M3
    holds_mm: list[list[tuple[float, float]]] = field(default_factory=list)  # per contour
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def lines(self) -> int:
        """Return the number of lines of the program."""
        return self.text.count('\n')


def _cum(path: np.ndarray) -> np.ndarray:
    d = np.hypot(*np.diff(path, axis=0).T)
    return np.concatenate(([0.0], np.cumsum(d)))


def _at(path: np.ndarray, cum: np.ndarray, s: np.ndarray) -> np.ndarray:
    return np.c_[np.interp(s, cum, path[:, 0]), np.interp(s, cum, path[:, 1])]


def _merge(intervals: list[tuple[float, float]], gap: float) -> list[tuple[float, float]]:
    out: list[list[float]] = []
    for a, b in sorted(intervals):
        if out and a <= out[-1][1] + gap:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return [(a, b) for a, b in out]


def _void_distance(sheet: Any, pts: np.ndarray, dist: np.ndarray) -> float:
    """Return ``dist`` of the first point of ``pts`` over no material (inf: none).

    The raster lookup of ``SheetXY.void_ahead_mm``, at given distances.
    """
    c = sheet.cell_mm
    j = ((pts[:, 1] - sheet.y0) / c).astype(np.int64)
    i = ((pts[:, 0] - sheet.x0) / c).astype(np.int64)
    m = sheet.material
    ok = (j >= 0) & (j < m.shape[0]) & (i >= 0) & (i < m.shape[1])
    solid = np.zeros(len(pts), dtype=bool)
    solid[ok] = m[j[ok], i[ok]]
    void = np.flatnonzero(~solid)
    return math.inf if void.size == 0 else float(dist[void[0]])


def hold_stretches(job: Any, program: Any, hold_mm: float, release_mm: float,
                   step_mm: float) -> list[list[tuple[float, float]]]:
    """Return, per contour, the path stretches ``(s0, s1)`` [mm] the edge-ahead rule holds.

    The simulated CNC's rule (``ladrc_follow`` ``control/follow/cnc.py``): at a path point
    whose first void ahead (within the CNC's look-ahead, on the CNC's sheet model) is at most
    ``hold_mm`` away, held until ``release_mm`` of path after that void. The sheet model is
    the CNC station's (``ladrc_sim.job.cnc_station``): kerfs laid as the path is walked, each
    contour dropped once cut.
    """
    from ladrc_sim import KerfLayer, SheetXY

    sheet = SheetXY(job.plate(), job.surface, nozzle_diameter_mm=job.sensor.nozzle_diameter_mm)
    sheet.prepare([c.region for c in program.contours])
    kerf = KerfLayer(sheet, job.kerf_mm)
    look, ahead_step = float(job.cnc.look_ahead_mm), 0.5
    out: list[list[tuple[float, float]]] = []
    for c in program.contours:
        path = np.vstack((c.lead_in_mm, c.points_mm[1:]))
        cum = _cum(path)
        total = float(cum[-1])
        lead = float(cum[len(c.lead_in_mm) - 1])
        s_walk = np.arange(0.0, total, step_mm)
        pts = _at(path, cum, s_walk)
        stretches: list[tuple[float, float]] = []
        for s, (x, y) in zip(s_walk, pts, strict=True):
            sc = s - lead
            beam = not any(a <= sc <= b for a, b in c.micro_joints)
            kerf.step(float(x), float(y), beam)
            if hold_mm <= 0.0:
                continue
            # the CNC's look-ahead points; and the path's end: a closed contour ends on the kerf
            # of its own start (the simulated CNC's raster and sampling grid meet it at some
            # contours, not at others: here always, as the sensor does)
            s_ahead = s + np.arange(1, int(look / ahead_step) + 1) * ahead_step
            s_ahead = s_ahead[s_ahead < total]
            d = (_void_distance(sheet, _at(path, cum, s_ahead), s_ahead - s) if s_ahead.size
                 else math.inf)
            d = min(d, total - s if total - s <= look else math.inf)
            if d <= hold_mm:
                stretches.append((float(s), min(float(s) + d + release_mm, total)))
        end = path[-1]
        kerf.step(float(end[0]), float(end[1]), False)
        sheet.drop(c.region)
        out.append(_merge(stretches, step_mm * 1.5))
    return out


def _fmt(v: float, digits: int) -> str:
    text = f'{v:.{digits}f}'.rstrip('0').rstrip('.')
    return '0' if text in ('-0', '') else text


def postprocess(job: Any, settings: PostSettings | None = None,
                controller: dict[str, Any] | None = None) -> PostResult:
    """Return the G-code of ``job`` (a ``ladrc_sim`` job with its program) for LinuxCNC.

    ``controller``: the dotted controller parameters the holds take ``cnc.edge_ahead_hold_mm``
    and ``cnc.edge_release_mm`` from where ``settings`` leaves them -1 (default: the job's
    ``controller`` section over the controller's defaults).
    """
    s = settings or PostSettings()
    bad = s.problems()
    if bad:
        raise ValueError(bad[0])
    program = job.program()
    hold_mm, release_mm = s.edge_ahead_hold_mm, s.edge_release_mm
    if hold_mm < 0.0 or release_mm < 0.0:
        from ladrc_follow import CncParams

        base = CncParams()
        given = {**(controller if controller is not None else job.controller)}
        if hold_mm < 0.0:
            hold_mm = float(given.get('cnc.edge_ahead_hold_mm', base.edge_ahead_hold_mm))
        if release_mm < 0.0:
            release_mm = float(given.get('cnc.edge_release_mm', base.edge_release_mm))
    holds = (hold_stretches(job, program, hold_mm, release_mm, s.step_mm) if s.holds
             else [[] for _ in program.contours])
    d = s.digits
    feed = float(job.cnc.feed_mm_s) * 60.0
    lines: list[str] = []

    def emit(text: str) -> int:
        lines.append(text)
        return len(lines)

    src = Path(program.source).name
    emit(f'(LADRC laser: job {job.name}, {len(program.contours)} contours from {src}, '
         f'{program.units} drawing)')
    emit('(ladrc_tools.cam.postprocess: the kerf-compensated path, G40)')
    emit('(M3 $0: the beam request; M62/M63 P2: hold the height; M62/M63 P3: beam off)')
    emit('G21 G90 G17 G40 G49 G94')
    if s.blend_mm > 0.0:
        q = f' Q{_fmt(s.naive_cam_mm, d)}' if s.naive_cam_mm > 0.0 else ''
        emit(f'G64 P{_fmt(s.blend_mm, d)}{q}')
    else:
        emit('G61')
    emit('M52 P1 (adaptive feed: the height controller asks)')
    emit(f'F{_fmt(feed, 3)}')
    result = PostResult('', [], holds, {'blend_mm': s.blend_mm, 'naive_cam_mm': s.naive_cam_mm,
                                        'holds': s.holds, 'edge_ahead_hold_mm': hold_mm,
                                        'edge_release_mm': release_mm, 'feed_mm_s':
                                        float(job.cnc.feed_mm_s)})
    for k, c in enumerate(program.contours, 1):
        path = np.vstack((c.lead_in_mm, c.points_mm[1:]))
        cum = _cum(path)
        total = float(cum[-1])
        lead = float(cum[len(c.lead_in_mm) - 1])
        events: list[tuple[float, int, str]] = []  # (s, order, code): off before on at one s
        for a, b in holds[k - 1]:
            events.append((a, 1, 'M62 P2 (hold the height: edge ahead)'))
            if b < total - 1e-6:
                events.append((b, 0, 'M63 P2'))
        for a, b in c.micro_joints:
            events.append((lead + a, 1, 'M62 P3 (micro-joint: beam off)'))
            events.append((lead + b, 0, 'M63 P3'))
        events.sort()
        kind = f'hole of part {c.part}' if c.inner else f'outline of part {c.part}'
        emit(f'(contour {k} of {len(program.contours)}: {kind}, {total:.1f} mm, lead-in '
             f'{lead:.1f} mm)')
        x0, y0 = path[0]
        emit(f'G0 X{_fmt(x0, d)} Y{_fmt(y0, d)}')
        result.contour_lines.append(emit('M3 $0 S1'))
        # the path with a vertex at every event
        cuts = sorted({round(e[0], 6) for e in events if 0.0 < e[0] < total})
        s_all = np.unique(np.concatenate((cum, cuts)))
        pts = _at(path, cum, s_all)
        ei = 0
        for i in range(1, len(s_all)):
            while ei < len(events) and events[ei][0] <= s_all[i - 1] + 1e-6:
                emit(events[ei][2])
                ei += 1
            x, y = pts[i]
            if s_all[i] - s_all[i - 1] > 1e-9:
                emit(f'G1 X{_fmt(x, d)} Y{_fmt(y, d)}')
        emit('M5 $0')
        if any(e[2].startswith('M62 P3') for e in events):
            emit('M65 P3')
        if any(b >= total - 1e-6 for _, b in holds[k - 1]):
            emit('M65 P2 (release the hold: the contour is done)')
    emit('M2')
    result.text = '\n'.join(lines) + '\n'
    return result


def write(job: Any, path: str | Path, settings: PostSettings | None = None) -> PostResult:
    """Post-process ``job`` into the file ``path``; return the result."""
    result = postprocess(job, settings)
    Path(path).write_text(result.text, encoding='utf-8')
    return result
