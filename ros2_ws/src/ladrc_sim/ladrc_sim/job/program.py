"""A part program from a nest drawn in DXF, as a CAM makes it for a laser CNC.

All lengths are millimetres once ``$INSUNITS`` has scaled the drawing.

* **Reading** (ezdxf): LINE, ARC, CIRCLE, ELLIPSE, SPLINE, LWPOLYLINE (bulges) and 2D
  POLYLINE in modelspace, flattened by ezdxf's path module to a chord error of at most
  ``tolerance_mm``; other entities (text, dimensions, hatches, 3D polylines) are ignored and
  listed in ``Program.ignored``.
* **Block INSERTs** (a nest as nesting software writes it) are exploded, nested blocks too,
  MINSERT grids too: each entity of the block is placed by ezdxf's own transformation of the
  INSERT (``Insert.matrix44()``: insertion point, the block's base point, x/y/z scale, a
  negative scale mirroring, rotation, extrusion), composed down the nesting, applied to the
  entity's path before it is flattened. An entity on layer ``0`` in a block is on the layer of
  its INSERT (the CAD rule).
* **Layers**: ``layers`` (default all) selects the layers read, by name, case-insensitive; a
  layer named that carries no entity is refused, naming the drawing's layers.
* **Units**: ``$INSUNITS`` as the file writes it (read from the file's own tags: ezdxf fills a
  default, metres, into a drawing without a HEADER section, as R12 files from laser CAMs are),
  else ``units`` (the job file's ``dxf_units``); the file's and ``units`` disagreeing, neither
  saying, or a unit not in :data:`UNIT_MM` is refused, one line naming what the file says and
  does not say. A drawing whose size is absurd for the sheet is refused.
* **Cleaning**: pieces shorter than the join tolerance are dropped; a piece within twice the
  chord tolerance of one at least as long (drawn twice, or over part of it) is dropped as a
  duplicate; both counted in ``Program.reading``.
* **Chaining** (the reader's own: ezdxf's edgeminer needs ezdxf 1.4, the noble profile has
  1.1.3): open pieces are joined end to end, either way round, where their ends meet within
  ``max(join_tolerance_mm, tolerance_mm, 1e-6 x the drawing's size)``, a gap closed by a
  straight step (the joins and the widest gap in ``Program.reading``); a chain that does not
  close is listed there (``open_contours: cut_closed``) or refused naming its first entity
  (``refuse``). Contours of less than 1e-6 mm² are dropped.
* **Nesting**: a contour inside an odd number of others is a hole of the smallest one around
  it; the others are parts (a part in another part's hole is a part of its own). Contours that
  cross each other are refused; a contour drawn twice over itself is cut once.
* **Direction and kerf**: outlines clockwise, holes counter-clockwise (the usual laser CAM
  convention): the part is on the right of the travel and the scrap on its left, for both. The
  path runs half a kerf into the scrap, outside a part's outline and inside a hole: the
  compensation to the left of the travel (G41 on a control that compensates itself).
* **Lead-ins**, straight, from the scrap: into a hole from its pole (the centre of its largest
  inscribed circle, beside the parts inside it and their kerf) to the nearest point of its
  path, perpendicular to it, shortened to fit a small hole; onto an outline along the outward
  normal at the middle of its longest edge whose lead-in clears the other parts (and keeps the
  nozzle on the sheet, when the sheet is given).
* **Micro-joints** (optional): beam-off gaps spread evenly along each outline, none in its first
  2 mm.
* **Order**: a part's holes before its outline; parts nearest next from the origin, by the
  pierce point of the contour each would cut first; holes nearest next within a part (with
  ``small_contour_mm``: the smaller holes after the others, each next the nearest whose pierce
  point is half of it from the voids cut so far, else the farthest); a part in another part's
  hole before that part.

``Program.parts`` are in drawing order (of each outline's first entity in the modelspace).
"""

from __future__ import annotations

from dataclasses import dataclass
import io
import math
import numbers
from pathlib import Path
import re

import ezdxf
from ezdxf import path as dxf_path
from ezdxf.enums import InsertUnits
from ezdxf.lldxf.const import DXFError, acad_release
from ezdxf.lldxf.tagger import ascii_tags_loader
from ezdxf.math import Matrix44, Vec3, fit_points_to_cad_cv
import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry.polygon import orient
from shapely.ops import polylabel

UNITS = {1: ('in', 25.4), 4: ('mm', 1.0), 5: ('cm', 10.0), 6: ('m', 1000.0)}
"""``$INSUNITS`` codes accepted: name and millimetres per unit."""
UNIT_MM = {'mm': 1.0, 'cm': 10.0, 'm': 1000.0, 'in': 25.4}
"""The units a job may give a drawing that does not say (``dxf_units``): millimetres per unit."""
MAX_NESTING = 16         # blocks nested deeper than this: refused (a cycle, or not a nest)
SUPPORTED = ('LINE', 'ARC', 'CIRCLE', 'ELLIPSE', 'SPLINE', 'LWPOLYLINE', 'POLYLINE')
MIN_AREA_MM2 = 1e-6      # less: a drawing artefact (a line drawn there and back), dropped
MIN_LEAD_MM = 0.5        # the shortest lead-in tried onto an outline before giving up on clearance
JOINT_FREE_MM = 2.0      # no micro-joint in the first 2 mm after the lead-in (the cut settles)
SHEET_MARGIN_MM = 5.0    # a pierce keeps the 8 mm nozzle face on the sheet, plus 1 mm
PIERCE_CLEAR_MM = 1.0    # a lead-in's distance to other parts beyond half a kerf (pierce crater)


