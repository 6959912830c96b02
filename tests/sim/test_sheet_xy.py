"""The job world's sheet in XY (models/sheet_xy.py) and the CNC's path motion (job/motion.py)."""

from __future__ import annotations

import math

from ladrc_sim.job.motion import PathMotion
from ladrc_sim.models.axis import ParamError
from ladrc_sim.models.sheet_xy import SheetXY, SurfaceParams
import numpy as np
import pytest
from shapely.geometry import Point, box

H = 0.0005


@pytest.fixture(scope='module')
def plate():
    return box(0, 0, 200, 100).difference(Point(120, 50).buffer(15, quad_segs=64))


def exact(poly, x, y, r=4.0) -> float:
    disc = Point(x, y).buffer(r, quad_segs=128)
    return disc.intersection(poly).area / disc.area


@pytest.mark.parametrize('x, y', [(0.0, 50.0), (2.0, 50.0), (-2.5, 50.0), (3.3, 47.1),
                                  (0.0, 0.0), (120.0 - 15.0, 50.0), (120.0 - 17.0, 52.3),
                                  (50.0, 50.0), (-10.0, 50.0), (120.0, 50.0)])
def test_coverage_is_the_share_of_the_nozzle_face_over_material(plate, x, y):
    s = SheetXY(plate)
    assert s.coverage(x, y) == pytest.approx(exact(plate, x, y), abs=0.006)


def test_coverage_moves_smoothly_not_in_cell_steps(plate):
    s = SheetXY(plate)
    xs = np.linspace(-3.0, 3.0, 241)  # 0.025 mm steps, a tenth of a cell
    cov = np.array([s.coverage(x, 50.0) for x in xs])
    assert np.all(np.diff(cov) > 0.0) and np.max(np.diff(cov)) < 0.01


def test_a_kerf_a_dropped_part_and_a_tipped_one(plate):
    s = SheetXY(plate, SurfaceParams())
    before = s.coverage(30.0, 30.0)
    s.lay_kerf(20.0, 30.0, 40.0, 30.0, 0.25)  # a kerf under the nozzle's centre
    assert not s.material_at(30.0, 30.0) and s.material_at(30.0, 30.5)
    assert 0.9 < s.coverage(30.0, 30.0) < before - 0.04  # ~0.25 x 8 mm of a 50 mm² face
    part = box(150, 20, 180, 40)
    s.drop(part)
    assert s.coverage(165.0, 30.0) == 0.0 and s.top_mm(165.0, 30.0) == -math.inf
    tipped = box(20, 60, 60, 90)
    s.tip(tipped, 3.0)
    assert s.material_at(40.0, 75.0)
    # the highest face point on the part: x = 59 (the face reaches 63, beyond the part)
    assert s.top_mm(59.0, 75.0) == pytest.approx(3.0 * (59.0 - 20.0) / 40.0, abs=1e-9)


def test_void_ahead_finds_the_first_void_along_the_path(plate):
    s = SheetXY(plate)
    path = np.c_[np.arange(1, 61) * 0.5 + 90.0, np.full(60, 50.0)]  # toward the hole at 105
    assert s.void_ahead_mm(path, 0.5) == pytest.approx(15.0, abs=0.5)
    assert s.void_ahead_mm(path[:10], 0.5) == math.inf


def test_surface_parameters_are_checked():
    with pytest.raises(ParamError, match='wave_length_mm'):
        SurfaceParams(wave_length_mm=0.0)
    s = SheetXY(box(0, 0, 100, 100), SurfaceParams(sag_mm=2.0, corner_warp_mm=1.0,
                                                   warp_size_mm=50.0))
    assert s.z_mm(50.0, 50.0) == pytest.approx(-2.0) and s.z_mm(0.0, 0.0) == 0.0
    assert s.z_mm(100.0, 100.0) == pytest.approx(1.0)


def run(m: PathMotion, max_ticks: int = 200000) -> tuple[np.ndarray, np.ndarray]:
    xy, v = [], []
    for _ in range(max_ticks):
        xy.append(m.step())
        v.append(m.v)
        if m.done:
            break
    return np.array(xy), np.array(v)


def test_path_motion_slows_in_corners_never_exceeds_feed_and_ends_at_rest():
    square = np.array([[0, 0], [50, 0], [50, 50], [0, 50], [0, 0]], dtype=float)
    m = PathMotion(square, 100.0, 2000.0, 0.05, H)
    xy, v = run(m)
    assert m.done and v[-1] == 0.0 and np.allclose(xy[-1], [0.0, 0.0], atol=1e-9)
    assert v.max() <= 100.0 + 1e-9
    assert np.max(np.abs(np.diff(v))) <= 1.1 * 2000.0 * H  # (the last tick: a residue)
    corner = np.argmin(np.hypot(xy[:, 0] - 50.0, xy[:, 1]))
    v_corner = math.sqrt(2000.0 * 0.05 * math.sin(math.pi / 4) / (1 - math.sin(math.pi / 4)))
    assert v[corner] <= v_corner * 1.2 + 2000.0 * H  # slowed to the junction speed
    step = np.hypot(*np.diff(xy, axis=0).T)
    assert step.sum() == pytest.approx(200.0, rel=1e-3)


def test_short_segments_never_reach_the_feed():
    m = PathMotion(np.array([[0, 0], [2.0, 0]]), 100.0, 2000.0, 0.05, H)
    _, v = run(m)
    assert v.max() <= math.sqrt(2000.0 * 2.0) * 1.02 < 100.0  # a triangle: sqrt(a L) peak


def test_the_row_sums_after_kerfs_and_drops_equal_a_sum_of_the_whole_raster(plate):
    """The window-only update of the row prefix sums (kerfs, prepared and unprepared drops)."""
    sheet = SheetXY(plate)
    parts = [box(20, 20, 60, 60), Point(150, 30).buffer(8)]
    sheet.prepare(parts[:1])  # one rasterised before, one when it drops
    rng = np.random.default_rng(3)
    for x0, y0, x1, y1 in rng.uniform(5, 95, (40, 4)) * [2, 1, 2, 1]:
        sheet.lay_kerf(x0, y0, x1, y1, 0.3)
    for part in parts:
        sheet.drop(part)
    m = sheet.material
    assert not m[sheet._index(40, 40)] and not m[sheet._index(150, 30)]
    whole = np.zeros((m.shape[0], m.shape[1] + 1), dtype=np.int64)
    whole[:, 1:] = np.cumsum(m, axis=1)
    assert np.array_equal(sheet._prefix, whole)
    assert np.array_equal(sheet._material_pad[:, :-1], m)
