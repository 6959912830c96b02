"""The job library's drawings, written with ezdxf (``python -m ladrc_sim.job.dxf_library DIR``).

* :func:`plate_with_holes`: one 300 x 200 mm plate at (50, 50) with three round holes and two
  square ones (one with rounded corners: a bulged polyline).
* :func:`nest`: 16 parts on a 1000 x 500 mm sheet drawn with every entity kind the reader
  takes (closed polylines, circles, loose lines to be chained, arcs and lines, an ellipse, a
  closed spline): three outlines within 5 mm of the sheet's border, five parts 5-6 mm apart;
  ``seed`` shuffles the drawing order only.
* :func:`tipping_pair`: two rectangles 3 mm apart; the job tips the first one up.

Deterministic; the shipped DXFs under ``jobs/`` are its output.
"""

from __future__ import annotations

import math
from pathlib import Path
import random
import sys

import ezdxf
from ezdxf.math import Vec3


def _new():
    doc = ezdxf.new('R2010', units=4)  # millimetres ($MEASUREMENT metric too)
    doc.header['$INSUNITS'] = 4        # (what the reader asks for, said again)
    return doc, doc.modelspace()


def _rect(msp, x: float, y: float, w: float, h: float) -> None:
    msp.add_lwpolyline([(x, y), (x + w, y), (x + w, y + h), (x, y + h)], close=True)


def _rounded_square(msp, x: float, y: float, a: float, r: float) -> None:
    """Add a square with corners of radius ``r``: a closed polyline with bulged corners."""
    b = math.tan(math.pi / 8.0)  # bulge of a quarter circle
    pts = [(x + r, y, 0), (x + a - r, y, b), (x + a, y + r, 0), (x + a, y + a - r, b),
           (x + a - r, y + a, 0), (x + r, y + a, b), (x, y + a - r, 0), (x, y + r, b)]
    msp.add_lwpolyline(pts, format='xyb', close=True)


def plate_with_holes(path: str | Path) -> None:
    """Write the plate with round and square holes."""
    doc, msp = _new()
    _rect(msp, 50, 50, 300, 200)
    for cx, cy, r in ((100, 100, 10), (170, 100, 15), (250, 110, 20)):
        msp.add_circle((cx, cy), r)
    _rect(msp, 90, 170, 20, 20)
    _rounded_square(msp, 200, 180, 30, 3)
    doc.saveas(str(path))


def _closed_spline(msp, fit: list[tuple[float, float]]) -> None:
    """Add a closed spline through ``fit``: the first point again at the end, one tangent there.

    The closed flag is set too; ezdxf (and a CAD) then draws it smooth through the joint.
    """
    pts = [Vec3(p) for p in fit] + [Vec3(fit[0])]
    s = msp.add_spline(pts)
    s.dxf.start_tangent = s.dxf.end_tangent = (pts[1] - pts[-2]).normalize()
    s.closed = True


def nest(path: str | Path, seed: int = 0) -> None:
    """Write the 16-part nest on a 1000 x 500 mm sheet.

    The geometry is the same for every seed; a seed other than 0 draws the entities in a
    shuffled order, each loose line either way round (the reader must not care). Deterministic
    for a seed; seed 0 is the drawing order below (the shipped ``jobs/nest_16.dxf``).
    """
    doc, msp = _new()
    draw: list = []  # (one part's entities) per item: what a seed shuffles

    def line(a: tuple[float, float], b: tuple[float, float]) -> None:
        draw.append(lambda m, flip=False: m.add_line(b, a) if flip else m.add_line(a, b))

    def part(fn) -> None:
        draw.append(lambda m, flip=False: fn(m))

    # bottom row: within 5 mm of the left / bottom / right edges
    part(lambda m: _rect(m, 3, 4, 120, 80))            # 1: 3 mm from the left, 4 from the bottom
    part(lambda m: m.add_circle((60, 44), 15))         #    its round hole
    part(lambda m: _rect(m, 880, 4, 116, 90))          # 2: 4 mm from the right and the bottom
    part(lambda m: _rounded_square(m, 920, 30, 30, 4))  #   a rounded square hole
    part(lambda m: m.add_circle((200, 45), 40))        # 3: a disc
    pts = [(270, 5), (390, 5), (390, 35), (300, 35), (300, 90), (270, 90), (270, 5)]
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        line(a, b)                                     # 4: an L of loose lines, 5 mm up
    line((420, 20), (500, 20))                         # 5: an obround of arcs and lines,
    part(lambda m: m.add_arc((500, 40), 20, -90, 90))  #    10 mm right of the L
    line((500, 60), (420, 60))
    part(lambda m: m.add_arc((420, 40), 20, 90, 270))
    part(lambda m: _rect(m, 540, 10, 150, 80))         # 6: a plate with an ellipse hole
    part(lambda m: m.add_ellipse((615, 50), major_axis=(40, 0), ratio=0.5))
    fit = [(730, 20), (800, 15), (850, 40), (840, 85), (770, 95), (725, 60)]
    part(lambda m: _closed_spline(m, fit))             # 7: a spline outline
    # middle row: parts 5-6 mm apart (the kerfs cut close by)
    x = 10.0
    for k, w in enumerate((100, 90, 110, 95, 105)):
        part(lambda m, x=x, w=w: _rect(m, x, 130, w, 120))  # 8-12
        if k % 2 == 0:
            part(lambda m, x=x, w=w: m.add_circle((x + w / 2, 190), 18))
        else:
            part(lambda m, x=x, w=w: _rect(m, x + w / 2 - 15, 175, 30, 30))
        x += w + 5.0 if k < 3 else w + 6.0
    # top row
    for k, cx in enumerate((650, 820)):
        part(lambda m, cx=cx: m.add_circle((cx, 200), 70))            # 13-14: discs
        part(lambda m, cx=cx, k=k: m.add_circle((cx, 200), 10 + 5 * k))  # with a hole
    part(lambda m: _rect(m, 100, 300, 300, 150))       # 15: a large plate, round holes
    for cx in (160, 250, 340):
        part(lambda m, cx=cx: m.add_circle((cx, 375), 20))
    part(lambda m: _rect(m, 480, 300, 400, 180))       # 16: a large plate, square holes
    for cx in (540, 660, 780):
        part(lambda m, cx=cx: _rect(m, cx - 20, 370, 40, 40))
    rng = random.Random(seed)
    flips = [False] * len(draw)
    if seed:
        rng.shuffle(draw)
        flips = [rng.random() < 0.5 for _ in draw]
    for fn, flip in zip(draw, flips, strict=True):
        fn(msp, flip)
    doc.saveas(str(path))


def tipping_pair(path: str | Path) -> None:
    """Write two rectangles 3 mm apart (the job tips the first up when it is cut free)."""
    doc, msp = _new()
    _rect(msp, 40, 40, 80, 60)
    _rect(msp, 123, 40, 80, 60)
    doc.saveas(str(path))


def main() -> None:
    """Write the library's drawings into the folder given (the shipped ``jobs/`` ones)."""
    out = Path(sys.argv[1] if len(sys.argv) > 1 else '.')
    out.mkdir(parents=True, exist_ok=True)
    plate_with_holes(out / 'plate_holes.dxf')
    nest(out / 'nest_16.dxf')
    tipping_pair(out / 'tipping_pair.dxf')


if __name__ == '__main__':
    main()