OPEN_CONTOURS = ('cut_closed', 'refuse')
"""What the reader does with a chain that does not close (the job file's ``open_contours``)."""
JOIN_TOLERANCE_MM = 0.5
"""Ends nearer than this are joined (the job file's ``join_tolerance_mm``): sub-mm gaps."""


@dataclass(frozen=True, eq=False)
class Piece:
    """An entity's flattened path (mm, on the sheet), its drawing order, layer and name."""

    order: int
    points: np.ndarray
    layer: str
    label: str                 # 'LINE #1F', or 'ARC of INSERT #2A (block 'P')'


@dataclass(frozen=True, eq=False)
class OpenChain:
    """A chain of pieces that does not close within the join tolerance."""

    label: str                 # its first entity in drawing order
    layer: str
    points: np.ndarray
    order: int

    def describe(self) -> dict:
        """Return it for the log and the figures: entity, layer, ends, length."""
        a, b = self.points[0], self.points[-1]
        return {'entity': self.label, 'layer': self.layer,
                'ends_mm': [[round(float(a[0]), 3), round(float(a[1]), 3)],
                            [round(float(b[0]), 3), round(float(b[1]), 3)]],
                'length_mm': round(_length(self.points), 3)}


class ProgramError(ValueError):
    """A drawing cannot be a part program; one line naming the file and the problem."""


@dataclass(frozen=True, eq=False)  # (arrays: identity, not value, equality)
class Contour:
    """One contour of the program, kerf-compensated, with its lead-in, in cut order."""

    points_mm: np.ndarray      # (n, 2) closed path (first == last), read-only
    inner: bool                # a hole of a part (cut before the part's outline)
    part: int                  # index of its part in Program.parts
    lead_in_mm: np.ndarray     # (m >= 2, 2) from the pierce point to points_mm[0], read-only
    region: Polygon            # what drops out once it is cut: the slug, or the part
    micro_joints: tuple[tuple[float, float], ...] = ()  # beam-off (start, end) path distances

    @property
    def pierce_xy(self) -> tuple[float, float]:
        """Return the pierce point (the lead-in's start)."""
        return float(self.lead_in_mm[0, 0]), float(self.lead_in_mm[0, 1])

    @property
    def length_mm(self) -> float:
        """Return the contour's path length."""
        return _length(self.points_mm)

    @property
    def size_mm(self) -> float:
        """Return the contour's largest extent (of its path's bounding box)."""
        lo, hi = self.points_mm.min(axis=0), self.points_mm.max(axis=0)
        return float(max(hi - lo))


@dataclass(frozen=True, eq=False)
class Program:
    """A part program: the contours in cut order and the parts as drawn."""

    source: str                # the DXF path as given
    units: str                 # the drawing's units ('mm', 'cm', 'm', 'in')
    scale_to_mm: float
    contours: tuple[Contour, ...]
    parts: tuple[Polygon, ...]  # as drawn (no kerf), in drawing order
    bounds_mm: tuple[float, float, float, float]  # of everything read (minx, miny, maxx, maxy)
    ignored: tuple[str, ...] = ()  # entity types in the modelspace not read (sorted)
    units_from: str = ''       # where the units come from: '$INSUNITS=4' or 'dxf_units'
    layers: tuple[str, ...] = ()  # the layers the contours were read from (sorted)
    reading: dict | None = None  # what the reader joined, dropped and left open (figures)


def _length(points: np.ndarray) -> float:
    d = np.diff(points, axis=0)
    return float(np.hypot(d[:, 0], d[:, 1]).sum())


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=float)
    a.setflags(write=False)
    return a


