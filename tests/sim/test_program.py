"""Part programs from DXF (job/program.py) and the drawings of the job library (dxf_library.py).

Drawings are written into ``tmp_path``: by the library, or small ones built here with ezdxf.
"""

from __future__ import annotations

import math
from pathlib import Path

import ezdxf
from ladrc_sim.job import dxf_library
from ladrc_sim.job.program import Program, ProgramError, load_program
import numpy as np
import pytest
from shapely.geometry import LinearRing, LineString, Point, Polygon

SHEET_MM = (1000.0, 500.0)  # the nest's sheet


def drawing(tmp_path: Path, build, units: int | None = 4, name: str = 'd.dxf') -> Path:
    doc = ezdxf.new('R2010')
    if units is None:
        del doc.header['$INSUNITS']  # (ezdxf.new sets metres)
    else:
        doc.header['$INSUNITS'] = units
    build(doc.modelspace())
    path = tmp_path / name
    doc.saveas(str(path))
    return path


def square_with_hole(msp) -> None:
    msp.add_lwpolyline([(10, 10), (60, 10), (60, 60), (10, 60)], close=True)
    msp.add_circle((35, 35), 8)


def rect(msp, x: float, y: float, w: float, h: float) -> None:
    msp.add_lwpolyline([(x, y), (x + w, y), (x + w, y + h), (x, y + h)], close=True)


def rapids_mm(contours) -> float:
    """Return the rapid travel from the origin through every contour's pierce, end to pierce."""
    here, total = np.zeros(2), 0.0
    for c in contours:
        total += math.dist(here, c.pierce_xy)
        here = c.points_mm[-1]
    return total


def one_line(exc: pytest.ExceptionInfo, path: Path) -> str:
    text = str(exc.value)
    assert '\n' not in text and 'Traceback' not in text and text.startswith(str(path))
    return text


