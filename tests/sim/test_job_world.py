"""The job world: part programs from DXF, job files, and shipped jobs run headless end to end.

A shipped job runs the simulated CNC, the follow controller and the cut sheet together
(job/runner.py); the figures asserted are the CNC-partner issue's must-holds on these jobs.
"""

from __future__ import annotations

from pathlib import Path

import ezdxf
from ladrc_follow.control.follow import FollowController
from ladrc_follow.control.params import ControllerParams, params_from_dict
from ladrc_sim.job.jobfile import JobError, load_job
from ladrc_sim.job.program import ProgramError, load_program
from ladrc_sim.job.runner import run_job
import numpy as np
import pytest
from shapely.geometry import Point

JOBS = (Path(__file__).resolve().parents[2] / 'ros2_ws' / 'src' / 'ladrc_sim' / 'ladrc_sim'
        / 'job' / 'jobs')


def drawing(tmp_path: Path, units: int | None, build, name: str = 'd.dxf') -> Path:
    doc = ezdxf.new('R2010')
    if units is not None:
        doc.header['$INSUNITS'] = units
    build(doc.modelspace())
    path = tmp_path / name
    doc.saveas(str(path))
    return path


def square_with_hole(msp) -> None:
    msp.add_lwpolyline([(10, 10), (60, 10), (60, 60), (10, 60)], close=True)
    msp.add_circle((35, 35), 8)


# ------------------------------------------------------------------------------ programs
def test_drawing_units_must_be_set_and_inches_are_scaled(tmp_path):
    with pytest.raises(ProgramError, match=r'd\.dxf: drawing units missing.*INSUNITS=0'):
        load_program(drawing(tmp_path, 0, square_with_hole), kerf_mm=0.2)
    inch = load_program(drawing(tmp_path, 1, square_with_hole, 'in.dxf'), kerf_mm=0.0)
    assert inch.units == 'in' and inch.parts[0].bounds == pytest.approx(
        (254.0, 254.0, 1524.0, 1524.0))
    with pytest.raises(ProgramError, match='units absurd for the sheet'):
        load_program(drawing(tmp_path, 1, square_with_hole, 'in2.dxf'), kerf_mm=0.2,
                     sheet_mm=(100.0, 100.0))


def test_loose_lines_are_chained_and_an_open_chain_is_refused(tmp_path):
    def loose(msp, close=True):
        pts = [(0, 0), (40, 0), (40, 30), (0, 30)] + ([(0, 0)] if close else [(0, 5)])
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            msp.add_line(b, a) if a[0] == 40 else msp.add_line(a, b)  # some reversed

    p = load_program(drawing(tmp_path, 4, loose), kerf_mm=0.0)
    assert len(p.parts) == 1 and p.parts[0].area == pytest.approx(1200.0)
    with pytest.raises(ProgramError, match=r'does not close: its ends \(0\.000, 5\.000\)'):
        load_program(drawing(tmp_path, 4, lambda m: loose(m, False), 'open.dxf'), kerf_mm=0.0,
                     open_contours='refuse')


def test_kerf_on_the_scrap_side_holes_first_and_lead_ins_in_the_scrap(tmp_path):
    p = load_program(drawing(tmp_path, 4, square_with_hole), kerf_mm=0.4, lead_in_mm=3.0)
    hole, outline = p.contours
    assert hole.inner and not outline.inner  # the hole before its part
    # the outline runs outside the part by half the kerf, the hole inside the hole
    assert outline.region.exterior.length == pytest.approx(200.0 + 0.2 * 2 * np.pi, rel=1e-3)
    assert hole.region.area == pytest.approx(np.pi * 7.8 ** 2, rel=2e-3)
    assert Point(hole.pierce_xy).within(hole.region)
    assert not Point(outline.pierce_xy).within(p.parts[0])
    assert np.allclose(outline.points_mm[0], outline.points_mm[-1])


def test_a_bulged_polyline_is_flattened_within_tolerance(tmp_path):
    from ladrc_sim.job.dxf_library import _rounded_square

    p = load_program(drawing(tmp_path, 4, lambda m: _rounded_square(m, 0, 0, 30, 3)),
                     kerf_mm=0.0)
    assert p.parts[0].area == pytest.approx(30 * 30 - (4 - np.pi) * 9, rel=5e-3)