def _number(name: str, label: str, value: object, lo: float, hi: float, *,
            open_low: bool = False) -> float:
    """Return ``value`` as a float in [lo, hi] (or (lo, hi]); otherwise refuse it, one line."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = math.nan
    if not (lo < x <= hi if open_low else lo <= x <= hi):  # NaN fails both
        span = f'({lo:g}, {hi:g}]' if open_low else f'{lo:g}..{hi:g}'
        what = 'outside' if x == x else 'is not a number in'
        raise ProgramError(f'{name}: {label} {value!r} {what} {span} mm')
    return x


def _check_arguments(name: str, kerf_mm: float, lead_in_mm: float, micro_joint_mm: float,
                     micro_joints_per_part: int, tolerance_mm: float,
                     sheet_mm: tuple[float, float] | None) -> None:
    """Refuse arguments out of range (NaN and non-numbers included) with one line."""
    _number(name, 'kerf_mm', kerf_mm, 0.0, 5.0)
    _number(name, 'lead_in_mm', lead_in_mm, 0.0, 50.0)
    _number(name, 'tolerance_mm', tolerance_mm, 0.0, 1.0, open_low=True)
    _number(name, 'micro_joint_mm', micro_joint_mm, 0.0, 50.0)
    n = micro_joints_per_part
    if isinstance(n, bool) or not isinstance(n, numbers.Integral) or not 0 <= n <= 100:
        raise ProgramError(f'{name}: micro_joints_per_part {n!r} is not a whole number in '
                           '0..100')
    if sheet_mm is not None:
        try:
            w, h = (float(s) for s in sheet_mm)
        except (TypeError, ValueError):
            w = h = math.nan
        if not (0.0 < w < math.inf and 0.0 < h < math.inf):
            raise ProgramError(f'{name}: sheet_mm {sheet_mm!r} is not (width, height) > 0 mm')


def _read(path: str | Path, name: str):
    """Return the ezdxf document of ``path``."""
    if not Path(path).is_file():
        raise ProgramError(f'{name}: no such file')
    try:
        return ezdxf.readfile(str(path))
    except Exception as exc:  # whatever the reader trips on, the file is the problem
        text = ' '.join(str(exc).split()) or type(exc).__name__
        if 'not a DXF file' in text:
            text = 'not a DXF file'
        raise ProgramError(f'{name}: cannot be read as DXF: {text}') from None


def _file_insunits(path: str | Path, doc) -> tuple[bool, int | None]:
    """Return (the file has a HEADER section, ``$INSUNITS`` as the file writes it or None).

    From the file's own tags, not ``doc.header``: ezdxf fills a default header (``$INSUNITS``
    6, metres) into a drawing without a HEADER section. A binary DXF: ``doc.header``.
    """
    data = Path(path).read_bytes()
    if data.startswith(b'AutoCAD Binary DXF'):
        return True, doc.header.get('$INSUNITS') if '$INSUNITS' in doc.header else None
    has_header = in_header = False
    code, prev = None, None
    try:
        for tag in ascii_tags_loader(io.StringIO(data.decode('latin-1'))):
            if tag.code == 2 and prev == (0, 'SECTION'):
                in_header = tag.value.strip() == 'HEADER'
                has_header |= in_header
            elif in_header and tag.code == 0 and tag.value.strip() == 'ENDSEC':
                break  # the header read: nothing else is looked at
            elif in_header and prev == (9, '$INSUNITS'):
                code = int(float(tag.value))
            prev = (tag.code, tag.value.strip() if isinstance(tag.value, str) else tag.value)
    except (ValueError, TypeError, DXFError):  # a tag ezdxf tolerated: what was read so far
        pass
    return has_header, code


def _units(doc, path: str | Path, name: str, given: str | None) -> tuple[str, float, str]:
    """Return the units' name, millimetres per unit, and where they come from (module doc)."""
    choices = '|'.join(UNIT_MM)
    if given is not None and given not in UNIT_MM:
        raise ProgramError(f'{name}: dxf_units {given!r} is not one of {choices}')
    has_header, code = _file_insunits(path, doc)
    if code:  # the file says
        if code not in UNITS:
            job = f'; dxf_units: {given} in the job file does not apply' if given else ''
            # the enum's own name: ezdxf 1.1.3's unit_name() reads str(IntEnum), which is the
            # number on Python >= 3.11 ('unitless' for every code)
            what = InsertUnits(code).name.lower() if 0 < code <= 24 else 'no unit'
            raise ProgramError(f'{name}: drawing units not supported ($INSUNITS={code}, '
                               f'{what}): set them to mm, cm, m or inches ($INSUNITS 4, 5, 6, '
                               f'1){job}')
        said, mm = UNITS[code]
        if given is not None and given != said:
            raise ProgramError(f'{name}: drawing units disagree: the file says {said} '
                               f'($INSUNITS={code}), the job file dxf_units: {given}')
        return said, mm, f'$INSUNITS={code}'
    if given is not None:
        return given, UNIT_MM[given], 'dxf_units'
    release = acad_release.get(doc.dxfversion, '')
    version = f'{release} ({doc.dxfversion})' if release else doc.dxfversion
    what = ('without $INSUNITS (no HEADER)' if not has_header else
            'without $INSUNITS in its HEADER' if code is None else
            'with $INSUNITS=0 (unitless)')
    raise ProgramError(f'{name}: drawing units missing: {version} file {what}: give '
                       f'dxf_units: {choices} in the job file')


def _flatten(e, step: float, m: Matrix44 | None = None) -> np.ndarray:
    """Return entity ``e`` as (n, 2) points in drawing units, chord error at most ``step``.

    ``m``: the transformation of the INSERTs the entity is placed by (applied before
    flattening, so the chord error is of the placed curve).
    """
    if (e.dxftype() == 'SPLINE' and e.closed and e.control_point_count() == 0
            and e.fit_point_count() > 2):
        # a closed spline given by fit points alone: ezdxf's path stops at the last one; CAD
        # closes it smoothly (one tangent at the joint), so close it that way
        fit = [Vec3(p) for p in e.fit_points]
        if not fit[0].isclose(fit[-1]):
            fit.append(fit[0])
        t = (fit[1] - fit[-2]).normalize()
        spline = fit_points_to_cad_cv(fit, tangents=[t, t])
        vs = (spline if m is None else spline.transform(m)).flattening(step)
    else:
        p = dxf_path.make_path(e)
        vs = (p if m is None else p.transform(m)).flattening(distance=step)
    pts = np.array([(v.x, v.y) for v in vs], dtype=float).reshape(-1, 2)
    if len(pts) > 1:  # zero-length steps out (a polyline's doubled vertex)
        keep = np.r_[True, np.any(np.abs(np.diff(pts, axis=0)) > 1e-12, axis=1)]
        pts = pts[keep]
    return pts


