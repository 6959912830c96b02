"""The post-processor's G-code both ways, and G-code jobs .

* The post-processor (``ladrc_tools/cam/postprocess.py``) writes what a laser CAM writes for
  LinuxCNC: one ``M3 $0``/``M5 $0`` per contour, ``G64 P`` (``G61`` for exact stop), the
  hold stretches between ``M62 P2`` and ``M63``/``M65 P2``.
* Round trip: LinuxCNC's own interpreter (its ``gcode`` module, on the system Python:
  ``ladrc_linuxcnc.machine.read_program``) reads the program back; every contour's path, in
  order, is the part program's (lead-in and contour, vertex by vertex, to the 4 decimals
  written), at the job's feed, with the spindle (the beam request) on along it and off over
  the rapids.
* The Z filter: a program with Z words is refused by the interpreter of an XY machine, and
  read once filtered.
* A job file's ``gcode:`` program: read by no parser here; ``ladrc job`` refuses it in one line.
"""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys

from ladrc_linuxcnc.machine import read_program
from ladrc_linuxcnc.z_filter import filter_line
from ladrc_sim.job.jobfile import JobError, find_job, load_job
from ladrc_tools.cam.postprocess import PostSettings, postprocess
from linuxcnc_runs import DATA, small_job
import numpy as np
import pytest
from system import require


@pytest.fixture(scope='module')
def small(tmp_path_factory) -> Path:
    return small_job(tmp_path_factory.mktemp('small'))


def test_one_beam_request_per_contour_and_the_holds(small):
    job = find_job(small)
    result = postprocess(job)
    lines = result.text.splitlines()
    n = len(job.program().contours)
    assert sum(ln.startswith('M3 $0') for ln in lines) == n == len(result.contour_lines)
    assert sum(ln.startswith('M5 $0') for ln in lines) == n
    assert 'G64 P0.05' in lines and 'M52 P1 (adaptive feed: the height controller asks)' in lines
    on = sum(ln.startswith('M62 P2') for ln in lines)
    off = sum(ln.startswith(('M63 P2', 'M65 P2')) for ln in lines)
    assert on == off == sum(len(h) for h in result.holds_mm) and on >= n  # each contour's end
    assert lines[-1] == 'M2' and all(lines[k - 1] == 'M3 $0 S1' for k in result.contour_lines)
    exact = postprocess(job, PostSettings(blend_mm=0.0, holds=False)).text.splitlines()
    assert 'G61' in exact and not any(ln.startswith('G64') for ln in exact)
    assert not any(ln.startswith('M62') for ln in exact)


def test_linuxcnc_reads_the_part_program_back(small, tmp_path):
    require('linuxcnc')
    job = find_job(small)
    result = postprocess(job)
    ngc = tmp_path / 'small.ngc'
    ngc.write_text(result.text, encoding='utf-8')
    read = read_program(ngc)
    assert read['result'] <= read['min_error'], read['error']
    moves = read['moves']
    contours = job.program().contours
    rapids = [m for m in moves if m[0] == 'G0']
    assert len(rapids) == len(contours)
    feed = job.cnc.feed_mm_s * 60.0
    k = -1
    cut: list[list] = [[] for _ in contours]
    for m in moves:
        if m[0] == 'G0':
            k += 1
            assert m[5] == 5, m  # the beam is not requested over a rapid
            assert m[2:4] == pytest.approx(contours[k].pierce_xy, abs=1e-4)
            continue
        assert m[0] == 'G1' and m[5] == 3 and m[4] == pytest.approx(feed), m
        cut[k].append(m[2:4])
    for c, got in zip(contours, cut, strict=True):
        want = np.vstack((c.lead_in_mm, c.points_mm[1:]))[1:]
        got = np.array(got)
        # every vertex of the program is reached, in order (a hold's split adds points on it)
        i = 0
        for p in want:
            while i < len(got) and np.hypot(*(got[i] - p)) > 1e-4:
                i += 1
            assert i < len(got), (p, got[-3:])
        assert np.allclose(got[-1], c.points_mm[-1], atol=1e-4)


def test_the_z_filter_makes_a_program_with_z_readable(tmp_path):
    assert filter_line('G1 X10 Y5 Z-1.2 F600\n') == ('G1 X10 Y5 (Z-1.2) F600\n', 1)
    assert filter_line('G0 Z[#<_ini[axis_z]max_limit> - 5] ; up\n')[1] == 1
    require('linuxcnc')
    raw = tmp_path / 'with_z.ngc'
    raw.write_text('G21 G90\nG0 Z10\nG0 X5 Y5\nM3 $0 S1\nG1 X20 Y5 Z-0.5 F600\nM5 $0\nM2\n',
                   encoding='utf-8')
    refused = read_program(raw)
    assert refused['result'] > refused['min_error'] and 'z' in refused['error'].lower()
    filtered = tmp_path / 'filtered.ngc'
    from ladrc_linuxcnc import z_filter

    r = subprocess.run([sys.executable, z_filter.__file__, str(raw)], capture_output=True,
                       text=True, check=True)
    assert 'ladrc z filter: 2 Z word(s) commented out on 2 line(s)' in r.stderr
    filtered.write_text(r.stdout, encoding='utf-8')
    read = read_program(filtered)
    assert read['result'] <= read['min_error'], read['error']
    # the Z-only line keeps its G0: a rapid of no length in XY (the head's Z is not LinuxCNC's)
    assert [m[:4] for m in read['moves']] == [['G0', 2, 0.0, 0.0], ['G0', 3, 5.0, 5.0],
                                             ['G1', 5, 20.0, 5.0]]


def test_a_gcode_job_is_linuxcncs_to_read(tmp_path, capsys):
    job = load_job(DATA / 'plasmatest.yaml')
    assert job.gcode == DATA / 'plasmatest.ngc' and job.dxf is None
    assert job.program().contours == () and job.time_budget_s(job.program()) == 400.0
    from ladrc_tools.cli import main

    assert main(['job', str(DATA / 'plasmatest.yaml')]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'runs under LinuxCNC only' in err
    both = tmp_path / 'both.yaml'
    both.write_text('name: x\ndxf: a.dxf\ngcode: b.ngc\nsheet: {width_mm: 100, height_mm: 100}\n')
    with pytest.raises(JobError, match='dxf or gcode: the program, one of them'):
        load_job(both)


def test_ladrc_post_writes_once_and_says_what_it_wrote(small, tmp_path, capsys):
    from ladrc_tools.cli import main

    out = tmp_path / 'small.ngc'
    assert main(['post', str(small), '-o', str(out), '--blend-mm', '0.1']) == 0
    assert 'G64 P0.1' in out.read_text() and '"contours": 3' in capsys.readouterr().out
    assert main(['post', str(small), '-o', str(out)]) == 2
    assert 'exists already' in capsys.readouterr().err
    assert main(['post', str(DATA / 'plasmatest.yaml'), '-o', str(tmp_path / 'x.ngc')]) == 2
    assert 'already is G-code' in capsys.readouterr().err
