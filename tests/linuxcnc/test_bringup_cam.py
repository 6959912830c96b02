"""``bringup --cnc linuxcnc`` with the shop's CAM programs (docs/linuxcnc.md, "CAM programs").

* A SheetCam-style program (tests/data/linuxcnc/sheetcam_style.ngc: G20 inches, N-numbers,
  Z-only lines, arc lead-ins, modal arcs, ``o<touchoff> call`` per contour, M05 and a dwell)
  as a G-code job, its origin placed on the sheet by the job's ``dxf_origin_mm`` (G54): run to
  its end with the height controller, one pierce per touchoff call with the call's values (mm),
  no contact.
* A program calling an undefined subroutine: LinuxCNC's interpreter refuses it before the
  run, within a second of the program's open; the bring-up says so in one line naming the
  line, the figures name LinuxCNC's error and its line, exit 1; no node is started.

Free-running: a timing guard of the simulation may stop a run early, safely
(tests/support/linuxcnc_runs.py); the end is asked of a run no guard stopped (``ATTEMPTS``).
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
import time

from linuxcnc_runs import ATTEMPTS, DATA, bringup_linuxcnc, report, summary, timing_abort
import pytest
from system import require

pytestmark = pytest.mark.ros
ROOT = Path(__file__).resolve().parents[2]
MM = 25.4


@pytest.fixture(scope='module')
def ros_env() -> dict[str, str]:
    """Return the environment of the ROS tests (own ROS_DOMAIN_ID, localhost discovery)."""
    spec = importlib.util.spec_from_file_location(
        'ros_conftest_for_linuxcnc_cam', ROOT / 'tests' / 'ros' / 'conftest.py')
    ros = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ros)  # sets ROS_DOMAIN_ID / localhost discovery (or skips)
    return dict(os.environ)


def domain(env: dict[str, str]) -> list[str]:
    return ['--domain-id', env['ROS_DOMAIN_ID']]


def test_a_sheetcam_program_runs_to_its_end_one_pierce_per_touchoff(tmp_path, ros_env):
    require('linuxcnc')
    calls = DATA.joinpath('sheetcam_style.ngc').read_text().count('o<touchoff> call')
    for attempt in range(1, ATTEMPTS + 1):
        rc, f, err = bringup_linuxcnc(DATA / 'sheetcam_style.yaml', tmp_path / f'run{attempt}',
                                      *domain(ros_env), timeout_s=300.0, env=ros_env)
        report(f'attempt {attempt}: exit {rc} {summary(f)}')
        assert f, err
        assert f['contacts'] == 0 and f['linuxcnc']['bridge']['moved_before_ready'] == 0
        if f.get('finished') or not timing_abort(f):
            break
    bridge = f['linuxcnc']['bridge']
    assert rc == 0 and f['finished'] and not f['aborted'], (summary(f), err)
    assert f['pierces'] == bridge['pierces'] == calls == 3
    assert [c['pierce']['from'] for c in bridge['contours']] == ['program'] * 3
    first = bridge['contours'][0]
    assert first['pierce']['heights_mm'] == pytest.approx([0.15 * MM])
    assert first['pierce']['dwell_s'] == pytest.approx([0.2])
    assert first['pierce']['cut_gap_mm'] == pytest.approx(0.06 * MM)
    # N0130 X1.75 Y1.5 (inches) on the sheet: the job's dxf_origin_mm [20, 20] as G54
    assert first['pierce_xy_mm'] == pytest.approx([1.75 * MM + 20.0, 1.5 * MM + 20.0],
                                                  abs=1e-3)
    # (no bar on the gap: a user's program carries no edge-ahead holds, docs/linuxcnc.md)
    assert f['min_true_gap_cutting_mm'] > 0.0 and bridge['leapfrogs'] == 3
    assert 'program_error' not in f['linuxcnc']


def test_an_undefined_subroutine_ends_the_run_with_linuxcncs_error_and_line(tmp_path,
                                                                            ros_env):
    require('linuxcnc')
    job = tmp_path / 'job'
    job.mkdir()
    program = job / 'nosuch.ngc'
    program.write_text('N10 G20 G90 G40\nN20 G00 X1 Y1\nN30 o<touchoff> call [0.15] [0.4] '
                       '[0.06]\nN40 G01 X2 Y1 F100\nN50 M05\nN60 G00 X3 Y1\n'
                       'N70 o<nosuch> call [1] [2]\nN80 G00 X0 Y0\nN90 M30\n', encoding='utf-8')
    text = DATA.joinpath('sheetcam_style.yaml').read_text()
    (job / 'nosuch.yaml').write_text(text.replace('sheetcam_style.ngc', 'nosuch.ngc')
                                     .replace('name: sheetcam_style', 'name: nosuch'),
                                     encoding='utf-8')
    t0 = time.monotonic()
    rc, f, err = bringup_linuxcnc(job / 'nosuch.yaml', tmp_path / 'run', *domain(ros_env),
                                  timeout_s=300.0, env=ros_env)
    wall_s = time.monotonic() - t0
    failed = f['linuxcnc']['program_error']
    report(f'refused in {failed["after_s"]:.3f} s after the open; the bring-up took '
           f'{wall_s:.1f} s; {failed}')
    assert rc == 1 and f['finished'] is False and f['aborted']
    assert failed['line'] == 7 and failed['when'] == 'open'
    assert failed['program'] == str(program) and failed['text']
    assert failed['after_s'] < 1.0
    assert f['exit_codes'] == {} and f['linuxcnc']['bridge'] == {}  # no node ran, nothing cut
    last = [ln for ln in err.splitlines() if ln.startswith('bringup: ')][-1]
    assert str(program) in last and 'line 7 ' in last  # one line: the program and its line


def test_a_program_that_cuts_nothing_is_not_finished(tmp_path, ros_env):
    """Rapids only, no M3 and no touchoff call: the run says so, exit 1."""
    require('linuxcnc')
    job = tmp_path / 'job'
    job.mkdir()
    (job / 'rapids.ngc').write_text('G21 G90\nG0 X40 Y40\nG0 X80 Y60\nG0 X5 Y5\nM2\n',
                                    encoding='utf-8')
    text = DATA.joinpath('sheetcam_style.yaml').read_text()
    (job / 'rapids.yaml').write_text(text.replace('sheetcam_style.ngc', 'rapids.ngc')
                                     .replace('name: sheetcam_style', 'name: rapids'),
                                     encoding='utf-8')
    rc, f, err = bringup_linuxcnc(job / 'rapids.yaml', tmp_path / 'run', *domain(ros_env),
                                  timeout_s=300.0, env=ros_env)
    report(f'exit {rc} {summary(f)}')
    assert rc == 1 and f['finished'] is False and f['aborted'], summary(f)
    assert f['linuxcnc']['bridge']['pierces'] == 0 and f['contacts'] == 0
    assert 'program_error' not in f['linuxcnc']
    assert [ln for ln in err.splitlines() if ln.startswith('bringup: ')][-1]


def test_an_error_while_the_program_runs_ends_the_job(tmp_path, ros_env):
    """A rapid past the table (X 3500 mm) after a cut: LinuxCNC stops the program.

    The bridge ends the job (aborted, the head lifted); the run says so with the line, exit 1.
    """
    require('linuxcnc')
    job = tmp_path / 'job'
    job.mkdir()
    (job / 'past.ngc').write_text('G21 G90\nG0 X40 Y40\nM3 $0 S1\nG1 X80 F2400\nM5 $0\n'
                                  'G0 X3500 Y40\nG0 X5 Y5\nM2\n', encoding='utf-8')
    text = DATA.joinpath('sheetcam_style.yaml').read_text()
    (job / 'past.yaml').write_text(text.replace('sheetcam_style.ngc', 'past.ngc')
                                   .replace('name: sheetcam_style', 'name: past'),
                                   encoding='utf-8')
    for attempt in range(1, ATTEMPTS + 1):
        rc, f, err = bringup_linuxcnc(job / 'past.yaml', tmp_path / f'run{attempt}',
                                      *domain(ros_env), timeout_s=300.0, env=ros_env)
        report(f'attempt {attempt}: exit {rc} {summary(f)}')
        assert f, err
        assert f['contacts'] == 0 and rc == 1 and f['finished'] is False
        if 'program_error' in f['linuxcnc'] or not timing_abort(f):
            break
    failed = f['linuxcnc']['program_error']
    report(f'stopped {failed["after_s"]:.3f} s after cycle start: {failed}')
    assert failed['when'] == 'run' and failed['line'] == 6
    bridge = f['linuxcnc']['bridge']
    assert bridge['pierces'] == 1 and bridge['aborted'] and not bridge['finished']
    assert max(c['pierce_xy_mm'][0] for c in bridge['contours']) < 3001.0
    last = [ln for ln in err.splitlines() if ln.startswith('bringup: ')][-1]
    assert 'line 6 ' in last