def _entities(doc, name: str):
    """Yield (entity, its layer, its INSERTs' transformation or None, where) from the modelspace.

    INSERTs exploded (module docstring); ``where`` names the entity for a message: its handle,
    or its block and the handle of the modelspace INSERT that places it.
    """

    def walk(entities, layer0: str | None, m: Matrix44 | None, where: str | None, depth: int):
        for e in entities:
            layer = e.dxf.get('layer', '0')
            if layer == '0' and layer0 is not None:
                layer = layer0  # in a block, layer 0 takes its INSERT's
            if e.dxftype() != 'INSERT':
                here = where or f'#{e.dxf.handle}'
                yield e, layer, m, here
                continue
            block = doc.blocks.get(e.dxf.name)
            here = where or f'#{e.dxf.handle}'
            if block is None:
                raise ProgramError(f'{name}: INSERT {here} names block {e.dxf.name!r}, which '
                                   'the drawing does not have')
            if depth >= MAX_NESTING:
                raise ProgramError(f'{name}: INSERT {here}: blocks nested deeper than '
                                   f'{MAX_NESTING} (block {e.dxf.name!r})')
            for ins in (e.multi_insert() if e.mcount > 1 else (e,)):  # a MINSERT: its grid
                try:
                    own = ins.matrix44()
                except Exception as exc:  # a broken INSERT is the drawing's problem
                    text = ' '.join(str(exc).split()) or type(exc).__name__
                    raise ProgramError(f'{name}: INSERT {here} cannot be placed: {text}') from None
                yield from walk(block, layer, own if m is None else own @ m,
                                f'{here} (block {e.dxf.name!r})', depth + 1)

    yield from walk(doc.modelspace(), None, None, None, 0)


def _pieces(doc, scale: float, tol: float, name: str,
            origin_mm: tuple[float, float] = (0.0, 0.0),
            layers: tuple[str, ...] | None = None) -> tuple[list, list, list[str], set[str]]:
    """Return closed rings and open pieces, the ignored types, and the layers found.

    Rings and pieces as (drawing order, (n, 2) mm, layer); the points are on the sheet: the
    drawing's (0, 0) lies at ``origin_mm``. ``layers``: the layers read (casefolded; None:
    all); the layers found are those of every entity, read or not.
    """
    closed, open_, ignored, found = [], [], set(), set()
    for order, (e, layer, m, where) in enumerate(_entities(doc, name)):
        found.add(layer)
        if layers is not None and layer.casefold() not in layers:
            continue
        kind = e.dxftype()
        if kind not in SUPPORTED or (kind == 'POLYLINE' and not e.is_2d_polyline):
            ignored.add(kind if kind != 'POLYLINE' else 'POLYLINE (3D or mesh)')
            continue
        try:
            pts = _flatten(e, tol / scale, m) * scale + origin_mm
        except Exception as exc:  # a broken entity is the drawing's problem
            text = ' '.join(str(exc).split()) or type(exc).__name__
            what = f'{kind} #{e.dxf.handle}' if m is None else f'{kind} of INSERT {where}'
            raise ProgramError(f'{name}: {what} cannot be flattened: {text}') from None
        if len(pts) < 2:
            continue
        label = (f'{kind} #{e.dxf.handle}' if m is None else f'{kind} of INSERT {where}')
        if len(pts) >= 4 and math.dist(pts[0], pts[-1]) <= tol:
            pts[-1] = pts[0]
            closed.append(Piece(order, pts, layer, label))
        else:
            open_.append(Piece(order, pts, layer, label))
    return closed, open_, sorted(ignored), found


def _clean(closed: list, open_: list, tol: float, same: float) -> tuple[list, list, int, int]:
    """Return (closed, open) without the pieces shorter than ``tol`` and the duplicates.

    Short: an open piece whose length, or a closed one whose extent, is below ``tol`` (a
    drawing's dot or stub). Duplicate: a piece lying within ``same`` (the flattening's error,
    twice) of another one that is at least as long (drawn twice, or over part of another); the
    first drawn of two equal ones stays. Also returns how many were dropped as short and as
    duplicates.
    """
    short = 0
    keep = []
    for piece in closed + open_:
        ext = piece.points.max(axis=0) - piece.points.min(axis=0)
        if (_length(piece.points) if piece not in closed else float(max(ext))) < tol:
            short += 1
        else:
            keep.append(piece)
    lines = [LineString(pc.points) if len(pc.points) > 1 else Point(pc.points[0]) for pc in keep]
    lengths = [g.length for g in lines]
    tree = shapely.STRtree(lines)
    dropped: set[int] = set()
    halo = {}
    for i, g in enumerate(lines):
        for j in tree.query(g, predicate='dwithin', distance=same):
            j = int(j)
            if j == i or j in dropped or i in dropped:
                continue
            # i lies over j (j at least as long; equal: the later drawn goes)
            if lengths[j] < lengths[i] or (lengths[j] == lengths[i]
                                           and keep[j].order > keep[i].order):
                continue
            if j not in halo:
                halo[j] = lines[j].buffer(same, quad_segs=4)
            if halo[j].covers(g):
                dropped.add(i)
                break
    closed_ids = {id(pc) for pc in closed}
    kept = [pc for k, pc in enumerate(keep) if k not in dropped]
    return ([pc for pc in kept if id(pc) in closed_ids],
            [pc for pc in kept if id(pc) not in closed_ids], short, len(dropped))


