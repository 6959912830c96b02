"""A sheet in XY (the job world): what the capacitive sensor and the nozzle see at (x, y).

The plate is its outline with holes (a shapely polygon) over a surface ``z(x, y)`` (tilt,
waviness, the sag of a thin sheet, a warped corner); the kerfs of what has been cut are laid as
they are cut (the current contour's trailing kerf included), and a part cut free drops out (its
region becomes void) or tips up (a known cause of collisions: its material stays, on a plane
rising across it).

Material is a raster of ``raster_mm`` cells (0.25 mm: a 0.2-0.3 mm kerf is one cell wide),
filled once from the polygons with ``shapely.contains_xy`` and changed in place by the kerf and
the parts. Chosen by measurement against exact polygon intersections per tick (docs/job-world.md
gives the figures): a coverage lookup is one sum over the nozzle's cells, with no cost growing
with the number of kerfs and parts, which a polygon difference per kerf segment has.

The sensor's footprint is the nozzle face (``nozzle_diameter_mm`` 8 mm, the sensor model's
``SensorParams.nozzle_diameter_mm``): ``coverage`` is the share of its cells over material, the
quantity the edge model already takes (models/sensor.py: "fraction of the nozzle over the
sheet"); the 7 mm fringe is the edge model's own ``edge_fringe_mm``, not counted twice. The
true gap is the nozzle face minus the highest material under it (the centre and two rings of
points); a contact is any material at or above the face.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

from ladrc_contract.schema import param
import numpy as np
import shapely
from shapely.geometry import Polygon

from .axis import check_fields

RASTER_MM = 0.25
"""Cell size of the material raster [mm]."""
MARGIN_MM = 30.0
"""Raster margin around the plate: the nozzle may leave the sheet by this much and still see."""


@dataclass(frozen=True)
class SurfaceParams:
    """The plate's surface height ``z(x, y)`` [mm] over its flat reference."""

    tilt_x: float = param(0.0, 'mm/mm', 'slope dz/dx', ge=-0.05, le=0.05)
    tilt_y: float = param(0.0, 'mm/mm', 'slope dz/dy', ge=-0.05, le=0.05)
    wave_amp_mm: float = param(0.0, 'mm', 'waviness: amplitude of sin(x) sin(y)', ge=0.0, le=10.0)
    wave_length_mm: float = param(200.0, 'mm', 'waviness: wave length', gt=1.0, le=1e4)
    sag_mm: float = param(0.0, 'mm', 'a thin sheet sagging between its supports (the edges): '
                          'down by this mid-span', ge=0.0, le=20.0)
    corner_warp_mm: float = param(0.0, 'mm', 'the corner at (max x, max y) warped up by this',
                                  ge=0.0, le=20.0)
    warp_size_mm: float = param(150.0, 'mm', 'distance over which the warp falls off', gt=1.0,
                                le=1e4)

    def __post_init__(self) -> None:
        check_fields(self)


