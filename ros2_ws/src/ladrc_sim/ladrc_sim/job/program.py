"""A part program from a nest drawn in DXF, as a CAM makes it for a laser CNC.

* **Reading** (ezdxf): LINE, ARC, CIRCLE, ELLIPSE, SPLINE, LWPOLYLINE (bulges), POLYLINE in
  modelspace, flattened by ezdxf's path module within ``tolerance_mm``; other entities (text,
  dimensions, hatches, blocks) are ignored and listed. ``$INSUNITS`` must say the units; a
  drawing without them, or whose size is absurd for the sheet, is refused with one line.
* **Chaining**: open pieces are joined end to end (either way round) into closed contours; a
  chain that does not close is refused, naming where it is open.
* **Nesting**: a contour inside an odd number of others is a hole of the smallest part
  containing it; the others are parts (a part inside another part's hole is a part).
* **Kerf compensation** on the scrap side (G42, the beam on the right of the travel): an outer
  contour runs half a kerf outside the part, clockwise; a hole half a kerf inside it,
  counter-clockwise. Round joins: the beam's centre goes round an outside corner on an arc.
* **Lead-ins** from the scrap: into a hole from its inner point, onto an outline along the
  outward normal of its longest edge (an edge whose lead-in stays on the sheet when the sheet
  is given). **Micro-joints** (optional): beam-off gaps on outer contours.
* **Order**: a part's holes before its outline; parts nearest next from the origin, holes
  nearest next within a part.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path

import ezdxf
from ezdxf import path as dxf_path
import numpy as np
import shapely
from shapely.geometry import LinearRing, Point, Polygon
from shapely.geometry.polygon import orient

UNITS = {1: ('in', 25.4), 4: ('mm', 1.0), 5: ('cm', 10.0), 6: ('m', 1000.0)}
"""``$INSUNITS`` codes accepted: name and millimetres per unit."""
SUPPORTED = ('LINE', 'ARC', 'CIRCLE', 'ELLIPSE', 'SPLINE', 'LWPOLYLINE', 'POLYLINE')


class ProgramError(ValueError):
    """A drawing cannot be a part program; one line naming the file and the problem."""


@dataclass(frozen=True, eq=False)  # (arrays: identity, not value, equality)
class Contour:
    """One contour of the program, kerf-compensated, with its lead-in, in cut order."""

    points_mm: np.ndarray      # (n, 2) closed path (first == last)
    inner: bool                # a hole of a part (cut before the part's outline)
    part: int                  # index of its part in Program.parts
    lead_in_mm: np.ndarray     # (m, 2) from the pierce point to points_mm[0]
    region: Polygon            # what drops out once it is cut (the slug, or the part)
    micro_joints: tuple[tuple[float, float], ...] = ()  # beam-off path intervals

    @property
    def pierce_xy(self) -> tuple[float, float]:
        """Return the pierce point (the lead-in's start)."""
        return float(self.lead_in_mm[0, 0]), float(self.lead_in_mm[0, 1])

    @property
    def length_mm(self) -> float:
        """Return the contour's path length."""
        d = np.diff(self.points_mm, axis=0)
        return float(np.hypot(d[:, 0], d[:, 1]).sum())


@dataclass(frozen=True, eq=False)
class Program:
    """A part program: the contours in cut order and the parts as drawn."""

    source: str
    units: str
    scale_to_mm: float
    contours: tuple[Contour, ...]
    parts: tuple[Polygon, ...]
    bounds_mm: tuple[float, float, float, float]
    ignored: tuple[str, ...] = ()


def _pieces(doc, scale: float, tol: float, name: str) -> tuple[list, list, list[str]]:
    """Return the closed rings and the open pieces (lists of (x, y)), and ignored types."""
    closed, open_, ignored = [], [], set()
    for e in doc.modelspace():
        kind = e.dxftype()
        if kind not in SUPPORTED:
            ignored.add(kind)
            continue
        try:
            p = dxf_path.make_path(e)
            pts = [(v.x * scale, v.y * scale) for v in p.flattening(distance=tol / scale)]
        except Exception as exc:  # noqa: BLE001 - a broken entity is the drawing's problem
            raise ProgramError(f'{name}: {kind} {e.dxf.handle} cannot be read: {exc}') from None
        if len(pts) < 2:
            continue
        if math.dist(pts[0], pts[-1]) <= tol and len(pts) > 3:
            closed.append(pts)
        else:
            open_.append(pts)
    return closed, open_, sorted(ignored)


def _chain(pieces: list, tol: float, name: str) -> list:
    """Join open pieces end to end into closed rings."""
    rings = []
    left = [list(p) for p in pieces]
    while left:
        chain = left.pop()
        while math.dist(chain[0], chain[-1]) > tol:
            end = chain[-1]
            found = next((k for k, p in enumerate(left)
                          if math.dist(p[0], end) <= tol or math.dist(p[-1], end) <= tol), None)
            if found is None:
                x, y = end
                raise ProgramError(f'{name}: a contour does not close: open end at '
                                   f'({x:.3f}, {y:.3f}) mm (nothing within {tol:g} mm)')
            p = left.pop(found)
            chain += p[1:] if math.dist(p[0], end) <= tol else p[::-1][1:]
        rings.append(chain)
    return rings


def _nest(polys: list[Polygon]) -> list[Polygon]:
    """Return the parts: each even-depth contour with the odd-depth ones directly inside."""
    polys = sorted(polys, key=lambda p: -p.area)
    depth = [sum(1 for q in polys[:i] if q.contains(p)) for i, p in enumerate(polys)]
    parts = []
    for i, p in enumerate(polys):
        if depth[i] % 2:
            continue
        holes = [q.exterior for j, q in enumerate(polys)
                 if depth[j] == depth[i] + 1 and p.contains(q)]
        parts.append(Polygon(p.exterior, holes))
    return parts


def _ring(poly) -> np.ndarray:
    """Return the exterior of ``poly`` (the largest piece of a multipolygon) as (n, 2)."""
    if poly.geom_type == 'MultiPolygon':
        poly = max(poly.geoms, key=lambda g: g.area)
    return np.asarray(poly.exterior.coords)


def _start_at(ring: np.ndarray, k: int, point: np.ndarray) -> np.ndarray:
    """Return the closed ring re-ordered to start at ``point`` on its edge ``k``."""
    body = ring[:-1]
    order = np.r_[body[k + 1:], body[:k + 1]]
    out = np.vstack((point, order, point))
    return out


def _outer_lead(ring: np.ndarray, lead: float, sheet: Polygon | None) -> tuple:
    """Return (ring from the start, lead-in) of a clockwise outline: onto its longest edge."""
    seg = np.diff(ring, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    for k in np.argsort(-length):
        if length[k] < 1e-6:
            break
        mid = ring[k] + seg[k] / 2.0
        normal = np.array([-seg[k, 1], seg[k, 0]]) / length[k]  # left of travel: outward (cw)
        start = mid + normal * lead
        if sheet is None or sheet.contains(Point(start).buffer(4.0 + 1.0)):
            return _start_at(ring, int(k), mid), np.vstack((start, mid))
    k = int(np.argmax(length))  # nowhere on the sheet: the longest edge anyway
    mid = ring[k] + seg[k] / 2.0
    normal = np.array([-seg[k, 1], seg[k, 0]]) / max(length[k], 1e-9)
    return _start_at(ring, k, mid), np.vstack((mid + normal * lead, mid))


def _hole_lead(ring: np.ndarray, slug: Polygon, lead: float) -> tuple:
    """Return (ring from the start, lead-in) of a hole: from its inner point to its edge."""
    centre = np.asarray(slug.representative_point().coords[0])
    seg = np.diff(ring, axis=0)
    # the point of the ring nearest the centre, on its edge
    best = (math.inf, 0, ring[0])
    for k in range(len(seg)):
        ll = float(seg[k] @ seg[k])
        t = 0.0 if ll == 0.0 else min(max(float((centre - ring[k]) @ seg[k]) / ll, 0.0), 1.0)
        p = ring[k] + t * seg[k]
        d = float(np.hypot(*(p - centre)))
        if d < best[0]:
            best = (d, k, p)
    d, k, p = best
    reach = min(lead, 0.8 * d) if d > 0.5 / 0.8 else d  # a small hole: from its centre
    start = p + (centre - p) / max(d, 1e-9) * reach
    return _start_at(ring, k, p), np.vstack((start, p))


def _joints(points: np.ndarray, n: int, gap: float) -> tuple[tuple[float, float], ...]:
    if n <= 0 or gap <= 0.0:
        return ()
    d = np.diff(points, axis=0)
    total = float(np.hypot(d[:, 0], d[:, 1]).sum())
    usable = total - 2.0
    if usable <= n * gap:
        return ()
    return tuple((2.0 + usable * (i + 0.5) / n, 2.0 + usable * (i + 0.5) / n + gap)
                 for i in range(n))


def load_program(path: str | Path, *, kerf_mm: float, lead_in_mm: float = 3.0,
                 micro_joint_mm: float = 0.0, micro_joints_per_part: int = 0,
                 tolerance_mm: float = 0.01,
                 sheet_mm: tuple[float, float] | None = None) -> Program:
    """Read ``path`` and make its part program (module docstring); :class:`ProgramError`."""
    name = str(path)
    if not 0.0 <= kerf_mm <= 5.0:
        raise ProgramError(f'{name}: kerf_mm {kerf_mm!r} outside 0..5 mm')
    if not 0.0 <= lead_in_mm <= 50.0:
        raise ProgramError(f'{name}: lead_in_mm {lead_in_mm!r} outside 0..50 mm')
    if not 0.0 < tolerance_mm <= 1.0:
        raise ProgramError(f'{name}: tolerance_mm {tolerance_mm!r} outside 0 (excl.)..1 mm')
    try:
        doc = ezdxf.readfile(str(path))
    except OSError as exc:
        raise ProgramError(f'{name}: cannot read: {exc.strerror or exc}') from None
    except ezdxf.DXFError as exc:
        raise ProgramError(f'{name}: not a readable DXF: {" ".join(str(exc).split())}') from None
    code = int(doc.header.get('$INSUNITS', 0))
    if code not in UNITS:
        raise ProgramError(f'{name}: drawing units missing or unsupported ($INSUNITS={code}): '
                           'set them to millimetres (4), or cm, m, inches')
    units, scale = UNITS[code]
    closed, open_, ignored = _pieces(doc, scale, tolerance_mm, name)
    size = max([max(abs(x) for x, _ in r) for r in closed + open_] or [0.0])
    rings = closed + _chain(open_, max(tolerance_mm, 1e-6 * size), name)
    polys = [Polygon(r).buffer(0) for r in rings]
    polys = [p if p.geom_type == 'Polygon' else max(p.geoms, key=lambda g: g.area)
             for p in polys if p.area > 1e-6]
    if not polys:
        raise ProgramError(f'{name}: no closed contour in the drawing')
    minx, miny, maxx, maxy = shapely.total_bounds(polys)
    w, h = maxx - minx, maxy - miny
    if max(w, h) < 1.0 or (sheet_mm is not None and (w > 2.0 * sheet_mm[0]
                                                      or h > 2.0 * sheet_mm[1])):
        raise ProgramError(f'{name}: units absurd for the sheet: the drawing is {w:.4g} x '
                           f'{h:.4g} mm in {units} ($INSUNITS={code})'
                           + (f', the sheet {sheet_mm[0]:g} x {sheet_mm[1]:g} mm'
                              if sheet_mm else ''))
    parts = _nest(polys)
    sheet = (Polygon([(0, 0), (sheet_mm[0], 0), (sheet_mm[0], sheet_mm[1]), (0, sheet_mm[1])])
             if sheet_mm else None)
    half = kerf_mm / 2.0
    per_part = []
    for i, part in enumerate(parts):
        holes = []
        for hole in part.interiors:
            slug = Polygon(hole).buffer(-half, join_style='round') if half else Polygon(hole)
            if slug.is_empty or slug.area <= 1e-6:
                continue  # smaller than the kerf: the beam takes it whole
            ring = np.asarray(orient(Polygon(_ring(slug)), sign=1.0).exterior.coords)  # ccw
            pts, lead = _hole_lead(ring, Polygon(ring), lead_in_mm)
            holes.append(Contour(pts, True, i, lead, Polygon(ring)))
        outer = Polygon(part.exterior).buffer(half, join_style='round') if half else part
        ring = np.asarray(orient(Polygon(_ring(outer)), sign=-1.0).exterior.coords)  # cw
        pts, lead = _outer_lead(ring, lead_in_mm, sheet)
        region = Polygon(ring, [c.region.exterior.coords for c in holes])
        per_part.append((holes, Contour(pts, False, i, lead, region,
                                        _joints(pts, micro_joints_per_part, micro_joint_mm))))
    # order: parts nearest next from the origin; within a part its holes nearest next, then
    # its outline
    order, here = [], np.zeros(2)
    left = list(range(len(per_part)))
    while left:
        k = min(left, key=lambda j: float(np.hypot(*(np.asarray(
            (per_part[j][0] or [per_part[j][1]])[0].pierce_xy) - here))))
        left.remove(k)
        holes, outline = per_part[k]
        todo = list(holes)
        while todo:
            c = min(todo, key=lambda q: float(np.hypot(*(np.asarray(q.pierce_xy) - here))))
            todo.remove(c)
            order.append(c)
            here = np.asarray(c.points_mm[-1])
        order.append(outline)
        here = np.asarray(outline.points_mm[-1])
    return Program(name, units, scale, tuple(order), tuple(parts),
                   (float(minx), float(miny), float(maxx), float(maxy)), tuple(ignored))


def ring_of(points: np.ndarray) -> LinearRing:
    """Return ``points`` as a shapely ring (for drawing and checks)."""
    return LinearRing(points)