def _chain(pieces: list, tol: float) -> tuple[list, list, int, float]:
    """Join open pieces end to end into closed rings within ``tol``.

    Return (rings as :class:`Piece`, the open chains as :class:`OpenChain`, the joins made
    across a gap wider than 1e-6 mm, the widest gap closed). A gap is closed by a straight
    step from one piece's end to the next one's start.
    """
    rings, opened = [], []
    joins, widest = 0, 0.0
    n = len(pieces)
    ends = np.array([(pc.points[0], pc.points[-1]) for pc in pieces],
                    dtype=float).reshape(n, 2, 2)
    free = np.ones(n, dtype=bool)
    for i in range(n):  # each chain from its first piece in drawing order
        if not free[i]:
            continue
        free[i] = False
        chain, turned, gaps, members = [pieces[i].points], False, [], [i]
        closed = False
        while True:
            tail = chain[-1][-1]
            if len(chain) > 1 or len(chain[0]) >= 4:
                gap = math.dist(chain[0][0], tail)
                if gap <= tol and (len(chain) > 1 or gap > 1e-9):
                    gaps.append(gap)
                    closed = True
                    break
            d = np.hypot(ends[:, :, 0] - tail[0], ends[:, :, 1] - tail[1])
            d[~free] = np.inf
            j, end = np.unravel_index(int(np.argmin(d)), d.shape)
            if d[j, end] <= tol:  # the nearest free end: either way round
                free[j] = False
                members.append(int(j))
                gaps.append(float(d[j, end]))
                chain.append(pieces[j].points if end == 0 else pieces[j].points[::-1])
                continue
            if not turned:  # go on from the other end
                turned = True
                chain = [p[::-1] for p in reversed(chain)]
                continue
            break
        first = pieces[min(members, key=lambda k: pieces[k].order)]
        parts = [chain[0]] + [p[1:] if math.dist(p[0], q[-1]) <= 1e-9 else p
                              for q, p in zip(chain[:-1], chain[1:], strict=True)]
        path = np.vstack(parts)
        if not closed:
            opened.append(OpenChain(first.label, first.layer, path, first.order))
            continue
        joins += sum(1 for g in gaps if g > 1e-6)
        widest = max([widest, *gaps])
        if math.dist(path[0], path[-1]) <= 1e-9:
            path = path[:-1]
        ring = np.vstack((path, path[:1]))
        rings.append(Piece(first.order, ring, first.layer, first.label))
    return rings, opened, joins, widest


def _polygon(ring: np.ndarray, name: str) -> Polygon | None:
    """Return the closed ``ring`` as a polygon, None if degenerate; a self-crossing: refused."""
    if len(ring) < 4:
        return None
    poly = Polygon(ring)
    if not poly.is_valid:
        pieces = _polygons(shapely.make_valid(poly))
        total = sum(g.area for g in pieces)
        if sum(1 for g in pieces if g.area > 0.01 * total) > 1:
            reason = shapely.is_valid_reason(poly)  # 'Self-intersection[x y]'
            xy = re.findall(r'[-+0-9.eE]+', reason.partition('[')[2])[:2]
            where = f'near ({float(xy[0]):.3f}, {float(xy[1]):.3f}) mm' if len(xy) == 2 else (
                f'({reason})')
            raise ProgramError(f'{name}: a contour crosses itself {where}')
        poly = max(pieces, key=lambda g: g.area, default=None)  # a flattening sliver off
    return poly if poly is not None and poly.area > MIN_AREA_MM2 else None


def _nest(polys: list[Polygon], name: str) -> tuple[list[int], dict, dict]:
    """Return the parts (indices), each part's holes, and the part whose hole holds a part."""
    tree = shapely.STRtree(polys)
    a, b = tree.query(polys, predicate='overlaps')
    if len(a):
        x, y = polys[a[0]].boundary.intersection(polys[b[0]].boundary).representative_point(
        ).coords[0]
        raise ProgramError(f'{name}: two contours cross each other near ({x:.3f}, {y:.3f}) mm')
    a, b = tree.query(polys, predicate='contains')
    pairs = {(int(i), int(j)) for i, j in zip(a, b, strict=True) if i != j}
    dropped = {max(i, j) for i, j in pairs if (j, i) in pairs}  # a contour drawn twice: once
    around: dict[int, list[int]] = {j: [] for j in range(len(polys)) if j not in dropped}
    for i, j in pairs:
        if i not in dropped and j not in dropped:
            around[j].append(i)
    depth = {j: len(v) for j, v in around.items()}
    inside = {j: max(v, key=lambda i: depth[i]) for j, v in around.items() if v}  # smallest
    parts = [j for j in sorted(around) if depth[j] % 2 == 0]
    holes = {p: [j for j in sorted(around) if depth[j] % 2 and inside[j] == p] for p in parts}
    enclosing = {p: inside[inside[p]] for p in parts if depth[p]}
    return parts, holes, enclosing


def _quad_segs(half: float, tol: float) -> int:
    """Return the buffer's segments per quarter circle for a chord error within ``tol``."""
    if half <= tol:
        return 1
    step = 2.0 * math.acos(1.0 - tol / half)
    return int(min(max(math.ceil(math.pi / 2.0 / step), 2), 64))


def _polygons(geom) -> list[Polygon]:
    """Return the polygons of ``geom`` (a buffer may split) above the least area."""
    geoms = getattr(geom, 'geoms', [geom])
    return [g for g in geoms if g.geom_type == 'Polygon' and g.area > MIN_AREA_MM2]