class SheetXY:
    """The plate in XY: material raster, surface, kerfs, dropped and tipped parts."""

    def __init__(self, plate: Polygon, surface: SurfaceParams | None = None, *,
                 raster_mm: float = RASTER_MM, nozzle_diameter_mm: float = 8.0) -> None:
        if plate.is_empty or not plate.is_valid:
            raise ValueError('the plate outline is empty or not a valid polygon')
        self.plate = plate
        self.surface = surface or SurfaceParams()
        self.cell_mm = raster_mm
        minx, miny, maxx, maxy = plate.bounds
        self._bounds = (minx, miny, maxx, maxy)
        self.x0, self.y0 = minx - MARGIN_MM, miny - MARGIN_MM
        nx = int(math.ceil((maxx - minx + 2 * MARGIN_MM) / raster_mm))
        ny = int(math.ceil((maxy - miny + 2 * MARGIN_MM) / raster_mm))
        self.material = np.zeros((ny, nx), dtype=bool)
        # row prefix sums of the material (int16: a row has fewer than 32767 cells): the
        # material between two x positions of a row is a difference of two lookups
        if nx >= 32767:
            raise ValueError(f'the plate is too wide for the raster ({nx} cells)')
        self._prefix = np.zeros((ny, nx + 1), dtype=np.int16)
        self._stride = nx + 1
        self._prefix_flat = self._prefix.reshape(-1)  # views, for one gather per lookup
        self._material_pad = np.zeros((ny, nx + 1), dtype=bool)  # material, a row like _prefix
        self._material_flat = self._material_pad.reshape(-1)
        self._prepared: dict[int, tuple[Polygon, tuple[slice, slice, np.ndarray]]] = {}
        self._fill(plate, True)
        r = nozzle_diameter_mm / 2.0
        self.nozzle_radius_mm = r
        self._k = int(math.ceil(r / raster_mm))
        self._rows = np.arange(-self._k, self._k + 1)
        # the face's sample points for the highest material under it: centre, r/2, r
        angles = np.linspace(0.0, 2.0 * math.pi, 8, endpoint=False)
        ring = [(0.0, 0.0)] + [(rr * math.cos(a), rr * math.sin(a))
                               for rr in (r / 2.0, r) for a in angles]
        self._face = ring
        self.tipped: list[tuple[Polygon, float, float, float]] = []  # (region, x0, x1, rise)

    # ---- geometry --------------------------------------------------------------------------
    def _cells(self, geom) -> tuple[slice, slice, np.ndarray]:
        """Return the raster window of ``geom``'s bounds and which of its cells it covers.

        A scan-line fill (even-odd over every ring's edges, at the cell centres' rows): the
        polygon test per cell (``shapely.contains_xy``) took 5 s for a 1 x 0.5 m plate.
        """
        minx, miny, maxx, maxy = geom.bounds
        c = self.cell_mm
        i0 = max(int((minx - self.x0) / c) - 1, 0)
        j0 = max(int((miny - self.y0) / c) - 1, 0)
        i1 = min(int((maxx - self.x0) / c) + 2, self.material.shape[1])
        j1 = min(int((maxy - self.y0) / c) + 2, self.material.shape[0])
        ys = self.y0 + (np.arange(j0, j1) + 0.5) * c
        rings = []
        for poly in getattr(geom, 'geoms', [geom]):
            rings += [np.asarray(poly.exterior.coords)] + [np.asarray(r.coords)
                                                           for r in poly.interiors]
        edges = np.concatenate([np.c_[r[:-1], r[1:]] for r in rings])  # x0, y0, x1, y1
        ex0, ey0, ex1, ey1 = edges.T
        y = ys[:, None]
        crosses = (ey0 <= y) != (ey1 <= y)  # the row's line crosses the edge (half-open)
        with np.errstate(divide='ignore', invalid='ignore'):
            xc = ex0 + (y - ey0) * (ex1 - ex0) / (ey1 - ey0)
        xc = np.where(crosses, xc, 0.0)  # (horizontal edges: no crossing, no NaN)
        # a crossing at x toggles the cells whose centre lies right of it
        col = np.ceil((xc - self.x0) / c - 0.5).astype(np.int64) - i0
        toggles = np.zeros((j1 - j0, i1 - i0 + 1), dtype=np.int32)
        rr, ee = np.nonzero(crosses)
        np.add.at(toggles, (rr, np.clip(col[rr, ee], 0, i1 - i0)), 1)
        inside = (np.cumsum(toggles, axis=1)[:, :-1] & 1).astype(bool)
        return slice(j0, j1), slice(i0, i1), inside

    def prepare(self, regions: list[Polygon]) -> None:
        """Rasterise regions that will drop out later now (a job's parts, before its loop).

        A part's scan-line fill takes tens of milliseconds: inside a live 2 kHz loop that is a
        stall the controller sees as stale input. Prepared, a drop is a masked write.
        """
        for region in regions:
            self._prepared[id(region)] = (region, self._cells(region))

    def _fill(self, geom, value: bool) -> None:
        held = self._prepared.get(id(geom))
        rows, cols, inside = held[1] if held is not None and held[0] is geom else self._cells(
            geom)
        window = self.material[rows, cols]  # a view: writes through
        window[inside] = value
        self._update_rows(rows.start, rows.stop, cols.start, cols.stop)

    def _update_rows(self, j0: int, j1: int, i0: int = 0, i1: int | None = None) -> None:
        """Update the row prefix sums after the material of rows j0:j1, columns i0:i1 changed.

        The window's columns are summed again from the prefix at i0; the columns right of it
        shift by the change of the window's sum (one add, not a sum of the whole width).
        """
        m = self.material
        i1 = m.shape[1] if i1 is None else i1
        p = self._prefix[j0:j1]  # p[:, k]: the material of m[:, :k]
        old = p[:, i1].copy()
        np.cumsum(m[j0:j1, i0:i1], axis=1, dtype=np.int16, out=p[:, i0 + 1:i1 + 1])
        p[:, i0 + 1:i1 + 1] += p[:, i0:i0 + 1]
        if i1 < m.shape[1]:
            delta = p[:, i1] - old
            if delta.any():
                p[:, i1 + 1:] += delta[:, None]
        self._material_pad[j0:j1, i0:i1] = m[j0:j1, i0:i1]

    def z_mm(self, x: float, y: float) -> float:
        """Return the surface height at (x, y) [mm] (without tipped parts)."""
        s = self.surface
        z = s.tilt_x * x + s.tilt_y * y
        if s.wave_amp_mm:
            w = 2.0 * math.pi / s.wave_length_mm
            z += s.wave_amp_mm * math.sin(w * x) * math.sin(w * y)
        if s.sag_mm or s.corner_warp_mm:
            minx, miny, maxx, maxy = self._bounds
            u = (x - minx) / (maxx - minx) if maxx > minx else 0.5
            v = (y - miny) / (maxy - miny) if maxy > miny else 0.5
            if s.sag_mm:  # a parabola in each direction, 0 at the supports (the edges)
                z -= s.sag_mm * 16.0 * u * (1.0 - u) * v * (1.0 - v)
            if s.corner_warp_mm:
                d = math.hypot(maxx - x, maxy - y)
                z += s.corner_warp_mm * max(0.0, 1.0 - d / s.warp_size_mm) ** 2
        return z

    def _index(self, x: float, y: float) -> tuple[int, int]:
        c = self.cell_mm
        return int((y - self.y0) / c), int((x - self.x0) / c)

    def material_at(self, x: float, y: float) -> bool:
        """Return whether there is material at (x, y)."""
        j, i = self._index(x, y)
        m = self.material
        return 0 <= j < m.shape[0] and 0 <= i < m.shape[1] and bool(m[j, i])

    def coverage(self, x: float, y: float) -> float:
        """Return the share of the nozzle face over material (0..1).

        Row by row over the face: the chord of each cell row at its centre, its material by
        the row's prefix sums with the end cells counted by fraction, so the coverage moves
        smoothly with (x, y), not in cell steps.
        """
        c, r, k = self.cell_mm, self.nozzle_radius_mm, self._k
        m = self.material
        u = (x - self.x0) / c  # position in cells
        v = (y - self.y0) / c
        j_mid = int(v)
        if not (k + 1 <= j_mid < m.shape[0] - k - 1 and k + 1 <= u < m.shape[1] - k - 1):
            return 0.0  # beyond the raster: no sheet
        dy = (self._rows + (j_mid + 0.5 - v)) * c
        hw = np.sqrt(np.maximum(r * r - dy * dy, 0.0)) / c
        a = u - hw
        b = u + hw
        ia = a.astype(np.int64)
        ib = b.astype(np.int64)
        base = (self._rows + j_mid) * self._stride
        idx = np.concatenate((base + ib, base + ia))
        p = self._prefix_flat.take(idx)
        f = self._material_flat.take(idx)
        n = len(ia)
        covered = float((p[:n] - p[n:]).sum() + ((b - ib) * f[:n]).sum()
                        - ((a - ia) * f[n:]).sum())
        total = float((b - a).sum())
        return float(covered / total) if total > 0.0 else 0.0

    def top_mm(self, x: float, y: float) -> float:
        """Return the highest material under the nozzle face [mm]; -inf when there is none."""
        return -self.under_face(x, y, 0.0)[1]

    def under_face(self, x: float, y: float, nozzle_mm: float) -> tuple[float, float]:
        """Return (sensed gap, true gap) of a nozzle face at height ``nozzle_mm`` over (x, y).

        True gap: to the highest material under the face (+inf: none). Sensed gap: the gap of
        a parallel plate of the same capacitance, the harmonic mean of the gaps to the
        material under the face points (the capacitance is the sum of their 1/gap): a tipped
        part under one side reads closer, as a real sensor does; a flat sheet reads its gap.
        """
        true_gap = math.inf
        inv = 0.0
        n = 0
        for dx, dy in self._face:
            px, py = x + dx, y + dy
            if not self.material_at(px, py):
                continue
            z = self.z_mm(px, py)
            for region, x0, x1, rise in self.tipped:
                if x0 <= px <= x1 and shapely.contains_xy(region, px, py):
                    z += rise * (px - x0) / (x1 - x0)
                    break
            d = nozzle_mm - z
            true_gap = d if d < true_gap else true_gap
            inv += 1.0 / (d if d > 1e-3 else 1e-3)
            n += 1
        if n == 0:
            return nozzle_mm - self.z_mm(x, y), math.inf
        return n / inv, true_gap

    # ---- cutting -----------------------------------------------------------------------------
    def lay_kerf(self, x0: float, y0: float, x1: float, y1: float, width_mm: float) -> None:
        """Clear the kerf of the cut from (x0, y0) to (x1, y1): cells within width/2 of it."""
        c = self.cell_mm
        half = max(width_mm, c) / 2.0  # at least one cell: the raster's resolution
        m = self.material
        i0 = max(int((min(x0, x1) - half - self.x0) / c), 0)
        i1 = min(int((max(x0, x1) + half - self.x0) / c) + 1, m.shape[1])
        j0 = max(int((min(y0, y1) - half - self.y0) / c), 0)
        j1 = min(int((max(y0, y1) + half - self.y0) / c) + 1, m.shape[0])
        if i0 >= i1 or j0 >= j1:
            return
        px = (self.x0 + (np.arange(i0, i1) + 0.5) * c)[None, :]
        py = (self.y0 + (np.arange(j0, j1) + 0.5) * c)[:, None]
        dx, dy = x1 - x0, y1 - y0
        ll = dx * dx + dy * dy
        t = np.clip(((px - x0) * dx + (py - y0) * dy) / ll, 0.0, 1.0) if ll > 0.0 else 0.0
        d2 = (px - x0 - t * dx) ** 2 + (py - y0 - t * dy) ** 2
        m[j0:j1, i0:i1] &= d2 > half * half
        self._update_rows(j0, j1, i0, i1)

    def drop(self, region: Polygon) -> None:
        """Drop a part or a slug cut free: its region becomes void."""
        self._fill(region, False)

    def tip(self, region: Polygon, rise_mm: float) -> None:
        """Tip a part cut free up: its material stays, rising ``rise_mm`` across it in x."""
        minx, _, maxx, _ = region.bounds
        shapely.prepare(region)
        self.tipped.append((region, minx, max(maxx, minx + 1e-6), rise_mm))

    def void_ahead_mm(self, path_xy: np.ndarray, step_mm: float) -> float:
        """Return the path distance to the first void point along ``path_xy`` (inf: none).

        ``path_xy``: points every ``step_mm`` along the path ahead, the first one step ahead.
        """
        if len(path_xy) == 0:
            return math.inf
        c = self.cell_mm
        j = ((path_xy[:, 1] - self.y0) / c).astype(np.int64)
        i = ((path_xy[:, 0] - self.x0) / c).astype(np.int64)
        m = self.material
        ok = (j >= 0) & (j < m.shape[0]) & (i >= 0) & (i < m.shape[1])
        solid = np.zeros(len(path_xy), dtype=bool)
        solid[ok] = m[j[ok], i[ok]]
        void = np.flatnonzero(~solid)
        return math.inf if void.size == 0 else float((void[0] + 1) * step_mm)