@pytest.fixture(scope='module')
def nest_dxf(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp('nest') / 'nest_16.dxf'
    dxf_library.nest(path)
    return path


@pytest.fixture(scope='module')
def nest(nest_dxf) -> Program:
    return load_program(nest_dxf, kerf_mm=0.25, micro_joint_mm=0.5, micro_joints_per_part=2,
                        sheet_mm=SHEET_MM)


# ------------------------------------------------------------------------------ units
@pytest.mark.parametrize('units', [0, None])
def test_a_drawing_without_units_is_refused_naming_the_file(tmp_path, units):
    path = drawing(tmp_path, square_with_hole, units)
    with pytest.raises(ProgramError) as exc:
        load_program(path, kerf_mm=0.2)
    text = one_line(exc, path)
    assert 'drawing units missing: R2010 (AC1024) file ' in text
    assert ('with $INSUNITS=0 (unitless)' if units == 0 else 'without $INSUNITS in its HEADER'
            ) in text and text.endswith('give dxf_units: mm|cm|m|in in the job file')


def test_an_unsupported_unit_is_refused(tmp_path):
    path = drawing(tmp_path, square_with_hole, 2)  # feet
    with pytest.raises(ProgramError, match=r'units not supported \(\$INSUNITS=2, feet\)'):
        load_program(path, kerf_mm=0.2)


@pytest.mark.parametrize('code, name, scale', [(1, 'in', 25.4), (5, 'cm', 10.0),
                                               (6, 'm', 1000.0), (4, 'mm', 1.0)])
def test_the_drawing_is_scaled_to_millimetres(tmp_path, code, name, scale):
    p = load_program(drawing(tmp_path, square_with_hole, code), kerf_mm=0.0)
    assert (p.units, p.scale_to_mm) == (name, scale)
    assert p.parts[0].bounds == pytest.approx((10 * scale, 10 * scale, 60 * scale, 60 * scale))
    assert p.bounds_mm == pytest.approx(p.parts[0].bounds)
    assert p.parts[0].area == pytest.approx((2500 - math.pi * 64) * scale ** 2, rel=1e-3)


def test_units_absurd_for_the_sheet_are_refused_with_the_numbers(tmp_path):
    inch = drawing(tmp_path, square_with_hole, 1)  # 1270 mm wide on a 400 mm sheet
    with pytest.raises(ProgramError) as exc:
        load_program(inch, kerf_mm=0.2, sheet_mm=(400.0, 300.0))
    text = one_line(exc, inch)
    assert 'units absurd for the sheet' in text and '1270 x 1270 mm' in text and '400' in text
    tiny = drawing(tmp_path, lambda m: rect(m, 0, 0, 0.05, 0.05), 6, 'tiny.dxf')  # 0.05 m
    assert load_program(tiny, kerf_mm=0.2).parts[0].area == pytest.approx(2500.0)
    micro = drawing(tmp_path, lambda m: rect(m, 0, 0, 0.5, 0.5), 4, 'micro.dxf')
    with pytest.raises(ProgramError, match='units absurd for the sheet: the drawing is 0.5 x'):
        load_program(micro, kerf_mm=0.2, sheet_mm=(400.0, 300.0))


# ------------------------------------------------------------------------------ reading
def test_files_that_cannot_be_read_are_one_line(tmp_path):
    with pytest.raises(ProgramError, match='no such file'):
        load_program(tmp_path / 'none.dxf', kerf_mm=0.2)
    junk = tmp_path / 'junk.dxf'
    junk.write_bytes(b'\x00\x01 not a drawing\n')
    with pytest.raises(ProgramError) as exc:
        load_program(junk, kerf_mm=0.2)
    assert 'cannot be read as DXF' in one_line(exc, junk)
    good = drawing(tmp_path, square_with_hole).read_text()
    cut = tmp_path / 'cut.dxf'
    cut.write_text(good[:len(good) // 2])
    with pytest.raises(ProgramError) as exc:
        load_program(cut, kerf_mm=0.2)
    one_line(exc, cut)
    empty = drawing(tmp_path, lambda m: m.add_text('no geometry'), 4, 'empty.dxf')
    with pytest.raises(ProgramError, match='nothing to cut'):
        load_program(empty, kerf_mm=0.2)


@pytest.mark.parametrize('kwargs, what', [
    ({'kerf_mm': -0.1}, 'kerf_mm'), ({'kerf_mm': 5.5}, 'kerf_mm'),
    ({'kerf_mm': math.nan}, 'kerf_mm'), ({'lead_in_mm': 51.0}, 'lead_in_mm'),
    ({'lead_in_mm': -1.0}, 'lead_in_mm'), ({'tolerance_mm': 0.0}, 'tolerance_mm'),
    ({'tolerance_mm': 1.5}, 'tolerance_mm'), ({'micro_joints_per_part': -1}, 'micro_joints'),
    ({'micro_joint_mm': -0.5}, 'micro_joint_mm'), ({'sheet_mm': (0.0, 100.0)}, 'sheet_mm'),
])
def test_arguments_out_of_range_are_refused(tmp_path, kwargs, what):
    path = drawing(tmp_path, square_with_hole)
    with pytest.raises(ProgramError) as exc:
        load_program(path, **{'kerf_mm': 0.2, **kwargs})
    assert what in one_line(exc, path)


def test_other_entities_are_ignored_and_listed(tmp_path):
    def build(msp):
        square_with_hole(msp)
        msp.add_text('PART 1', dxfattribs={'insert': (20, 20)})
        msp.add_point((5, 5))
    p = load_program(drawing(tmp_path, build), kerf_mm=0.2)
    assert len(p.parts) == 1 and len(p.contours) == 2
    assert p.ignored == ('POINT', 'TEXT')


# ------------------------------------------------------------------------------ chaining
def test_loose_lines_arcs_and_reversed_pieces_chain_into_one_contour(tmp_path):
    def build(msp):  # an obround 80 x 40 of lines and arcs, drawn out of order, some reversed
        msp.add_arc((80, 20), 20, -90, 90)
        msp.add_line((0, 40), (80, 40))      # reversed: the chain runs 80 -> 0
        msp.add_line((0, 0), (80, 0))
        msp.add_arc((0, 20), 20, 90, 270)
    p = load_program(drawing(tmp_path, build), kerf_mm=0.0)
    assert len(p.parts) == 1 and len(p.contours) == 1
    c = p.contours[0]
    assert np.array_equal(c.points_mm[0], c.points_mm[-1])
    assert p.parts[0].area == pytest.approx(80 * 40 + math.pi * 400, rel=1e-4)


def test_an_open_chain_is_refused_naming_its_open_ends(tmp_path):
    def build(msp):  # an L whose last side stops 0.8 mm short of the start
        pts = [(0, 0), (40, 0), (40, 30), (0, 30), (0, 0.8)]
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            msp.add_line(a, b)
    path = drawing(tmp_path, build)
    with pytest.raises(ProgramError) as exc:
        load_program(path, kerf_mm=0.0, open_contours='refuse')
    text = one_line(exc, path)
    assert 'does not close' in text and '(0.000, 0.800)' in text and '(0.000, 0.000)' in text
    assert '0.800 mm apart' in text and 'LINE #' in text
    with pytest.raises(ProgramError, match='no closed contour'):  # cut_closed: none to cut
        load_program(path, kerf_mm=0.0)
    # within the join tolerance the same chain closes, the gap reported
    p = load_program(path, kerf_mm=0.0, join_tolerance_mm=0.9)
    assert len(p.parts) == 1 and p.reading['largest_gap_closed_mm'] == pytest.approx(0.8)


def test_crossing_contours_are_refused(tmp_path):
    path = drawing(tmp_path, lambda m: (rect(m, 0, 0, 50, 50), rect(m, 40, 40, 50, 50)))
    with pytest.raises(ProgramError, match=r'cross each other near \('):
        load_program(path, kerf_mm=0.2)
    bow = drawing(tmp_path, lambda m: m.add_lwpolyline([(0, 0), (50, 50), (50, 0), (0, 50)],
                                                     close=True), name='bow.dxf')
    with pytest.raises(ProgramError, match=r'crosses itself near \(25\.000, 25\.000\)'):
        load_program(bow, kerf_mm=0.2)


def test_a_bulged_polyline_is_flattened_within_tolerance(tmp_path):
    p = load_program(drawing(tmp_path, lambda m: dxf_library._rounded_square(m, 0, 0, 30, 3)),
                     kerf_mm=0.0, tolerance_mm=0.01)
    exact = 30 * 30 - (4 - math.pi) * 3 ** 2
    assert p.parts[0].area == pytest.approx(exact, rel=5e-3)
    # the corners' points on their arcs, within the tolerance (ezdxf: Bezier curves, flattened)
    for x, y in p.contours[0].points_mm:
        if min(x, 30 - x) < 3 - 1e-9 and min(y, 30 - y) < 3 - 1e-9:
            cx, cy = (3 if x < 15 else 27), (3 if y < 15 else 27)
            assert math.hypot(x - cx, y - cy) == pytest.approx(3.0, abs=0.01)
    length = LinearRing(p.contours[0].points_mm).length
    assert length == pytest.approx(4 * 24 + 2 * math.pi * 3, abs=0.01)


def test_a_closed_spline_of_fit_points_is_closed_smoothly(tmp_path):
    fit = [(30, 20), (100, 15), (150, 40), (140, 85), (70, 95), (25, 60)]

    def flag_only(msp):  # the closed flag, the first point not repeated
        msp.add_spline(fit).closed = True

    a = load_program(drawing(tmp_path, flag_only), kerf_mm=0.0).parts[0]
    b = load_program(drawing(tmp_path, lambda m: dxf_library._closed_spline(m, fit),
                             name='lib.dxf'), kerf_mm=0.0).parts[0]
    assert a.area == pytest.approx(b.area, rel=1e-6) and a.is_valid
    assert all(Point(p).distance(a.exterior) < 0.02 for p in fit)  # through its fit points


# ------------------------------------------------------------------------------ kerf
def test_the_kerf_is_on_the_scrap_side_and_the_direction_is_cw_outside_ccw_inside(tmp_path):
    kerf = 0.4
    path = drawing(tmp_path, square_with_hole)
    p0 = load_program(path, kerf_mm=0.0)
    p = load_program(path, kerf_mm=kerf)
    hole, outline = p.contours
    part = p.parts[0]
    # the outline grows by its perimeter times half the kerf (+ the round corners' pi d^2)
    grown = Polygon(outline.points_mm).area - Polygon(p0.contours[1].points_mm).area
    assert grown == pytest.approx(200.0 * kerf / 2 + math.pi * (kerf / 2) ** 2, rel=1e-3)
    # the hole's slug shrinks by its perimeter times half the kerf (less pi d^2: a circle)
    hole0 = Polygon(p0.contours[0].points_mm)
    shrunk = hole0.area - hole.region.area
    assert shrunk == pytest.approx(hole0.length * kerf / 2 - math.pi * (kerf / 2) ** 2, rel=1e-3)
    assert hole.region.area == pytest.approx(math.pi * (8 - kerf / 2) ** 2, rel=3e-3)
    # the path half a kerf from the part, in the scrap, all along
    for c in (hole, outline):
        d = np.array([part.exterior.distance(Point(q)) if not c.inner else
                      part.interiors[0].distance(Point(q)) for q in c.points_mm])
        assert np.allclose(d, kerf / 2, atol=2e-3)
        assert not any(part.contains(Point(q)) for q in c.points_mm)
    assert not LinearRing(outline.points_mm).is_ccw and LinearRing(hole.points_mm).is_ccw
    # the scrap on the left of the travel: a step to the left of the first edge is off the part
    for c in (hole, outline):
        a, b = c.points_mm[0], c.points_mm[1]
        left = (a + b) / 2 + np.array([-(b - a)[1], (b - a)[0]]) / np.linalg.norm(b - a) * 0.1
        assert not part.contains(Point(left))
    # regions: the slug, and the part minus its holes, at the compensated boundary
    assert outline.region.area == pytest.approx(Polygon(outline.points_mm).area
                                                - hole.region.area, rel=1e-9)


def test_contours_are_closed_and_lengths_are_their_paths(tmp_path):
    p = load_program(drawing(tmp_path, square_with_hole), kerf_mm=0.2)
    for c in p.contours:
        assert np.array_equal(c.points_mm[0], c.points_mm[-1])
        assert c.points_mm.shape[1] == 2 and c.lead_in_mm.shape[0] >= 2
        assert c.length_mm == pytest.approx(LinearRing(c.points_mm).length)
        assert np.allclose(c.lead_in_mm[-1], c.points_mm[0])
        assert c.pierce_xy == tuple(c.lead_in_mm[0])
        assert not c.points_mm.flags.writeable


# ------------------------------------------------------------------------------ lead-ins
def test_lead_ins_come_from_the_scrap(tmp_path):
    def build(msp):
        rect(msp, 0, 0, 100, 60)
        msp.add_circle((20, 30), 10)              # room for the whole lead-in
        msp.add_circle((50, 30), 2)               # smaller than the lead-in: shortened
        dxf_library._rounded_square(msp, 70, 20, 20, 3)
    p = load_program(drawing(tmp_path, build), kerf_mm=0.2, lead_in_mm=3.0)
    part = p.parts[0]
    holes = [c for c in p.contours if c.inner]
    assert len(holes) == 3
    for c in holes:
        lead = LineString(c.lead_in_mm)
        assert c.region.buffer(1e-9).contains(lead)  # inside the hole's slug
        assert not part.intersection(lead).length
    lengths = sorted(LineString(c.lead_in_mm).length for c in holes)
    assert lengths[0] == pytest.approx(1.9, abs=0.02)  # radius 2 - kerf/2: from the centre
    assert lengths[1:] == pytest.approx([3.0, 3.0])
    small = min(holes, key=lambda c: c.region.area)
    assert math.dist(small.pierce_xy, (50, 30)) < 0.02
    outline = next(c for c in p.contours if not c.inner)
    lead = LineString(outline.lead_in_mm)
    assert lead.length == pytest.approx(3.0) and not part.intersection(lead).length
    assert part.exterior.distance(Point(outline.pierce_xy)) == pytest.approx(3.1, abs=1e-6)


def test_an_outline_lead_in_keeps_clear_of_a_close_neighbour_and_on_the_sheet(tmp_path):
    # two tall parts 4 mm apart: their long edges face each other, or the sheet's edge 3 mm off
    path = drawing(tmp_path, lambda m: (rect(m, 3, 20, 40, 150), rect(m, 47, 20, 40, 150)))
    p = load_program(path, kerf_mm=0.2, lead_in_mm=3.0, sheet_mm=(200.0, 200.0))
    for c in p.contours:
        others = [q for k, q in enumerate(p.parts) if k != c.part]
        lead = LineString(c.lead_in_mm)
        assert all(q.distance(lead) > 1.0 for q in others)
        assert 5.0 <= c.pierce_xy[0] <= 195.0 and 5.0 <= c.pierce_xy[1] <= 195.0


# ------------------------------------------------------------------------------ order
def test_holes_are_cut_before_their_part(nest):
    done: set[int] = set()
    for c in nest.contours:
        assert c.part not in done  # nothing of a part after its outline
        if not c.inner:
            done.add(c.part)
    assert done == set(range(len(nest.parts)))
    for k, part in enumerate(nest.parts):
        assert sum(1 for c in nest.contours if c.part == k and c.inner) == len(part.interiors)


def test_a_part_in_a_hole_is_cut_before_that_hole(tmp_path):
    def build(msp):  # a frame (its hole holds a part with a hole) drawn first
        rect(msp, 0, 0, 200, 200)
        rect(msp, 20, 20, 160, 160)
        rect(msp, 50, 50, 100, 100)
        msp.add_circle((100, 100), 20)
    p = load_program(drawing(tmp_path, build), kerf_mm=0.2)
    assert [q.area for q in p.parts] == pytest.approx([40000 - 25600, 10000 - math.pi * 400],
                                                      rel=1e-4)
    assert [(c.part, c.inner) for c in p.contours] == [(1, True), (1, False), (0, True),
                                                        (0, False)]


def test_nearest_next_beats_the_drawing_order(nest, tmp_path):
    dxf_library.nest(tmp_path / 'shuffled.dxf', seed=7)  # the same nest drawn in a random order
    shuffled = load_program(tmp_path / 'shuffled.dxf', kerf_mm=0.25, sheet_mm=SHEET_MM)
    for p in (nest, shuffled):
        drawn = [c for k in range(len(p.parts))  # the parts as drawn, holes first
                 for c in sorted((c for c in p.contours if c.part == k), key=lambda c: c.inner,
                                 reverse=True)]
        assert rapids_mm(p.contours) < 0.8 * rapids_mm(drawn)
    # the first contour cut: of those that can be first (a hole, an outline without holes),
    # the nearest to the origin
    can = [c for c in nest.contours if c.inner or not nest.parts[c.part].interiors]
    assert math.hypot(*nest.contours[0].pierce_xy) == min(math.hypot(*c.pierce_xy) for c in can)


# ------------------------------------------------------------------------------ micro-joints
def test_micro_joints_are_reported_on_outlines_and_spaced_evenly(nest, nest_dxf):
    for c in nest.contours:
        if c.inner:
            assert c.micro_joints == ()
            continue
        assert len(c.micro_joints) == 2
        starts = [a for a, _ in c.micro_joints]
        assert all(b - a == pytest.approx(0.5) for a, b in c.micro_joints)
        assert starts[0] > 2.0 and c.micro_joints[-1][1] < c.length_mm
        step = (c.length_mm - 2.0) / 2
        assert starts[1] - starts[0] == pytest.approx(step)
    none = load_program(nest_dxf, kerf_mm=0.25, sheet_mm=SHEET_MM)
    assert all(c.micro_joints == () for c in none.contours)


# ------------------------------------------------------------------------------ the library
def test_the_nest_is_as_the_library_says(nest, nest_dxf):
    assert len(nest.parts) == 16 and len(nest.contours) == 32
    w, h = SHEET_MM
    outlines = [c for c in nest.contours if not c.inner]
    left = [c for c in outlines if c.region.bounds[0] < 5.0]
    bottom = [c for c in outlines if c.region.bounds[1] < 5.0]
    right = [c for c in outlines if w - c.region.bounds[2] < 5.0]
    assert len({id(c) for c in left + bottom + right}) >= 3 and left and bottom and right
    assert any(q.bounds[0] == pytest.approx(3.0) for q in nest.parts)
    assert any(q.bounds[1] == pytest.approx(4.0) for q in nest.parts)
    gaps = [min(a.distance(b) for j, b in enumerate(nest.parts) if j != i)
            for i, a in enumerate(nest.parts)]
    assert min(gaps) >= 3.0 - 1e-9  # no overlap, 3 mm apart at least
    assert sum(g < 8.0 for g in gaps) >= 5
    x0, y0, x1, y1 = nest.bounds_mm
    assert 0.0 <= x0 and 0.0 <= y0 and x1 <= w and y1 <= h
    kinds = {e.dxftype() for e in ezdxf.readfile(str(nest_dxf)).modelspace()}
    assert kinds == {'LWPOLYLINE', 'CIRCLE', 'LINE', 'ARC', 'ELLIPSE', 'SPLINE'}


def test_the_nest_is_deterministic_for_a_seed(tmp_path):
    def entities(path: Path) -> list:
        return [(e.dxftype(), str(sorted(e.dxfattribs(drop={'handle', 'owner'}).items())))
                for e in ezdxf.readfile(str(path)).modelspace()]

    for name, seed in (('a', 3), ('b', 3), ('c', 4)):
        dxf_library.nest(tmp_path / f'{name}.dxf', seed=seed)
    a, b, c = (entities(tmp_path / f'{n}.dxf') for n in 'abc')
    assert a == b and a != c
    parts = [sorted(round(q.area, 3) for q in load_program(tmp_path / f'{n}.dxf',
                                                           kerf_mm=0.0).parts) for n in 'ac']
    assert parts[0] == parts[1]  # the same parts, drawn in another order


def test_the_plate_is_as_the_library_says(tmp_path):
    dxf_library.plate_with_holes(tmp_path / 'plate.dxf')
    p = load_program(tmp_path / 'plate.dxf', kerf_mm=0.2, sheet_mm=(400.0, 300.0))
    (part,) = p.parts
    assert part.exterior.bounds == (50.0, 50.0, 350.0, 250.0) and len(part.interiors) == 5
    holes = sorted((Polygon(r) for r in part.interiors), key=lambda q: q.area)
    areas = [math.pi * 100, 400.0, math.pi * 225, 900 - (4 - math.pi) * 9, math.pi * 400]
    assert [q.area for q in holes] == pytest.approx(areas, rel=2e-3)
    for i, a in enumerate(holes):
        assert a.distance(part.exterior) >= 15.0
        assert all(a.distance(b) >= 15.0 for b in holes[i + 1:])
    assert [c.inner for c in p.contours] == [True] * 5 + [False]


def test_the_library_writes_its_drawings_into_a_folder(tmp_path, monkeypatch):
    monkeypatch.setattr('sys.argv', ['dxf_library', str(tmp_path / 'out')])
    dxf_library.main()
    names = sorted(f.name for f in (tmp_path / 'out').iterdir())
    assert {'nest_16.dxf', 'plate_holes.dxf'} <= set(names)
    for name in names:
        assert ezdxf.readfile(str(tmp_path / 'out' / name)).header['$INSUNITS'] == 4