def _start_at(ring: np.ndarray, k: int, point: np.ndarray) -> np.ndarray:
    """Return the closed ``ring`` re-ordered to start (and end) at ``point`` on its edge ``k``."""
    body = ring[:-1]
    order = np.r_[body[k + 1:], body[:k + 1]]
    if math.dist(point, order[0]) < 1e-9:
        order = order[1:]
    if len(order) and math.dist(point, order[-1]) < 1e-9:
        order = order[:-1]
    return np.vstack((point, order, point))


def _hole_lead(ring: np.ndarray, slug: Polygon, lead: float, tol: float,
               islands: Polygon | None = None) -> tuple:
    """Return (ring from its start, lead-in) of a hole: from its pole to the nearest point.

    ``islands``: what inside the hole is cut before it (parts in the hole, with a margin):
    the pole is the material's, not theirs (the pierce over material, never a void).
    """
    material = slug
    if islands is not None and not islands.is_empty:
        left = _polygons(slug.difference(islands))
        if left:
            material = max(left, key=lambda g: g.area)
    pole = np.asarray(polylabel(material, tolerance=max(tol, 1e-3)).coords[0])
    a, seg = ring[:-1], np.diff(ring, axis=0)
    ll = np.maximum(np.einsum('ij,ij->i', seg, seg), 1e-24)
    t = np.clip(np.einsum('ij,ij->i', pole - a, seg) / ll, 0.0, 1.0)
    near = a + t[:, None] * seg
    d = np.hypot(near[:, 0] - pole[0], near[:, 1] - pole[1])
    k = int(np.argmin(d))
    p = near[k]
    # a hole smaller than the lead-in: shortened to fit, from its centre (its pole)
    reach = min(lead, float(d[k]))
    start = p + (pole - p) / max(float(d[k]), 1e-12) * reach
    return _start_at(ring, k, p), np.vstack((start, p))


def _candidates(length: np.ndarray, most: int = 48) -> list[np.ndarray]:
    """Return the edges to try a lead-in on: the long ones, then the rest, longest first.

    At most ``most`` of each, spread along the ring (a circle's edges are all as long).
    """
    out = []
    long = length >= 0.5 * float(length.max())
    for group in (np.flatnonzero(long), np.flatnonzero(~long & (length > 1e-9))):
        if len(group) > most:
            group = group[np.linspace(0, len(group) - 1, most).round().astype(int)]
        out.append(group[np.argsort(-length[group], kind='stable')])
    return out


