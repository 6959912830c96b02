"""The job library's drawings, written with ezdxf (``python -m ladrc_sim.job.dxf_library DIR``).

* :func:`plate_with_holes`: one 300 x 200 mm plate at (50, 50) with three round holes and two
  square ones (one with rounded corners: a bulged polyline).
* :func:`nest`: 16 parts on a 1000 x 500 mm sheet drawn with every entity kind the reader
  takes (closed polylines, circles, loose lines to be chained, arcs and lines, an ellipse, a
  spline): three outlines within 5 mm of the sheet's border, several parts 3-6 mm apart.
* :func:`tipping_pair`: two rectangles 3 mm apart; the job tips the first one up.

Deterministic; the shipped DXFs under ``jobs/`` are its output.
"""

from __future__ import annotations

import math
from pathlib import Path
import sys

import ezdxf


def _new():
    doc = ezdxf.new('R2010')
    doc.header['$INSUNITS'] = 4  # millimetres
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


def nest(path: str | Path) -> None:
    """Write the 16-part nest on a 1000 x 500 mm sheet."""
    doc, msp = _new()
    # border row (within 5 mm of the left / bottom / right edges)
    _rect(msp, 3, 4, 120, 80)                      # 1: left and bottom border
    msp.add_circle((60, 44), 15)                   #    its round hole
    _rect(msp, 880, 4, 116, 90)                    # 2: right border (4 mm), bottom (4 mm)
    _rounded_square(msp, 920, 30, 30, 4)           #    a rounded square hole
    msp.add_circle((200, 45), 40)                  # 3: a disc
    # an L of loose lines (chained by the reader)
    pts = [(270, 5), (390, 5), (390, 35), (300, 35), (300, 90), (270, 90), (270, 5)]
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        msp.add_line(a, b)                         # 4: L shape, 4-5 mm from the bottom
    # an obround of two arcs and two lines, 4 mm right of the L
    msp.add_line((420, 20), (500, 20))
    msp.add_arc((500, 40), 20, -90, 90)
    msp.add_line((500, 60), (420, 60))
    msp.add_arc((420, 40), 20, 90, 270)            # 5: obround
    _rect(msp, 540, 10, 150, 80)                   # 6: plate with an ellipse hole
    msp.add_ellipse((615, 50), major_axis=(40, 0), ratio=0.5)
    # a spline outline through six fit points (closed)
    fit = [(730, 20), (800, 15), (850, 40), (840, 85), (770, 95), (725, 60)]
    msp.add_spline(fit + [fit[0]])                 # 7: spline part
    # middle row: parts 5-6 mm apart (kerfs cut close by)
    x = 10.0
    for k, w in enumerate((100, 90, 110, 95, 105)):
        _rect(msp, x, 130, w, 120)                 # 8-12
        if k % 2 == 0:
            msp.add_circle((x + w / 2, 190), 18)
        else:
            _rect(msp, x + w / 2 - 15, 175, 30, 30)
        x += w + 5.0 if k < 3 else w + 6.0
    # top row
    for k, (cx, r) in enumerate(((650, 70), (820, 70))):
        msp.add_circle((cx, 200), r)               # 13-14: discs
        msp.add_circle((cx, 200), 10 + 5 * k)
    _rect(msp, 100, 300, 300, 150)                 # 15: a large plate with holes
    for cx in (160, 250, 340):
        msp.add_circle((cx, 375), 20)
    _rect(msp, 480, 300, 400, 180)                 # 16: a large plate, square holes
    for cx in (540, 660, 780):
        _rect(msp, cx - 20, 370, 40, 40)
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
