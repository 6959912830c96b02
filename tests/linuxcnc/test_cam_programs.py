"""CAM programs as the shop has them, run as they are (docs/linuxcnc.md, "CAM programs").

* The Z filter keeps every word of a line but its Z words: a Z-only ``G0``/``G1``/``G2``/``G3``
  line (with an N-number, with an F word) keeps its G code, N and F, and the next ``X.. Y..``
  line keeps its modal motion, as LinuxCNC's own interpreter reads the filtered program.
* ``o<touchoff> call [pierce height] [pierce delay] [cut height]`` (the shipped subroutine,
  ``[RS274NGC]SUBROUTINE_PATH``): LinuxCNC's interpreter reads a SheetCam-style program to its
  end; under LinuxCNC each call is one cut request whose pierce values reach the bridge in mm
  (a G20 program's inches converted) at the pierce point, the job's G54 offset applied; a
  value out of range is LinuxCNC's error on the call's line.
* The bridge's rules: the program's pierce where it gave one, the job's otherwise; a program
  that ended without a cut is not finished; LinuxCNC's program error ends the job in any phase.
* A run-time error (a move past the table) stops the program within a second: the display's
  error names LinuxCNC's text and the line, the bridge sees the program error.
* A DXF2GCODE-style program (G21, G92 X0 Y0, M3 (plasma on), G4 P1.5, circles as two G2
  halves with I/J, spaces inside numbers) runs to its end under LinuxCNC.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import subprocess

from ladrc_linuxcnc import protocol as p
from ladrc_linuxcnc.machine import (
    SYSTEM_PYTHON,
    LinuxCnc,
    RunSettings,
    config_dir,
    render_run_config,
)
from ladrc_linuxcnc.sequence import BridgeParams, Sequencer
from ladrc_linuxcnc.z_filter import filter_line
from linuxcnc_runs import DATA, Client, hal_u32, resume
import pytest
from system import require

MM = 25.4
RUN = p.F_RUNNING | p.F_MACHINE_ON | p.F_HOMED
GCODE_PATH = Path(__import__('ladrc_linuxcnc.gcode_path').gcode_path.__file__)


def filtered(text: str) -> str:
    """Return a program through the Z filter, line by line (as LinuxCNC's [FILTER] runs it)."""
    return ''.join(filter_line(line)[0] for line in text.splitlines(keepends=True))


def interpret(path: Path, tmp: Path) -> dict:
    """Return LinuxCNC's interpreter's reading of ``path`` with the shipped subroutines."""
    ini = tmp / 'interp.ini'
    ini.write_text(f'[RS274NGC]\nSUBROUTINE_PATH = {config_dir() / "subroutines"}\n',
                   encoding='utf-8')
    r = subprocess.run([SYSTEM_PYTHON, str(GCODE_PATH), str(path)], capture_output=True,
                       text=True, timeout=120, cwd=tmp, check=False,
                       env={**os.environ, 'INI_FILE_NAME': str(ini)})
    assert r.returncode == 0 and r.stdout.strip(), r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


# ---- the Z filter, per modal group -----------------------------------------------------------
@pytest.mark.parametrize(('line', 'out'), [
    ('G00 Z0.8\n', 'G00 (Z0.8)\n'),
    ('N0210 G00 Z0.8\n', 'N0210 G00 (Z0.8)\n'),
    ('G01 Z0.15 F20\n', 'G01 (Z0.15) F20\n'),
    ('N0150 G01 Z-0.02 F20\n', 'N0150 G01 (Z-0.02) F20\n'),
    ('G1 Z2\n', 'G1 (Z2)\n'),
    ('G02 Z-1 I5 J0\n', 'G02 (Z-1) I5 J0\n'),
    ('N70 G03 Z1 I-5 J0 F300\n', 'N70 G03 (Z1) I-5 J0 F300\n'),
    ('Z5\n', '(Z5)\n'),
    ('N0090 G00 Z0.8 (safe height)\r\n', 'N0090 G00 (Z0.8) (safe height)\r\n'),
    # codes whose axis words are their arguments: with Z alone they go with it
    ('G92 Z0\n', '(G92) (Z0)\n'),
    ('G91 G28 Z0\n', 'G91 (G28) (Z0)\n'),
    ('G38.2 Z-5 F100\n', '(G38.2) (Z-5) F100\n'),
    ('G92 X0 Y0 Z0\n', 'G92 X0 Y0 (Z0)\n'),
])
def test_only_the_z_words_become_comments(line, out):
    assert filter_line(line) == (out, 1)


MODAL = {  # group: (the Z-only line, the next line without a G word, its move, arc turn)
    'G0': ('N30 G00 Z0.8', 'N40 X20 Y10', 'G0', None),
    'G1': ('N30 G01 Z-0.5 F150', 'N40 X20 Y10', 'G1', None),
    'G2': ('N30 G02 Z-0.5 I5 J0 F150', 'N40 X20 Y10 I5 J0', 'ARC', -1),
    'G3': ('N30 G03 Z1 I5 J0', 'N40 X20 Y10 I5 J0 F150', 'ARC', 1),
}


@pytest.mark.parametrize('group', sorted(MODAL))
def test_the_next_line_keeps_its_modal_motion(group, tmp_path):
    """The line after a Z-only line moves as that line's G code says, at its F."""
    require('linuxcnc')
    z_line, next_line, kind, turn = MODAL[group]
    # (the motion before the Z-only line is another group's: the filter must keep the G code)
    before = 'N20 G03 X10 Y10 I5 J0 F900' if group != 'G3' else 'N20 G01 X10 Y10 F900'
    program = tmp_path / f'{group}.ngc'
    program.write_text(filtered(f'N10 G21 G90\nN15 G00 X0 Y10\n{before}\n{z_line}\n'
                                f'{next_line}\nN50 M2\n'), encoding='utf-8')
    read = interpret(program, tmp_path)
    assert read['result'] <= read['min_error'], read['error']
    line5 = [m for m in read['moves'] if m[1] == 5]
    assert line5 and {m[0] for m in line5} == {kind}, read['moves']
    assert line5[-1][2:4] == pytest.approx([20.0, 10.0], abs=1e-9)
    if kind != 'G0':
        assert line5[-1][4] == pytest.approx(150.0)  # the F of the Z-only line or its own
    if turn is not None:
        assert line5[-1][8] == turn  # clockwise (G2) or counter-clockwise (G3)


def test_a_lone_g28_z_is_no_move(tmp_path):
    """``G28 Z0`` without Z would send XY home: it goes into the comment with its Z."""
    require('linuxcnc')
    program = tmp_path / 'g28.ngc'
    program.write_text(filtered('G21 G90\nG0 X50 Y40\nG91 G28 Z0\nG90\nG92 Z0\n'
                                'G38.2 Z-5 F100\nG0 X60 Y40\nM2\n'), encoding='utf-8')
    read = interpret(program, tmp_path)
    assert read['result'] <= read['min_error'], read['error']
    assert [m[:4] for m in read['moves']] == [['G0', 2, 50.0, 40.0], ['G0', 7, 60.0, 40.0]]


# ---- the SheetCam-style program and o<touchoff> --------------------------------------------
SHEETCAM = DATA / 'sheetcam_style.ngc'
TOUCHOFF_LINES = [k for k, ln in enumerate(SHEETCAM.read_text().splitlines(), 1)
                  if 'o<touchoff> call' in ln]


def test_linuxcncs_interpreter_reads_the_sheetcam_program_to_its_end(tmp_path):
    require('linuxcnc')
    program = tmp_path / 'sheetcam.ngc'
    program.write_text(filtered(SHEETCAM.read_text()), encoding='utf-8')
    read = interpret(program, tmp_path)
    assert read['result'] <= read['min_error'], read['error']
    assert read['cut_requests'] == len(TOUCHOFF_LINES) == 3  # one per touchoff (M03 S1: none)
    lines = SHEETCAM.read_text().splitlines()
    moves = read['moves']
    at = {m[1]: m for m in moves}
    # the rapids after the Z-only G00 lines (after arcs, after lines): their X.. Y.. lines
    # without a G word are rapids with the beam off
    for k in (13, 23, 35, 47):
        assert lines[k - 1].split()[1][0] == 'X' and at[k][0] == 'G0' and at[k][5] == 5, at[k]
    # the modal arcs (no G word) are arcs, with the spindle on (the touchoff's M3)
    arcs = [m for m in moves if m[0] == 'ARC']
    assert len(arcs) == 6 and all(m[5] == 3 for m in arcs)
    assert [m[1] for m in arcs] == [16, 17, 18, 27, 28, 29]
    # inches: the outline's corner X4.75 Y2.0 (program coordinates, no offset in the reader)
    assert at[40][2:4] == pytest.approx([4.75 * MM, 2.0 * MM])
    assert at[40][0] == 'G1' and at[40][4] == pytest.approx(150 * MM)  # F150 in/min


def test_a_touchoff_value_out_of_range_is_linuxcncs_error_on_its_line(tmp_path):
    require('linuxcnc')
    program = tmp_path / 'bad_touchoff.ngc'
    program.write_text('N10 G20 G90\nN20 G00 X1 Y1\nN30 o<touchoff> call [3.0] [0.4] [0.06]\n'
                       'N40 G01 X2 Y1 F60\nN50 M05\nN60 M2\n', encoding='utf-8')
    read = interpret(program, tmp_path)
    assert read['result'] > read['min_error'] and read['line'] == 3  # 3 in = 76.2 mm


def test_each_touchoff_call_is_one_cut_request_with_its_values_in_mm(tmp_path):
    """Under LinuxCNC (this test the bridge): the M3 edges, where, with which pierce."""
    require('linuxcnc')
    offset = (20.0, 20.0)
    ini = render_run_config(tmp_path / 'run', RunSettings(
        program=SHEETCAM, home_xy_mm=(5.0, 5.0), work_offset_mm=offset, rapid_mm_s=1000.0,
        accel_mm_s2=5000.0))
    lc = LinuxCnc(ini)
    lc.start(timeout_s=180.0, lock_wait_s=1800.0)
    try:
        c = Client(lc.socket_path)
        requests: list[p.LcncSample] = []

        def answer(s: p.LcncSample) -> bool:
            spindle = s.flag(p.F_SPINDLE_ON)
            if spindle and not c.flags & p.O_AT_SPEED:
                requests.append(s)
            c.flags = p.O_HEIGHT_READY | ((p.O_AT_SPEED | p.O_BEAM) if spindle else 0)
            return bool(requests) and s.flag(p.F_IDLE) and not s.flag(p.F_RUNNING)

        c.run_until(answer, 120.0, 'the SheetCam-style program to its end')
        lc.wait_event('end', 30.0)
        events = lc.events()
        assert not [e for e in events if e['event'] in ('error', 'error_channel')], events
        filt = next(e for e in events if e['event'] == 'filter')
        assert Path(filt['output']).read_text().splitlines() == filtered(
            SHEETCAM.read_text()).splitlines()  # line for line: LinuxCNC's lines are the file's
        expected = [((1.75, 1.5), (0.15, 0.2, 0.06)), ((1.5, 3.2), (0.12, 0.15, 0.05)),
                    ((3.0, 0.25), (0.15, 0.2, 0.06))]
        assert len(requests) == len(TOUCHOFF_LINES) == 3
        for s, ((x, y), (h, t, cut)) in zip(requests, expected, strict=True):
            assert (s.x_mm, s.y_mm) == pytest.approx((x * MM + offset[0], y * MM + offset[1]),
                                                     abs=1e-6)
            assert (s.pierce_height_mm, s.pierce_delay_s, s.cut_height_mm) == pytest.approx(
                (h * MM, t, cut * MM))
        end = c.samples[-1][1]
        assert (end.x_mm, end.y_mm) == pytest.approx(offset, abs=1e-6)  # N0470 X0 Y0
    finally:
        lc.stop()


# ---- the bridge's rules ----------------------------------------------------------------------
def sample(seq, flags, x=0.0, pierce=(0.0, 0.0, 0.0)):
    return p.LcncSample(seq, seq * 1_000_000, x, 0.0, 0.0, 50.0, 0.0, 0.0, 1.0, 0, seq, flags,
                        *pierce)


ANSWER = {'state': 0, 'substate': 0, 'gap_seq': 5, 'velocity_mm_s': 0.0}


def test_the_program_pierce_else_the_jobs():
    seq = Sequencer(BridgeParams(socket_path='/x', pierce_heights_mm=(3.0, 2.0),
                                 pierce_dwell_s=(0.1, 0.1), cut_gap_mm=1.0, thc_delay_s=0.05))
    seq.step(sample(1, RUN), ANSWER, 0.0, 0.0)
    out = seq.step(sample(2, RUN | p.F_SPINDLE_ON, pierce=(3.81, 0.4, 1.524)), ANSWER, 0.0, 0.1)
    assert out.commands == [('pierce', {'heights_mm': (3.81,), 'dwell_s': (0.4,),
                                        'cut_gap_mm': 1.524, 'thc_delay_s': 0.05})]
    seq.step(sample(3, RUN), ANSWER, 0.0, 0.2)  # M5 before the pierce was done
    out = seq.step(sample(4, RUN | p.F_SPINDLE_ON), ANSWER, 0.0, 0.3)  # a plain M3
    assert out.commands == [('pierce', {'heights_mm': (3.0, 2.0), 'dwell_s': (0.1, 0.1),
                                        'cut_gap_mm': 1.0, 'thc_delay_s': 0.05})]
    assert [c['pierce']['from'] for c in seq.log.contours] == ['program', 'job']


def test_a_program_that_cut_nothing_is_not_finished():
    seq = Sequencer(BridgeParams(socket_path='/x'))
    seq.step(sample(1, RUN), ANSWER, 0.0, 0.0)
    seq.step(sample(2, RUN), ANSWER, 0.0, 0.1)  # rapids only, no M3
    seq.step(sample(3, p.F_MACHINE_ON | p.F_HOMED | p.F_IDLE), ANSWER, 0.0, 0.2)
    assert seq.log.pierces == 0 and not seq.log.finished and seq.log.aborted
    assert seq.end_ready(ANSWER, 0.3)


@pytest.mark.parametrize('phase', ['before the run', 'cutting'])
def test_linuxcncs_program_error_ends_the_job(phase):
    seq = Sequencer(BridgeParams(socket_path='/x'))
    ans = dict(ANSWER)
    t = 0.0
    if phase == 'cutting':
        seq.step(sample(1, RUN | p.F_SPINDLE_ON), ans, 0.0, t)
        ans = {**ans, 'state': 3, 'substate': 0, 'in_position': True, 'ready_to_move': True}
        seq.step(sample(2, RUN | p.F_SPINDLE_ON), {**ans, 'substate': 3}, 0.0, 0.1)
        out = seq.step(sample(3, RUN | p.F_SPINDLE_ON), ans, 0.0, 0.2)
        assert out.outputs.flags & p.O_AT_SPEED
        t = 0.3
    idle = p.F_MACHINE_ON | p.F_HOMED | p.F_IDLE
    out = seq.step(sample(9, idle | p.F_PROGRAM_ERROR), ans, 0.0, t)
    assert seq.log.aborted and not seq.log.finished
    assert not out.outputs.flags & (p.O_AT_SPEED | p.O_BEAM | p.O_HEIGHT_READY)
    names = [c[0] for c in out.commands]
    assert names == (['lift'] if phase == 'cutting' else ['stop_follow'])


# ---- LinuxCNC stops a program that fails while it runs ---------------------------------------
def test_a_move_past_the_table_stops_the_program_within_a_second(tmp_path):
    """LinuxCNC's motion refuses a rapid past X's limit (3001 mm): the program stops.

    Its interpreter reads the program without an error (it knows no limits): the error comes
    while it runs; the display aborts the program and names LinuxCNC's text and the line.
    """
    require('linuxcnc')
    program = tmp_path / 'past_the_table.ngc'
    program.write_text('G21 G90\nG0 X20 Y20\nM3 $0 S1\nG1 X60 F1200\nM5 $0\nG0 X3500 Y20\n'
                       'G0 X20 Y40\nM2\n', encoding='utf-8')
    ini = render_run_config(tmp_path / 'run', RunSettings(program=program, home_xy_mm=(10, 10),
                                                          rapid_mm_s=500.0, accel_mm_s2=5000.0))
    lc = LinuxCnc(ini)
    lc.start(timeout_s=180.0, lock_wait_s=1800.0)
    try:
        c = Client(lc.socket_path)
        t_flag = []

        def answer(s: p.LcncSample) -> bool:
            spindle = s.flag(p.F_SPINDLE_ON)
            c.flags = p.O_HEIGHT_READY | ((p.O_AT_SPEED | p.O_BEAM) if spindle else 0)
            if s.flag(p.F_PROGRAM_ERROR) and not t_flag:
                t_flag.append(s.t_ns)
            return bool(t_flag) and not s.flag(p.F_RUNNING) and s.current_vel_mm_s == 0.0

        c.run_until(answer, 60.0, 'the program error on the pins and the program stopped')
        stopped_s = (c.samples[-1][1].t_ns - t_flag[0]) * 1e-9
        err = lc.wait_event('error', 10.0)  # (written once the abort is done)
        events = lc.events()
        assert err['when'] == 'run' and err['line'] == 6 and err['program'] == str(program)
        run = next(e for e in events if e['event'] == 'run')
        cut_s = 40.0 / 20.0  # the G1 before the rapid: 40 mm at 20 mm/s
        after_cut_s = err['t'] - run['t'] - cut_s
        print(f'error {err["t"] - run["t"]:.3f} s after cycle start ({after_cut_s:.3f} s after '
              f'the cut before it), program stopped {stopped_s:.3f} s after the pin')
        assert after_cut_s < 1.0 and stopped_s < 1.0
        x_max = max(s.x_mm for _, s in c.samples)
        assert x_max < 61.0  # never on the way to X3500
        assert lc.proc.wait(timeout=60) is not None  # the display ended: LinuxCNC shut down
    finally:
        lc.stop()


RESUMES = 2


def test_a_dxf2gcode_program_runs_to_its_end(tmp_path):
    """G92 X0 Y0 makes where the head stands (the job's start) the program's origin."""
    require('linuxcnc')
    home = (60.0, 40.0)
    ini = render_run_config(tmp_path / 'run', RunSettings(
        program=DATA / 'dxf2gcode_style.ngc', home_xy_mm=home, rapid_mm_s=1000.0,
        accel_mm_s2=5000.0))
    lc = LinuxCnc(ini)
    lc.start(timeout_s=180.0, lock_wait_s=1800.0)
    try:
        c = Client(lc.socket_path)
        requests: list[p.LcncSample] = []

        def answer(s: p.LcncSample) -> bool:
            spindle = s.flag(p.F_SPINDLE_ON)
            if spindle and not c.flags & p.O_AT_SPEED:
                requests.append(s)
            c.flags = p.O_HEIGHT_READY | ((p.O_AT_SPEED | p.O_BEAM) if spindle else 0)
            return (bool(requests) and s.flag(p.F_IDLE) and not s.flag(p.F_RUNNING)
                    or s.flag(p.F_PAUSED))

        # A stall of this machine past the link timeout or the watchdog (0.5 s) pauses the
        # program, as it must; the operator's resume goes on. Only a pause the component
        # counted as a trip (its safe-trips / watchdog-trips pins) is resumed, RESUMES times at
        # most (measured: one such pause in three fresh-clone runs of make test).
        resumes = 0
        while True:
            c.run_until(answer, 120.0, 'the DXF2GCODE-style program to its end')
            if not c.samples[-1][1].flag(p.F_PAUSED):
                break
            trips = hal_u32(lc, 'ladrc.safe-trips') + hal_u32(lc, 'ladrc.watchdog-trips')
            assert trips > resumes, f'paused without a link or watchdog trip ({trips} trips)'
            resumes += 1
            assert resumes <= RESUMES, f'{resumes} stalls past 0.5 s in one program'
            resume(lc)
            c.run_until(lambda s: not s.flag(p.F_PAUSED), 10.0, 'running after the resume')
        print(f'resumed after a stall: {resumes} time(s) (budget {RESUMES})')
        lc.wait_event('end', 30.0)
        events = lc.events()
        assert not [e for e in events if e['event'] in ('error', 'error_channel')], events
        points = [v for s in requests for v in (s.x_mm - home[0], s.y_mm - home[1])]
        assert points == pytest.approx([10.0, 2.0, 35.5, -12.0, -17.394, 155.953], abs=1e-3)
        assert all(s.pierce_height_mm == 0.0 for s in requests)  # no touchoff: the job's
        # the last circle, two G2 halves about (-8.697, 155.953): its top reached (an arc)
        ys = [s.y_mm - home[1] for _, s in c.samples]
        assert max(ys) == pytest.approx(155.953 + 8.697, abs=0.01)
        end = c.samples[-1][1]
        assert (end.x_mm, end.y_mm) == pytest.approx(home, abs=1e-3)
    finally:
        lc.stop()


def test_the_bring_ups_verdict_on_the_displays_events():
    from ladrc_bringup.linuxcnc_run import early_end, program_error

    events = [{'t': 10.0, 'event': 'filter'}, {'t': 10.5, 'event': 'check', 'cut_requests': 3},
              {'t': 12.0, 'event': 'run'}, {'t': 15.0, 'event': 'idle', 'line': 17}]
    assert early_end(events, {'pierces': 1}) and not early_end(events, {'pierces': 3})
    assert program_error(events) is None
    refused = [*events[:2], {'t': 10.2, 'event': 'error', 'text': 'x (line 7)',
                             'program_error': 'x', 'line': 7, 'when': 'open', 'program': 'p'}]
    assert program_error(refused) == {'text': 'x', 'line': 7, 'when': 'open', 'program': 'p',
                                      'after_s': 0.2}
    stopped = [*events[:3], {'t': 14.5, 'event': 'error', 'text': 'y', 'program_error': 'y',
                             'line': 6, 'when': 'run', 'program': 'p'}]
    assert program_error(stopped)['after_s'] == 2.5