def _outer_lead(ring: np.ndarray, lead: float, half: float, fits) -> tuple:
    """Return (ring from its start, lead-in) of a clockwise outline, onto an edge's middle.

    The first lead-in that ``fits(start, end, clear)``, trying: open scrap (its pierce as far
    from other parts as from its own), then ``PIERCE_CLEAR_MM`` beyond half a kerf; the long
    edges, then the others; the lead-in shortened (to ``MIN_LEAD_MM``). None fits: the longest
    edge regardless.
    """
    seg = np.diff(ring, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    # the left of the travel: outward on a clockwise ring
    outward = np.column_stack((-seg[:, 1], seg[:, 0])) / np.maximum(length, 1e-12)[:, None]
    reaches = [lead] + [r for r in (lead / 2.0, MIN_LEAD_MM) if r < lead]
    groups = _candidates(length)
    for reach in reaches:
        for clear in (half + max(reach, PIERCE_CLEAR_MM), half + PIERCE_CLEAR_MM):
            for group in groups:
                for k in group:
                    mid = ring[k] + seg[k] / 2.0
                    start = mid + outward[k] * reach
                    if fits(start, mid, clear):
                        return _start_at(ring, int(k), mid), np.vstack((start, mid))
    k = int(np.argmax(length))
    mid = ring[k] + seg[k] / 2.0
    return _start_at(ring, k, mid), np.vstack((mid + outward[k] * lead, mid))


def _lead_check(own: int, parts: list[Polygon], tree: shapely.STRtree,
                sheet_mm: tuple[float, float] | None):
    """Return fits(start, end, clear): the lead-in in the scrap, ``clear`` mm from other parts.

    And its pierce point ``SHEET_MARGIN_MM`` inside the sheet, when the sheet is given.
    """

    def fits(start: np.ndarray, end: np.ndarray, clear: float) -> bool:
        if sheet_mm is not None and not (
                SHEET_MARGIN_MM <= start[0] <= sheet_mm[0] - SHEET_MARGIN_MM
                and SHEET_MARGIN_MM <= start[1] <= sheet_mm[1] - SHEET_MARGIN_MM):
            return False
        line = LineString((start, end)) if math.dist(start, end) > 1e-9 else Point(start)
        if line.geom_type == 'LineString' and parts[own].intersection(line).length > 1e-6:
            return False  # across its own part (a notch's other side)
        return all(int(i) == own for i in tree.query(line, predicate='dwithin', distance=clear))

    return fits


def _micro_joints(points: np.ndarray, n: int, gap: float) -> tuple[tuple[float, float], ...]:
    """Return ``n`` beam-off gaps of ``gap`` mm spread evenly after the first 2 mm."""
    if n <= 0 or gap <= 0.0:
        return ()
    usable = _length(points) - JOINT_FREE_MM
    if usable < 2.0 * n * gap:
        return ()  # a part too small for its joints: none (as a CAM skips them on small parts)
    step = usable / n
    return tuple((JOINT_FREE_MM + step * (i + 0.5) - gap / 2.0,
                  JOINT_FREE_MM + step * (i + 0.5) + gap / 2.0) for i in range(n))


def _order(groups: list, enclosing: dict[int, int], small_mm: float = 0.0) -> list[Contour]:
    """Return the contours in cut order (module docstring) from (holes, outline) per part.

    Holes of ``small_mm`` or more first (nearest next), then the smaller ones: next the nearest
    whose pierce point is ``small_mm / 2`` or more from every void cut so far, else the one
    whose pierce point is farthest from them.
    """
    here = np.zeros(2)
    left = set(range(len(groups)))
    out: list[Contour] = []
    voids: list[Polygon] = []

    def dist(c: Contour) -> float:
        return math.dist(c.pierce_xy, here)

    def pick(todo: list[Contour]) -> Contour:
        big = [c for c in todo if c.size_mm >= small_mm]
        if big or not voids:
            return min(big or todo, key=dist)
        gaps = [float(shapely.distance(Point(c.pierce_xy), shapely.union_all(voids[-64:])))
                for c in todo]
        clear = [c for c, g in zip(todo, gaps, strict=True) if g >= small_mm / 2.0]
        if clear:
            return min(clear, key=dist)
        return todo[int(np.argmax(gaps))]

    while left:
        # a part whose hole holds parts not cut yet waits: the slug would take them along
        busy = {enclosing[k] for k in left if k in enclosing}
        ready = [k for k in sorted(left) if k not in busy]
        k = min(ready, key=lambda j: min(dist(c) for c in (groups[j][0] or [groups[j][1]])))
        left.remove(k)
        holes, outline = groups[k]
        todo = list(holes)
        while todo:
            c = pick(todo) if small_mm > 0.0 else min(todo, key=dist)
            todo.remove(c)
            out.append(c)
            voids.append(c.region)
            here = c.points_mm[-1]
        out.append(outline)
        voids.append(outline.region)
        here = outline.points_mm[-1]
    return out


def load_program(path: str | Path, *, kerf_mm: float, lead_in_mm: float = 3.0,
                 micro_joint_mm: float = 0.0, micro_joints_per_part: int = 0,
                 tolerance_mm: float = 0.01,
                 sheet_mm: tuple[float, float] | None = None,
                 origin_mm: tuple[float, float] = (0.0, 0.0),
                 units: str | None = None,
                 layers: tuple[str, ...] | None = None,
                 join_tolerance_mm: float = JOIN_TOLERANCE_MM,
                 open_contours: str = 'cut_closed',
                 small_contour_mm: float = 0.0) -> Program:
    """Read the DXF ``path`` and make its part program (module docstring).

    ``origin_mm``: where the drawing's (0, 0) lies on the sheet (the CNC's work offset).
    ``units``: the drawing's units where the file does not say (:data:`UNIT_MM`; the job
    file's ``dxf_units``). ``layers``: the layers read (None or empty: all).
    ``join_tolerance_mm``: ends this near are joined, pieces shorter dropped, pieces lying
    within it of a longer one dropped as duplicates. ``open_contours``: :data:`OPEN_CONTOURS`
    (``cut_closed``: the closed ones cut, the open ones listed in ``Program.reading``;
    ``refuse``: the first open one refused, naming its entity). ``small_contour_mm``: holes
    smaller are cut after the others, their pierce points away from voids already cut
    (0: nearest next only).

    Every bad input (arguments, file, drawing) raises :class:`ProgramError`, one line.
    """
    name = str(path)
    _check_arguments(name, kerf_mm, lead_in_mm, micro_joint_mm, micro_joints_per_part,
                     tolerance_mm, sheet_mm)
    _number(name, 'join_tolerance_mm', join_tolerance_mm, 0.0, 5.0, open_low=True)
    _number(name, 'small_contour_mm', small_contour_mm, 0.0, 1000.0)
    if open_contours not in OPEN_CONTOURS:
        raise ProgramError(f'{name}: open_contours {open_contours!r} is not one of '
                           f'{" | ".join(OPEN_CONTOURS)}')
    doc = _read(path, name)
    units, scale, units_from = _units(doc, path, name, units)
    wanted = {str(x).casefold() for x in layers} if layers else None
    closed, open_, ignored, found = _pieces(doc, scale, tolerance_mm, name, origin_mm, wanted)
    if wanted is not None:
        missing = sorted(x for x in layers if str(x).casefold() not in
                         {f.casefold() for f in found})
        if missing:
            raise ProgramError(f'{name}: layers: {", ".join(map(str, missing))} not in the '
                               f'drawing (its layers: {", ".join(sorted(found)) or "none"})')
    drawn = [pc.points for pc in closed + open_]
    if not drawn:
        on = f' on layers {", ".join(map(str, layers))}' if wanted is not None else ''
        raise ProgramError(f'{name}: nothing to cut{on}: no line, arc, circle, ellipse, spline '
                           'or polyline in the modelspace or its block INSERTs')
    every = np.vstack(drawn)
    minx, miny = every.min(axis=0)
    maxx, maxy = every.max(axis=0)
    w, h = maxx - minx, maxy - miny
    if max(w, h) < 1.0 or (sheet_mm is not None and (w > 2.0 * sheet_mm[0]
                                                      or h > 2.0 * sheet_mm[1])):
        sheet = f', the sheet {sheet_mm[0]:g} x {sheet_mm[1]:g} mm' if sheet_mm else ''
        raise ProgramError(f'{name}: units absurd for the sheet: the drawing is {w:.4g} x '
                           f'{h:.4g} mm read as {units} ({units_from}){sheet}')
    join = max(join_tolerance_mm, tolerance_mm, 1e-6 * float(np.abs(every).max()))
    closed, open_, short, duplicates = _clean(closed, open_, join, 2.0 * tolerance_mm + 1e-6)
    chained, opened, joins, widest = _chain(open_, join)
    if opened and open_contours == 'refuse':
        o = opened[0].describe()
        (ax, ay), (bx, by) = o['ends_mm']
        raise ProgramError(
            f'{name}: {o["entity"]} on layer {o["layer"]!r}: a contour does not close: its ends '
            f'({ax:.3f}, {ay:.3f}) and ({bx:.3f}, {by:.3f}) mm are '
            f'{math.dist((ax, ay), (bx, by)):.3f} mm apart, no other end within {join:g} mm: '
            'close it in the drawing, raise join_tolerance_mm, put it on a layer not read '
            '(layers:) or set open_contours: cut_closed')
    rings = sorted(closed + chained, key=lambda r: r.order)
    polys = [p for p in (_polygon(r.points, name) for r in rings) if p is not None]
    if not polys:
        what = (f' ({len(opened)} open: {opened[0].label} on layer {opened[0].layer!r} first; '
                f'join_tolerance_mm {join:g})' if opened else '')
        raise ProgramError(f'{name}: no closed contour with an area in the drawing{what}')
    outlines, holes_of, enclosing = _nest(polys, name)
    parts = [Polygon(polys[j].exterior, [polys[h].exterior for h in holes_of[j]])
             for j in outlines]
    index = {j: k for k, j in enumerate(outlines)}

    half = kerf_mm / 2.0
    # Round joins: at an outside corner the beam's centre circles the corner at half a kerf (the
    # arc a control's G41 inserts): the part's corner stays sharp, the path is the shortest and
    # smooth for the motion; a mitre runs out to a point (far out at an acute corner) and back.
    # Segments per quarter circle for a chord error within the tolerance.
    quad = _quad_segs(half, tolerance_mm)
    tree = shapely.STRtree(parts)
    groups = []
    for k, j in enumerate(outlines):
        holes = []
        inside = [polys[q] for q, e in enclosing.items() if e == j]  # parts in its holes
        for h in holes_of[j]:
            slug = polys[h].buffer(-half, quad_segs=quad, join_style='round') if half else polys[h]
            islands = shapely.union_all([q for q in inside if polys[h].contains(q)]).buffer(
                half) if inside else None
            for piece in _polygons(slug):  # none: a hole within the kerf, the beam takes it all
                ring = np.asarray(orient(Polygon(piece.exterior), sign=1.0).exterior.coords)
                region = Polygon(ring)
                pts, lead = _hole_lead(ring, region, lead_in_mm, tolerance_mm, islands)
                holes.append(Contour(_frozen(pts), True, k, _frozen(lead), region))
        outer = (Polygon(polys[j].exterior).buffer(half, quad_segs=quad, join_style='round')
                 if half else Polygon(polys[j].exterior))
        ring = np.asarray(orient(Polygon(outer.exterior), sign=-1.0).exterior.coords)
        fits = _lead_check(k, parts, tree, sheet_mm)
        pts, lead = _outer_lead(ring, lead_in_mm, half, fits)
        region = Polygon(ring, [c.region.exterior.coords for c in holes])
        joints = _micro_joints(pts, micro_joints_per_part, micro_joint_mm)
        groups.append((holes, Contour(_frozen(pts), False, k, _frozen(lead), region, joints)))
    order = _order(groups, {index[p]: index[q] for p, q in enclosing.items()}, small_contour_mm)
    if sheet_mm is not None:
        _check_on_sheet(order, sheet_mm, name)
    return Program(name, units, scale, tuple(order), tuple(parts),
                   (float(minx), float(miny), float(maxx), float(maxy)), tuple(ignored),
                   units_from, tuple(sorted({r.layer for r in rings})),
                   {'join_tolerance_mm': round(join, 6), 'joins': joins,
                    'largest_gap_closed_mm': round(widest, 4),
                    'duplicates_removed': duplicates, 'short_dropped': short,
                    'open_contours': [o.describe() for o in opened]})


def _check_on_sheet(contours: list[Contour], sheet_mm: tuple[float, float], name: str) -> None:
    """Refuse a program with a cut path (lead-in included) off the sheet, one line."""
    for k, c in enumerate(contours, 1):
        pts = np.vstack([c.lead_in_mm, c.points_mm])
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        if lo[0] < 0.0 or lo[1] < 0.0 or hi[0] > sheet_mm[0] or hi[1] > sheet_mm[1]:
            raise ProgramError(
                f'{name}: contour {k} (part {c.part}) is not on the sheet: its path spans x '
                f'{lo[0]:.1f}..{hi[0]:.1f}, y {lo[1]:.1f}..{hi[1]:.1f} mm, the sheet 0..'
                f'{sheet_mm[0]:g} x 0..{sheet_mm[1]:g} mm (dxf_origin_mm places the drawing)')