def test_the_shipped_nest_is_as_its_job_says():
    job = load_job(JOBS / 'nest_16.yaml')
    p = job.program()
    assert len(p.parts) == 16
    border = [c for c in p.contours if not c.inner and min(
        c.region.bounds[0], c.region.bounds[1], 1000 - c.region.bounds[2]) < 5.0]
    assert len(border) >= 3
    for i, a in enumerate(p.parts):
        for b in p.parts[i + 1:]:
            assert a.distance(b) >= 3.0 - 1e-9
    # nearest next: the rapids are shorter than in the drawing's order
    assert any(c.micro_joints for c in p.contours if not c.inner)


def test_a_drawing_from_another_tool_is_read_and_placed_by_the_work_offset():
    job = load_job(JOBS / 'ezdxf_forms.yaml')  # forms.dxf of the ezdxf repository
    p = job.program()
    assert p.units == 'mm' and len(p.contours) == 40 and len(p.parts) == 23 and not p.ignored
    assert sum(c.inner for c in p.contours) == 40 - 23  # the holes inside parts, cut first
    as_drawn = load_program(job.dxf, kerf_mm=job.kerf_mm)  # no sheet, no offset
    ox, oy = job.dxf_origin_mm
    assert p.bounds_mm == pytest.approx(np.add(as_drawn.bounds_mm, (ox, oy, ox, oy)))
    assert as_drawn.bounds_mm[1] < 0.0 < p.bounds_mm[1]  # drawn below y = 0, cut on the sheet


def test_a_contour_off_the_sheet_is_refused_in_one_line(tmp_path):
    text = (JOBS / 'ezdxf_forms.yaml').read_text().replace(
        'dxf: ezdxf_forms.dxf', f'dxf: {JOBS / "ezdxf_forms.dxf"}')
    bad = tmp_path / 'off.yaml'
    bad.write_text(text.replace('[280, 1050]', '[600, 1050]'))
    with pytest.raises(JobError) as err:
        load_job(bad).program()
    assert 'is not on the sheet' in str(err.value) and '\n' not in str(err.value)
    bad.write_text(text.replace('[280, 1050]', '[280, .nan]'))
    with pytest.raises(JobError, match=r'dxf_origin_mm\[1\]'):
        load_job(bad)


