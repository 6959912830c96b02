"""The shop's drawings: DXFs from other tools read as they are.

* an R12 (AC1009) file as a laser CAM writes it: no HEADER section, so no ``$INSUNITS``
  (ezdxf fills its default, metres, into the document: the reader must not take it for the
  file's), loose LINE / ARC / CIRCLE / POLYLINE; the job file's ``dxf_units`` gives the units;
* a nest as nesting software writes it: one block of a part with a hole, INSERTed rotated,
  mirrored, scaled and through a nested block; exploded with ezdxf's own transformations;
* ``layers:`` selects the layers read; open contours (no marking layer here) are refused.

Every drawing is written here with ezdxf; ``ladrc job`` runs a job on each to its end.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
import subprocess
import sys

import ezdxf
from ezdxf.math import Vec3
from ladrc_sim.job.jobfile import JobError, load_job
from ladrc_sim.job.program import ProgramError, load_program
import numpy as np
import pytest
from shapely.geometry import Point

CHOICES = 'mm|cm|m|in'


# ------------------------------------------------------------------------------ drawings
def strip_header(text: str) -> str:
    """Return DXF ``text`` without its HEADER section (as a laser CAM's R12 file comes)."""
    lines = text.splitlines()
    pairs = list(zip(lines[0::2], lines[1::2], strict=True))
    out, skip = [], False
    for k, (code, value) in enumerate(pairs):
        if (code.strip(), value.strip()) == ('0', 'SECTION') and pairs[k + 1][1].strip() == \
                'HEADER':
            skip = True
        if not skip:
            out.append((code, value))
        elif (code.strip(), value.strip()) == ('0', 'ENDSEC'):
            skip = False
    return ''.join(f'{c}\n{v}\n' for c, v in out)


def r12_plate(msp) -> None:
    """Draw a 100 x 60 plate of loose lines with a round and an obround hole, and a part.

    The obround of arcs and lines, the part a 2D POLYLINE (R12 has no LWPOLYLINE).
    """
    pts = [(10, 10), (110, 10), (110, 70), (10, 70), (10, 10)]
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        msp.add_line(a, b)
    msp.add_circle((35, 40), 10)
    msp.add_line((60, 30), (80, 30))
    msp.add_arc((80, 40), 10, -90, 90)
    msp.add_line((80, 50), (60, 50))
    msp.add_arc((60, 40), 10, 90, 270)
    msp.add_polyline2d([(130, 10), (170, 10), (170, 50), (130, 50)], close=True)


def r12_file(path: Path, build=r12_plate, header: bool = False) -> Path:
    """Write an R12 drawing; without its HEADER section unless ``header``."""
    doc = ezdxf.new('R12')
    build(doc.modelspace())
    doc.saveas(str(path))
    if not header:
        path.write_text(strip_header(path.read_text()))
    return path


def square_100(msp) -> None:
    msp.add_polyline2d([(0, 0), (100, 0), (100, 100), (0, 100)], close=True)


@pytest.fixture
def headerless(tmp_path) -> Path:
    return r12_file(tmp_path / 'drawing.dxf')


def test_the_headerless_file_is_as_a_laser_cam_writes_it(headerless):
    text = headerless.read_text()
    assert 'HEADER' not in text and 'INSUNITS' not in text
    doc = ezdxf.readfile(str(headerless))
    assert doc.dxfversion == 'AC1009'
    # the trap: ezdxf fills a default header, $INSUNITS 6 (metres), into the document
    assert '$INSUNITS' in doc.header and doc.header['$INSUNITS'] == 6


PART_W, PART_H = 40.0, 20.0
HOLE_C, HOLE_R = (12.0, 10.0), 5.0
BASE = (2.0, 3.0)  # the block's base point (not its corner: the transform must take it)


def part_block(doc) -> None:
    """Add block PART: a 40 x 20 outline with one bulged corner, and a round hole.

    A mirror must flip the bulge; the block's entities are on layer 0 (they take their
    INSERT's layer).
    """
    blk = doc.blocks.new('PART', base_point=BASE)
    b = math.tan(math.pi / 8.0)  # a quarter-circle corner of radius 4
    blk.add_lwpolyline([(0, 0, 0), (PART_W - 4, 0, b), (PART_W, 4, 0), (PART_W, PART_H, 0),
                        (0, PART_H, 0)], format='xyb', close=True)
    blk.add_circle(HOLE_C, HOLE_R)


PLACED = (  # (insertion point, rotation, xscale, yscale): the modelspace INSERTs of PART
    ((20, 20), 0.0, 1.0, 1.0),       # as drawn
    ((110, 20), 30.0, 1.0, 1.0),     # rotated
    ((230, 20), 0.0, -1.0, 1.0),     # mirrored (negative x scale)
    ((250, 30), 15.0, 1.5, 0.8),     # scaled unevenly and rotated: the hole an ellipse
)
PAIR_AT, PAIR_ROT, PAIR_XS = (120, 140), 10.0, -1.0  # the nested block PAIR, mirrored


def nest_file(path: Path, marks: bool = False) -> Path:
    """Write the nest: PART inserted four ways, and PAIR (two PARTs) mirrored and rotated.

    In PAIR one PART is rotated 90 degrees; everything is placed on layer NEST. ``marks``: an
    open line on layer MARK (an engraving a CAM would put on a marking layer).
    """
    doc = ezdxf.new('R2010', units=4)
    part_block(doc)
    pair = doc.blocks.new('PAIR')
    pair.add_blockref('PART', (0, 0))
    pair.add_blockref('PART', (70, 0), dxfattribs={'rotation': 90})
    msp = doc.modelspace()
    for at, rot, xs, ys in PLACED:
        msp.add_blockref('PART', at, dxfattribs={'rotation': rot, 'xscale': xs, 'yscale': ys,
                                                 'layer': 'NEST'})
    msp.add_blockref('PAIR', PAIR_AT, dxfattribs={'rotation': PAIR_ROT, 'xscale': PAIR_XS,
                                                  'layer': 'NEST'})
    if marks:
        msp.add_line((300, 150), (340, 150), dxfattribs={'layer': 'MARK'})
    doc.saveas(str(path))
    return path


def ezdxf_explode(path: Path) -> list[tuple[Vec3, list]]:
    """Return, per placed PART, its hole's centre and three sharp corners, as ezdxf places them.

    By ezdxf's own ``Insert.virtual_entities()`` (recursively), independent of the reader's
    composed matrices.
    """
    doc = ezdxf.readfile(str(path))
    out = []

    def walk(entities):
        for e in entities:
            if e.dxftype() != 'INSERT':
                continue
            if e.dxf.name == 'PART':
                m = e.matrix44()
                corners = [m.transform(Vec3(x, y)) for x, y in ((0, 0), (0, PART_H),
                                                                (PART_W, PART_H))]
                for v in e.virtual_entities():
                    if v.dxftype() == 'CIRCLE':
                        out.append((v.ocs().to_wcs(v.dxf.center), corners))
                    elif v.dxftype() == 'ELLIPSE' and math.isclose(  # (not the corner's)
                            abs(v.dxf.end_param - v.dxf.start_param), math.tau):
                        out.append((Vec3(v.dxf.center), corners))
            else:
                walk(e.virtual_entities())

    walk(doc.modelspace())
    return out


# ------------------------------------------------------------------------------ units
def test_a_headerless_r12_file_without_dxf_units_is_refused_in_one_line(headerless):
    with pytest.raises(ProgramError) as exc:
        load_program(headerless, kerf_mm=0.2)
    assert str(exc.value) == (
        f'{headerless}: drawing units missing: R12 (AC1009) file without $INSUNITS (no '
        f'HEADER): give dxf_units: {CHOICES} in the job file')


def test_an_r12_file_with_a_header_says_its_header_has_no_insunits(tmp_path):
    path = r12_file(tmp_path / 'r12.dxf', header=True)  # ezdxf's R12 header: no $INSUNITS
    with pytest.raises(ProgramError) as exc:
        load_program(path, kerf_mm=0.2)
    assert str(exc.value) == (f'{path}: drawing units missing: R12 (AC1009) file without '
                              f'$INSUNITS in its HEADER: give dxf_units: {CHOICES} in the job '
                              'file')
    assert load_program(path, kerf_mm=0.2, units='mm').units_from == 'dxf_units'


@pytest.mark.parametrize('units, mm', [('in', 2540.0), ('mm', 100.0), ('cm', 1000.0)])
def test_dxf_units_scale_a_drawing_that_does_not_say(tmp_path, units, mm):
    path = r12_file(tmp_path / 'sq.dxf', square_100)
    p = load_program(path, kerf_mm=0.0, units=units)
    assert (p.units, p.units_from) == (units, 'dxf_units')
    assert p.parts[0].bounds == pytest.approx((0.0, 0.0, mm, mm))
    assert p.bounds_mm == pytest.approx((0.0, 0.0, mm, mm))


def test_the_files_units_and_dxf_units_must_agree(tmp_path):
    doc = ezdxf.new('R2010', units=4)
    square_100(doc.modelspace())
    path = tmp_path / 'mm.dxf'
    doc.saveas(str(path))
    with pytest.raises(ProgramError) as exc:
        load_program(path, kerf_mm=0.2, units='in')
    assert str(exc.value) == (f'{path}: drawing units disagree: the file says mm '
                              '($INSUNITS=4), the job file dxf_units: in')
    p = load_program(path, kerf_mm=0.0, units='mm')  # saying the same: fine
    assert (p.units, p.units_from) == ('mm', '$INSUNITS=4')
    assert p.parts[0].bounds == pytest.approx((0.0, 0.0, 100.0, 100.0))
    with pytest.raises(ProgramError, match=r"dxf_units 'ft' is not one of mm\|cm\|m\|in"):
        load_program(path, kerf_mm=0.2, units='ft')


def test_units_absurd_for_the_sheet_say_where_the_units_came_from(tmp_path):
    path = r12_file(tmp_path / 'sq.dxf', square_100)
    with pytest.raises(ProgramError, match=r'2540 x 2540 mm read as in \(dxf_units\), the '
                       r'sheet 400 x 300 mm'):
        load_program(path, kerf_mm=0.2, units='in', sheet_mm=(400.0, 300.0))


def test_the_headerless_plate_is_read_with_dxf_units(headerless):
    p = load_program(headerless, kerf_mm=0.0, units='mm')
    assert len(p.parts) == 2 and len(p.contours) == 4 and not p.ignored
    plate = p.parts[0]
    assert plate.bounds == pytest.approx((10.0, 10.0, 110.0, 70.0))
    want = 100 * 60 - math.pi * 100 - (20 * 20 + math.pi * 100)
    assert plate.area == pytest.approx(want, rel=1e-3)
    assert p.parts[1].area == pytest.approx(1600.0)


# ------------------------------------------------------------------------------ INSERTs
@pytest.fixture(scope='module')
def nest_dxf(tmp_path_factory) -> Path:
    return nest_file(tmp_path_factory.mktemp('nest') / 'inserts.dxf')


def test_a_nest_of_inserts_cuts_every_contour_of_every_placed_part(nest_dxf):
    p = load_program(nest_dxf, kerf_mm=0.0)
    assert len(p.parts) == 6 and len(p.contours) == 12 and not p.ignored
    assert sum(c.inner for c in p.contours) == 6 and p.layers == ('NEST',)
    part_area = PART_W * PART_H - (4 * 4 - math.pi * 4) - math.pi * HOLE_R ** 2
    scales = [abs(xs * ys) for _, _, xs, ys in PLACED] + [1.0, 1.0]
    assert sorted(q.area for q in p.parts) == pytest.approx(
        sorted(part_area * s for s in scales), rel=1e-3)


def test_the_exploded_nest_is_where_ezdxf_places_it(nest_dxf):
    p = load_program(nest_dxf, kerf_mm=0.0)
    placed = ezdxf_explode(nest_dxf)
    assert len(placed) == 6
    holes = [c.region.centroid for c in p.contours if c.inner]
    for centre, corners in placed:
        d = [math.dist((h.x, h.y), (centre.x, centre.y)) for h in holes]
        k = int(np.argmin(d))
        assert d[k] < 1e-3, (centre, d)  # the hole's centre where ezdxf puts it
        part = p.parts[p.contours[[i for i, c in enumerate(p.contours) if c.inner][k]].part]
        for v in corners:  # sharp corners of the outline: on the part's boundary
            assert part.exterior.distance(Point(v.x, v.y)) < 1e-6, v
    # a point worked by hand: the mirrored PART's far corner (block (40, 20), base (2, 3))
    (x0, y0), _, _, _ = PLACED[2]
    want = (x0 - (PART_W - BASE[0]), y0 + PART_H - BASE[1])
    assert any(q.exterior.distance(Point(want)) < 1e-9 for q in p.parts)


def test_a_mirrored_insert_mirrors_its_bulged_corner(nest_dxf):
    p = load_program(nest_dxf, kerf_mm=0.0)
    (x0, y0), _, _, _ = PLACED[2]
    mirrored = next(q for q in p.parts if q.bounds[2] == pytest.approx(x0 + BASE[0]))
    # the rounded corner is at the block's (40, 0): mirrored to the left, at the bottom
    lx, ly = x0 - (PART_W - BASE[0]), y0 - BASE[1]
    assert not mirrored.contains(Point(lx + 0.5, ly + 0.5))  # rounded off
    assert mirrored.contains(Point(lx + 0.5, ly + PART_H - 0.5))  # a sharp corner
    assert mirrored.area == pytest.approx(
        PART_W * PART_H - (16 - 4 * math.pi) - 25 * math.pi, rel=1e-3)  # (chords)


# ------------------------------------------------------------------------------ layers
def test_layers_select_what_is_read_and_open_contours_are_listed_or_refused(tmp_path):
    path = nest_file(tmp_path / 'marked.dxf', marks=True)
    listed = load_program(path, kerf_mm=0.2)  # cut_closed: the parts cut, the line listed
    assert len(listed.contours) == 12
    (line,) = listed.reading['open_contours']
    assert line['layer'] == 'MARK' and line['length_mm'] == pytest.approx(40.0)
    with pytest.raises(ProgramError) as exc:
        load_program(path, kerf_mm=0.2, open_contours='refuse')
    text = str(exc.value)
    assert '\n' not in text and 'a contour does not close' in text and "layer 'MARK'" in text
    assert line['entity'] in text and line['entity'].startswith('LINE #')
    p = load_program(path, kerf_mm=0.2, layers=('nest',))  # case-insensitive
    assert len(p.contours) == 12 and p.layers == ('NEST',)
    with pytest.raises(ProgramError) as exc:
        load_program(path, kerf_mm=0.2, layers=('CUT', 'NEST'))
    assert str(exc.value) == f'{path}: layers: CUT not in the drawing (its layers: MARK, NEST)'
    doc = ezdxf.readfile(str(path))  # a layer of text only: nothing to cut there
    doc.modelspace().add_text('PART 7', dxfattribs={'layer': 'LABELS'})
    doc.saveas(str(path))
    with pytest.raises(ProgramError, match='nothing to cut on layers LABELS: no line'):
        load_program(path, kerf_mm=0.2, layers=('LABELS',))


def test_a_block_entity_on_its_own_layer_keeps_it(tmp_path):
    doc = ezdxf.new('R2010', units=4)
    blk = doc.blocks.new('P')
    blk.add_lwpolyline([(0, 0), (30, 0), (30, 30), (0, 30)], close=True)  # layer 0
    blk.add_circle((15, 15), 5, dxfattribs={'layer': 'HOLES'})
    doc.modelspace().add_blockref('P', (10, 10), dxfattribs={'layer': 'PARTS'})
    path = tmp_path / 'own.dxf'
    doc.saveas(str(path))
    assert load_program(path, kerf_mm=0.0).layers == ('HOLES', 'PARTS')
    only = load_program(path, kerf_mm=0.0, layers=('PARTS',))
    assert len(only.contours) == 1 and only.parts[0].area == pytest.approx(900.0)


# ------------------------------------------------------------------------------ job files
JOB = """name: {name}
dxf: {dxf}
sheet:
  width_mm: {w}
  height_mm: {h}
  surface: {{tilt_x: 0.0005, wave_amp_mm: 0.2, wave_length_mm: 250}}
cut: {{kerf_mm: 0.2, lead_in_mm: 3.0}}
cnc: {{feed_mm_s: 80, rapid_mm_s: 500, accel_mm_s2: 2000, pierce_heights_mm: [3.0],
      pierce_dwell_s: [0.1]}}
sensor: {{noise_std_mm: 0.003, quant_mm: 0.001}}
start_xy: [5.0, 5.0]
seed: 1
{extra}"""


def job_file(tmp_path: Path, name: str, dxf: Path, extra: str = '', w: int = 200,
             h: int = 100) -> Path:
    path = tmp_path / f'{name}.yaml'
    path.write_text(JOB.format(name=name, dxf=dxf.name, w=w, h=h, extra=extra))
    return path


def ladrc_job(path: Path, capsys) -> tuple[int, str, str]:
    from ladrc_tools.cli import main

    rc = main(['job', str(path)])
    out, err = capsys.readouterr()
    return rc, out, err


def test_the_job_file_refusals_are_one_line_through_the_cli(tmp_path, capsys):
    dxf = r12_file(tmp_path / 'drawing.dxf')
    rc, out, err = ladrc_job(job_file(tmp_path, 'no_units', dxf), capsys)
    assert rc == 2 and out == '' and err.count('\n') == 1 and 'Traceback' not in err
    assert err.strip().endswith('drawing.dxf: drawing units missing: R12 (AC1009) file '
                                'without $INSUNITS (no HEADER): give dxf_units: mm|cm|m|in in '
                                'the job file')
    bad = job_file(tmp_path, 'bad_units', dxf, 'dxf_units: ft\n')
    with pytest.raises(JobError) as exc:
        load_job(bad)
    assert str(exc.value) == (f"{bad}: dxf_units: 'ft': one of {CHOICES.replace('|', ' | ')} "
                              "(the drawing's units where the DXF does not say them)")
    rc, out, err = ladrc_job(bad, capsys)
    assert rc == 2 and err.count('\n') == 1 and 'Traceback' not in err
    bad = job_file(tmp_path, 'bad_layers', dxf, 'layers: {CUT: 1}\n')
    with pytest.raises(JobError, match=r'layers: a list of DXF layer names'):
        load_job(bad)
    doc = ezdxf.new('R2010', units=4)
    square_100(doc.modelspace())
    doc.saveas(str(tmp_path / 'mm.dxf'))
    rc, out, err = ladrc_job(job_file(tmp_path, 'disagree', tmp_path / 'mm.dxf',
                                      'dxf_units: in\n'), capsys)
    assert rc == 2 and err.count('\n') == 1 and 'Traceback' not in err
    assert err.strip().endswith('mm.dxf: drawing units disagree: the file says mm '
                                '($INSUNITS=4), the job file dxf_units: in')


def test_the_refusal_through_the_console_script_exits_2_without_a_traceback(tmp_path):
    dxf = r12_file(tmp_path / 'drawing.dxf')
    job = job_file(tmp_path, 'no_units', dxf)
    done = subprocess.run([sys.executable, '-m', 'ladrc_tools.cli', 'job', str(job)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stdout == ''
    assert done.stderr.count('\n') == 1 and 'Traceback' not in done.stderr
    assert '(no HEADER): give dxf_units: mm|cm|m|in in the job file' in done.stderr


def figures(out: str) -> dict:
    return json.loads(out.strip().splitlines()[-1])


def test_ladrc_job_cuts_the_headerless_r12_drawing_to_its_end(tmp_path, capsys):
    dxf = r12_file(tmp_path / 'drawing.dxf')
    job = job_file(tmp_path, 'r12_plate', dxf, 'dxf_units: mm\n')
    assert load_job(job).program().units_from == 'dxf_units'
    rc, out, err = ladrc_job(job, capsys)
    f = figures(out)
    print(json.dumps({k: f[k] for k in ('job_time_s', 'pierces', 'contacts', 'faults',
                                        'min_gap_over_target_cutting', 'wall_s')}))
    assert rc == 0 and f['finished'] and not f['aborted'], f
    assert f['contacts'] == 0 and f['faults'] == 0 and f['pierces'] == 4
    assert len(f['min_true_gap_per_contour_mm']) == 4  # every contour cut
    assert f['min_gap_over_target_cutting'] >= 0.7


def test_ladrc_job_cuts_the_nest_of_inserts_to_its_end(tmp_path, capsys):
    dxf = nest_file(tmp_path / 'inserts.dxf', marks=True)
    job = job_file(tmp_path, 'insert_nest', dxf, 'layers: [NEST]\n', w=340, h=220)
    rc, out, err = ladrc_job(job, capsys)
    f = figures(out)
    print(json.dumps({k: f[k] for k in ('job_time_s', 'pierces', 'contacts', 'faults',
                                        'min_gap_over_target_cutting', 'wall_s')}))
    assert rc == 0 and f['finished'] and not f['aborted'], f
    assert f['contacts'] == 0 and f['faults'] == 0 and f['pierces'] == 12
    assert len(f['min_true_gap_per_contour_mm']) == 12  # every contour of every placed part
    assert f['min_gap_over_target_cutting'] >= 0.7


# ------------------------------------------------------------------------------ as a CAM reads
def entities_only(path: Path) -> Path:
    """Rewrite the DXF ``path`` as its ENTITIES section alone (an R12 file as CAMs write it)."""
    lines = path.read_text().splitlines()
    pairs = list(zip(lines[0::2], lines[1::2], strict=True))
    out, keep = [], False
    for k, (code, value) in enumerate(pairs):
        if (code.strip(), value.strip()) == ('0', 'SECTION'):
            keep = pairs[k + 1][1].strip() == 'ENTITIES'
        if keep:
            out.append((code, value))
        if keep and (code.strip(), value.strip()) == ('0', 'ENDSEC'):
            keep = False
    path.write_text(''.join(f'{c}\n{v}\n' for c, v in out) + '  0\nEOF\n')
    return path


GAPS_MM = (0.1, 0.25, 0.446, 0.3)  # where each side of the plate stops short of the next


def gapped_inch_plate(path: Path) -> Path:
    """Write a 4 x 2.5 in plate of four LINEs, each stopping short (GAPS_MM), and a hole.

    R12, ENTITIES only: no HEADER, no units (the job file says inches).
    """
    doc = ezdxf.new('R12')
    msp = doc.modelspace()
    corners = [(0.5, 0.5), (4.5, 0.5), (4.5, 3.0), (0.5, 3.0)]
    for k, gap in enumerate(GAPS_MM):
        (ax, ay), (bx, by) = corners[k], corners[(k + 1) % 4]
        n = math.hypot(bx - ax, by - ay)
        msp.add_line((ax, ay), (bx - (bx - ax) / n * gap / 25.4, by - (by - ay) / n * gap / 25.4))
    msp.add_circle((1.5, 1.75), 0.4)
    doc.saveas(str(path))
    return entities_only(path)


def stray_line_nest(path: Path) -> Path:
    """Write an AC1015 nest with a lone 3.5 mm LINE beside its first part.

    The part: one closed LWPOLYLINE with bulges, two circles and a small round hole in it; a
    second part beside it.
    """
    doc = ezdxf.new('R2000', units=4)
    msp = doc.modelspace()
    b = math.tan(math.pi / 8.0)  # quarter-circle corners of radius 5
    msp.add_lwpolyline([(15, 10, 0), (65, 10, b), (70, 15, 0), (70, 45, b), (65, 50, 0),
                        (15, 50, b), (10, 45, 0), (10, 15, b)], format='xyb', close=True)
    msp.add_circle((25, 30), 8)
    msp.add_circle((50, 30), 8)
    msp.add_circle((62, 43), 2.5)  # smaller than the nozzle: cut locked
    msp.add_lwpolyline([(90, 10), (130, 10), (130, 50), (90, 50)], close=True)
    msp.add_line((75, 20), (75, 23.5))  # the stray line
    doc.saveas(str(path))
    return path


def duplicated_plate(path: Path) -> Path:
    """Write a square plate with a hole, drawn over itself, and a stub.

    The square as LINEs and as an LWPOLYLINE, a line over part of one side, the circle twice,
    a 0.2 mm line apart.
    """
    doc = ezdxf.new('R2010', units=4)
    msp = doc.modelspace()
    corners = [(10, 10), (70, 10), (70, 60), (10, 60)]
    for k in range(4):
        msp.add_line(corners[k], corners[(k + 1) % 4])
    msp.add_lwpolyline(corners, close=True)        # the same outline again
    msp.add_line((20, 10), (50, 10))                # over part of the bottom side
    msp.add_circle((40, 35), 10)
    msp.add_circle((40, 35), 10)                    # drawn twice
    msp.add_line((80, 30), (80.2, 30))              # a stub
    doc.saveas(str(path))
    return path


def letter(msp, x: float, y: float, kind: str, h: float = 5.0) -> float:
    """Draw one engraved letter of closed SPLINEs at (x, y); return its advance.

    'O': an outline and its counter; 'I': a bar of four open splines end to end; 'D': a lobe.
    """
    if kind == 'O':
        for rx, ry, n in ((1.75, h / 2, 12), (0.8, h / 2 - 1.0, 10)):
            fit = [(x + 1.75 + rx * math.cos(a), y + h / 2 + ry * math.sin(a))
                   for a in np.linspace(0.0, math.tau, n, endpoint=False)]
            msp.add_spline(fit).closed = True
        return 4.2
    if kind == 'I':
        c = [(x, y), (x + 1.2, y), (x + 1.2, y + h), (x, y + h)]
        for a, b in zip(c, c[1:] + c[:1], strict=True):
            msp.add_spline([a, ((a[0] + b[0]) / 2 + 0.02, (a[1] + b[1]) / 2), b])
        return 2.0
    fit = [(x + 1.8 + 1.8 * math.cos(a) * (1 + 0.2 * math.sin(3 * a)), y + h / 2 + h / 2 *
            math.sin(a)) for a in np.linspace(0.0, math.tau, 16, endpoint=False)]
    msp.add_spline(fit).closed = True
    return 4.2


def text_plate(path: Path, rows: int = 2, text: str = 'OIDOIDODOI') -> Path:
    """Write a plate with engraved text: rows of SPLINE letters among holes.

    Six round holes of 8 mm, two slots, letters 5 mm high and 0.8 mm apart: contours smaller
    than the sensor's field, each pierced next to the voids of the letters cut before it.
    """
    doc = ezdxf.new('R2010', units=4)
    msp = doc.modelspace()
    msp.add_lwpolyline([(10, 10), (130, 10), (130, 80), (10, 80)], close=True)
    for i in range(6):
        msp.add_circle((25 + 18 * i, 68), 4)
    for x in (25, 95):
        msp.add_lwpolyline([(x, 20, 0, 0, 0), (x + 20, 20, 0, 0, 1), (x + 20, 26, 0, 0, 0),
                            (x, 26, 0, 0, 1)], format='xyseb', close=True)
    for r in range(rows):
        x = 25.0
        for ch in text:
            x += letter(msp, x, 36 + 8 * r, ch)
    doc.saveas(str(path))
    return path


def test_a_stray_open_line_is_listed_and_every_closed_contour_cut(tmp_path):
    path = stray_line_nest(tmp_path / 'stray.dxf')
    p = load_program(path, kerf_mm=0.2)
    assert len(p.contours) == 5 and len(p.parts) == 2
    (line,) = p.reading['open_contours']
    assert line['layer'] == '0' and line['length_mm'] == pytest.approx(3.5)
    assert sorted(line['ends_mm']) == [[75.0, 20.0], [75.0, 23.5]]
    with pytest.raises(ProgramError) as exc:  # refuse: one line naming the entity
        load_program(path, kerf_mm=0.2, open_contours='refuse')
    text = str(exc.value)
    assert '\n' not in text and text.startswith(f"{path}: {line['entity']} on layer '0': ")
    assert 'open_contours: cut_closed' in text and 'join_tolerance_mm' in text


def test_sub_mm_gaps_of_an_inch_r12_entities_only_file_are_joined_and_reported(tmp_path):
    path = gapped_inch_plate(tmp_path / 'gaps.dxf')
    assert path.read_text().splitlines()[3].strip() == 'ENTITIES'  # nothing before it
    p = load_program(path, kerf_mm=0.2, units='in')
    assert p.units == 'in' and len(p.contours) == 2
    assert p.reading['joins'] == 4
    assert p.reading['largest_gap_closed_mm'] == pytest.approx(max(GAPS_MM), abs=1e-3)
    assert p.parts[0].area == pytest.approx(4.0 * 2.5 * 25.4 ** 2 - math.pi * (0.4 * 25.4) ** 2,
                                            rel=1e-3)
    # a tolerance below the widest gap: that contour stays open, and no closed one is left
    with pytest.raises(ProgramError) as exc:
        load_program(path, kerf_mm=0.2, units='in', join_tolerance_mm=0.2,
                     open_contours='refuse')
    assert 'LINE #' in str(exc.value) and "on layer '0'" in str(exc.value)


def test_duplicates_overlaps_and_stubs_are_removed_and_counted(tmp_path):
    p = load_program(duplicated_plate(tmp_path / 'dup.dxf'), kerf_mm=0.2)
    assert len(p.contours) == 2 and len(p.parts) == 1
    r = p.reading
    # the four LINEs under the LWPOLYLINE drawn over them, the overlap, the second circle
    assert r['duplicates_removed'] == 6 and r['short_dropped'] == 1 and r['open_contours'] == []
    assert p.parts[0].area == pytest.approx(60 * 50 - math.pi * 100, rel=1e-3)


def test_the_text_plate_orders_small_contours_away_from_voids_and_pierces_over_material(
        tmp_path):
    path = text_plate(tmp_path / 'text.dxf')
    p = load_program(path, kerf_mm=0.2, small_contour_mm=8.0)
    cut: list = []
    for c in p.contours:
        pierce = Point(c.pierce_xy)
        assert not any(r.contains(pierce) for r in cut)  # never over a void already cut
        if c.inner:
            assert c.region.contains(pierce)  # over the slug's material
        cut.append(c.region)
    small = [c for c in p.contours if c.inner and c.size_mm < 8.0]
    assert len(small) > 20 and p.contours.index(small[0]) >= 6  # the large holes first
    nearest = load_program(path, kerf_mm=0.2)  # nearest next only
    assert [c.pierce_xy for c in nearest.contours] != [c.pierce_xy for c in p.contours]


def job_figures_of(rc_out) -> dict:
    rc, out, _ = rc_out
    assert rc == 0, out
    return figures(out)


TEXT_JOB = """name: text_plate
dxf: text.dxf
sheet:
  width_mm: 140
  height_mm: 90
  surface: {tilt_x: 0.0005, wave_amp_mm: 0.2, wave_length_mm: 250}
cut: {kerf_mm: 0.2, lead_in_mm: 3.0}
cnc: {feed_mm_s: 80, rapid_mm_s: 500, accel_mm_s2: 2000, pierce_heights_mm: [3.0],
      pierce_dwell_s: [0.1]}
sensor: {noise_std_mm: 0.003, quant_mm: 0.001}
start_xy: [5.0, 5.0]
seed: 1
"""


def test_ladrc_job_cuts_the_text_plate_locked_and_unlocked_it_is_held_as_an_edge(tmp_path,
                                                                               capsys):
    text_plate(tmp_path / 'text.dxf')
    job = tmp_path / 'text.yaml'
    job.write_text(TEXT_JOB)
    from ladrc_tools.cli import main

    rc = main(['job', str(job)])
    f = job_figures_of((rc, *capsys.readouterr()))
    n = len(load_job(job).program().contours)
    print(json.dumps({k: f[k] for k in ('job_time_s', 'pierces', 'locked_contours', 'contacts',
                                        'faults', 'min_gap_over_target_cutting', 'wall_s')}))
    assert f['finished'] and not f['aborted'] and f['faults'] == 0 and f['contacts'] == 0
    assert f['pierces'] == n and len(f['min_true_gap_per_contour_mm']) == n
    assert f['locked_contours'] > 20 and f['min_gap_over_target_cutting'] >= 0.7
    # the same plate with every contour followed: the edge guard takes the voids around a
    # letter's pierce for a sheet edge (the reading widens as at an edge): held, not followed
    main(['job', str(job), '--off', 'small_contours'])
    off = figures(capsys.readouterr()[0])
    assert off['locked_contours'] == 0 and off['contacts'] == 0
    assert off['faults'] >= 1 or off['holds']['void_lock']['count'] > 0, off


def test_ladrc_job_cuts_the_shop_drawings_to_the_end_and_reports_what_it_read(tmp_path,
                                                                           capsys):
    from ladrc_tools.cli import main

    jobs = [
        (job_file(tmp_path, 'stray', stray_line_nest(tmp_path / 'stray.dxf'), w=150, h=70), 5),
        (job_file(tmp_path, 'gaps', gapped_inch_plate(tmp_path / 'gaps.dxf'),
                  'dxf_units: in\njoin_tolerance_mm: 0.5\n', w=130, h=90), 2),
        (job_file(tmp_path, 'dup', duplicated_plate(tmp_path / 'dup.dxf'), w=100, h=80), 2),
    ]
    for job, n in jobs:
        rc = main(['job', str(job)])
        out, _ = capsys.readouterr()
        f = job_figures_of((rc, out, ''))
        print(json.dumps({k: f[k] for k in ('job', 'pierces', 'locked_contours', 'contacts',
                                            'faults', 'drawing')}))
        assert f['finished'] and f['faults'] == 0 and f['contacts'] == 0 and f['pierces'] == n
        assert len(f['min_true_gap_per_contour_mm']) == n
        if f['job'] == 'stray':  # the open line in the log and the figures
            assert len(f['drawing']['open_contours']) == 1 and f['locked_contours'] == 1
            assert 'open contour not cut: LINE #' in out.splitlines()[0]
        if f['job'] == 'gaps':
            assert f['drawing']['joins'] == 4
            assert f['drawing']['largest_gap_closed_mm'] == pytest.approx(0.446, abs=1e-3)
        if f['job'] == 'dup':
            assert f['drawing']['duplicates_removed'] == 6
    # the stray-line nest with the CNC apart from the world, as with the CNC node
    rc = main(['job', str(jobs[0][0]), '--separate-cnc'])
    f = job_figures_of((rc, *capsys.readouterr()))
    assert f['finished'] and f['faults'] == 0 and f['contacts'] == 0 and f['pierces'] == 5
    assert f['locked_contours'] == 1 and f['separate_cnc']


def test_job_file_reading_keys_are_checked_in_one_line(tmp_path):
    dxf = stray_line_nest(tmp_path / 'stray.dxf')
    bad = job_file(tmp_path, 'bad', dxf, 'open_contours: mark_them\n')
    with pytest.raises(JobError) as exc:
        load_job(bad)
    assert '\n' not in str(exc.value) and 'open_contours' in str(exc.value)
    bad = job_file(tmp_path, 'bad2', dxf, 'join_tolerance_mm: 9\n')
    with pytest.raises(JobError, match='join_tolerance_mm'):
        load_job(bad)
    refuse = job_file(tmp_path, 'refuse', dxf, 'open_contours: refuse\n')
    with pytest.raises(JobError, match=r"LINE #\w+ on layer '0': a contour does not close"):
        load_job(refuse).program()
