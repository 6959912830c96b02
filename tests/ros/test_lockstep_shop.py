"""A shop drawing live in lock step equals headless: a stray line listed, a small hole locked.

The drawing has what the reader must take as a CAM does (a lone open LINE beside the part,
listed and not cut) and a hole smaller than the nozzle, pierced and cut locked: the CNC's
``pierce`` with ``locked`` goes over the wire (``follow/pierce``), the bag records it and the
live run equals ``ladrc job`` bit for bit.
"""

from __future__ import annotations

import json
from pathlib import Path
import sys

import pytest

pytest.importorskip('rclpy')
sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_lockstep import JOB_FIGURES, TOOLS, assert_equal_bags, lockstep_run, run  # noqa: E402

pytestmark = pytest.mark.ros

SHOP_JOB = """name: lockstep_shop
description: A 50 x 35 mm part with a 12 mm and a 4 mm hole, a stray 3.5 mm line beside it.
dxf: shop.dxf
sheet:
  width_mm: 90
  height_mm: 60
  surface: {tilt_x: 0.0005, wave_amp_mm: 0.2, wave_length_mm: 60}
cut: {kerf_mm: 0.2, lead_in_mm: 2.0}
cnc: {feed_mm_s: 120, rapid_mm_s: 500, accel_mm_s2: 2000, cut_gap_mm: 1.0,
      pierce_heights_mm: [3.0], pierce_dwell_s: [0.05], thc_delay_s: 0.05,
      lift_mm: 6.0, leapfrog: true}
sensor: {noise_std_mm: 0.003, quant_mm: 0.001}
start_xy: [5.0, 5.0]
seed: 3
"""


def shop_job(folder: Path) -> str:
    """Write the job: three contours, one of them locked, and one open line."""
    import ezdxf

    doc = ezdxf.new('R2000', units=4)
    msp = doc.modelspace()
    msp.add_lwpolyline([(15, 12), (65, 12), (65, 47), (15, 47)], close=True)
    msp.add_circle((30, 30), 6)
    msp.add_circle((52, 24), 2)
    msp.add_line((72, 20), (72, 23.5))
    doc.saveas(str(folder / 'shop.dxf'))
    (folder / 'shop.yaml').write_text(SHOP_JOB)
    return str(folder / 'shop.yaml')


def test_live_lockstep_shop_drawing_equals_headless(tmp_path):
    name = shop_job(tmp_path)
    live, headless = tmp_path / 'live', tmp_path / 'headless'
    figures = lockstep_run(name, live, tmp_path / 'logs', '--job')
    res = run([str(TOOLS / 'ladrc'), 'job', name, '-o', str(headless)])
    assert res.returncode == 0, res.stdout[-2000:]
    head = json.loads(res.stdout.strip().splitlines()[-1])
    for key in JOB_FIGURES:
        assert figures[key] == head[key], (key, figures[key], head[key])
    assert_equal_bags(headless / 'bag', live, int(round(head['job_time_s'] / 0.0005)))
    assert head['finished'] and head['faults'] == 0 and head['contacts'] == 0
    assert head['pierces'] == 3 and head['locked_contours'] == 1
    assert len(head['drawing']['open_contours']) == 1