def test_a_bad_job_file_is_one_line(tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('name: x\ndxf: none.dxf\nsheet: {width_mm: 100, height_mm: 100}\n')
    with pytest.raises(JobError, match=r'bad\.yaml: dxf: .*none\.dxf does not exist'):
        load_job(bad)
    bad.write_text(f'name: x\ndxf: {JOBS / "plate_holes.dxf"}\nsheet: {{width_mm: 400, '
                   'height_mm: 300}\ncnc: {feed_mm_s: fast}\n')
    with pytest.raises(JobError, match=r'cnc\.feed_mm_s: expected a number'):
        load_job(bad)


# ------------------------------------------------------------------------------ jobs
def run(name: str, cnc: dict | None = None, controller: dict | None = None):
    job = load_job(JOBS / f'{name}.yaml').with_changes(cnc, controller)
    params = params_from_dict(dict(job.controller)) if job.controller else ControllerParams()
    return run_job(job, FollowController(params))


@pytest.fixture(scope='module')
def plate():
    return run('plate_holes')


def test_the_plate_job_runs_to_its_end_without_contact_and_above_the_bar(plate):
    f = plate.figures
    assert f['finished'] and not f['aborted'] and f['faults'] == 0 and f['contacts'] == 0
    assert f['pierces'] == 6 and len(f['min_true_gap_per_contour_mm']) == 6
    assert f['min_gap_over_target_cutting'] >= 0.7
    assert f['holds']['edge_ahead']['count'] >= 1  # before the end of a contour: its own kerf


def test_the_thin_warped_sheet_runs_to_its_end_above_the_bar():
    f = run('thin_warped').figures  # sag 2 mm, a corner warped up 6 mm, feed 200 mm/s
    assert f['finished'] and f['faults'] == 0 and f['contacts'] == 0 and f['pierces'] == 6
    assert f['min_gap_over_target_cutting'] >= 0.7


def test_in_position_before_xy_moves_in_every_contour(plate):
    s = plate.series
    cut = (s['segment'] == 2).astype(int)
    starts = np.flatnonzero(np.diff(cut) == 1) + 1
    assert len(starts) == 6
    for k in starts:  # the first tick of each cut: following, not piercing, at the cut gap
        assert s['state'][k - 1] in (3, 4) and s['substate'][k - 1] in (0, 4)
        assert abs(s['true_gap_mm'][k] - 1.0) < 0.1


def test_corner_lock_holds_the_dive_at_corners_smaller(plate):
    off = run('plate_holes', controller={'cnc.corner_lock': False})
    on_f, off_f = plate.figures, off.figures
    assert on_f['holds']['corner_lock']['count'] > 0 == off_f['holds']['corner_lock']['count']
    assert on_f['corner_max_down_mm'] < off_f['corner_max_down_mm']


def test_leapfrog_saves_job_time_against_lift_stop_move(plate):
    lift = run('plate_holes', cnc={'leapfrog': False})
    assert lift.figures['finished'] and lift.figures['contacts'] == 0
    assert plate.figures['job_time_s'] < lift.figures['job_time_s']


def test_a_tipped_part_ends_in_the_retract_and_a_feed_hold():
    r = run('tipping_pair')
    s, f = r.series, r.figures
    assert f['contacts'] >= 1 and f['faults'] == 1 and 'collision' in f['aborted']
    k = int(np.argmax(s['state'] == 5))
    assert np.all(s['command_mm_s'][k:] >= 0.0) and s['command_mm_s'][k:].max() > 10.0
    assert s['nozzle_mm'][-1] > s['nozzle_mm'][k] + 1.0  # retracted


def test_a_job_is_deterministic():
    a, b = run('tipping_pair'), run('tipping_pair')
    for key in a.series:
        assert np.array_equal(a.series[key], b.series[key], equal_nan=True), key


def test_a_job_bag_replays_bit_for_bit(tmp_path):
    from ladrc_tools.cli_job import load, write_bag
    from ladrc_tools.cli_job import run as run_cli
    from ladrc_tools.offline.replay import compare, load_recording, replay

    job = load('tipping_pair')
    result = run_cli(job, [], record_internals=True)
    write_bag(job, result, tmp_path / 'bag')
    rec = load_recording(tmp_path / 'bag')
    got = compare(rec, replay(rec))
    assert got['ticks'] == len(result.series['t_s'])
    assert got['mismatches'] == 0 and got['internal_mismatch_ticks'] == 0
    assert {'pierce', 'leapfrog'} <= {e.name for e in rec.events}
    assert int(np.max(result.internals['cnc_seq'])) > 0  # the CNC's values went through
    from ladrc_bags import open_bag
    from ladrc_tools.offline.report import analyse

    with open_bag(tmp_path / 'bag') as bag:
        report, _ = analyse(bag)
    assert report['holds']['pierce']['count'] >= 1 and report['holds']['retract']['count'] == 1


def test_ladrc_report_draws_and_measures_the_job_from_its_bag_alone(tmp_path):
    import json

    from ladrc_tools.cli_job import load, write_bag
    from ladrc_tools.cli_job import run as run_cli
    from ladrc_tools.offline.report import write_report

    job = load('tipping_pair')
    result = run_cli(job, [], record_internals=True)
    write_bag(job, result, tmp_path / 'bag')
    out = write_report(tmp_path / 'bag', tmp_path / 'report')
    assert (out / 'job.png').is_file()
    got = json.loads((out / 'report.json').read_text())['job']
    want = result.figures
    assert got['name'] == 'tipping_pair'
    f = got['figures']
    for key in ('pierces', 'faults', 'contacts', 'min_true_gap_cutting_mm', 'job_time_s',
                'holds', 'finished'):
        assert f[key] == want[key], key
    assert f['aborted'].startswith('the height controller faulted: collision')
    # segment times from the CNC values the controller used: a CNC cycle per boundary at most
    for key in ('cutting_s', 'rapid_s', 'pierce_s'):
        assert abs(f[key] - want[key]) <= 0.002 * 8, key
    assert '## Job `tipping_pair`' in (out / 'report.md').read_text()


def test_a_job_on_a_terminal_shows_its_contours_cut_and_piped_shows_nothing(monkeypatch):
    import io

    from ladrc_tools.cli_job import contour_progress, load
    from ladrc_tools.cli_job import run as run_cli

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    job = load('tipping_pair')  # two contours; the second ends in the collision (not cut)
    for stream, shown in ((Terminal(), True), (io.StringIO(), False)):
        monkeypatch.setattr('sys.stderr', stream)
        run_cli(job, [], progress=contour_progress('ladrc job tipping_pair'))
        text = stream.getvalue()
        if shown:
            assert text == '\rladrc job tipping_pair: contour 1/2 cut\n', text
        else:
            assert text == ''
