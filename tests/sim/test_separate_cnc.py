"""A separate CNC: the world knows the CNC only through its motion samples (job/world.py).

``run_job(..., separate_cnc=True)`` is what the sim node and the CNC node do on the wire
(tests/ros/test_lockstep.py checks that bit for bit): the CNC keeps its own model of the sheet
(cnc_station.py), the sheet sees XY extrapolated between the CNC's samples and learns the
contours cut from them.
"""

from __future__ import annotations

import math
from pathlib import Path

from ladrc_contract.tick import CncInput
from ladrc_follow.control.follow import FollowController
from ladrc_follow.control.params import ControllerParams, params_from_dict
from ladrc_sim.job.jobfile import load_job
from ladrc_sim.job.runner import run_job
from ladrc_sim.job.world import MotionView
import numpy as np
import pytest

JOBS = (Path(__file__).resolve().parents[2] / 'ros2_ws' / 'src' / 'ladrc_sim' / 'ladrc_sim'
        / 'job' / 'jobs')


def sample(contour: int = 1, segment: int = 2) -> CncInput:
    return CncInput(1, 0.0, segment, True, contour, 100.0, 90.0, 5.0, math.inf)


def test_xy_is_extrapolated_one_cycle_at_most_and_held_after():
    view = MotionView(3.0, 4.0)
    view.see(0.0, None)
    assert (view.x, view.y) == (3.0, 4.0)  # no sample yet: the start
    view.see(0.0, sample(), 10.0, 20.0)
    assert (view.x, view.y) == (10.0, 20.0)  # one sample: where it says
    view.see(0.0005, None)
    assert (view.x, view.y) == (10.0, 20.0)  # no direction yet
    view.see(0.001, sample(), 11.0, 19.0)  # 1 kHz: 1 mm per cycle in x, -1 in y
    view.see(0.0015, None)
    assert view.x == pytest.approx(11.5) and view.y == pytest.approx(18.5)
    view.see(0.0100, None)  # the CNC silent for 9 ms: one cycle ahead, no further
    assert view.x == pytest.approx(12.0) and view.y == pytest.approx(18.0)
    assert view.feed_mm_s == 100.0 and view.actual_feed_mm_s == 90.0 and view.cutting


def test_a_contour_is_cut_when_the_samples_leave_it():
    view = MotionView(0.0, 0.0)
    view.see(0.0, sample(contour=2), 1.0, 1.0)
    assert view.cut_done == []
    view.see(0.001, None)
    assert view.cut_done == []
    view.see(0.002, sample(contour=0, segment=1), 1.0, 1.0)
    assert view.cut_done == [1]  # 0-based: the program's second contour
    view.see(0.003, sample(contour=0, segment=1), 2.0, 1.0)
    assert view.cut_done == []


def run(name: str, separate: bool):
    job = load_job(JOBS / f'{name}.yaml')
    params = params_from_dict(dict(job.controller)) if job.controller else ControllerParams()
    return run_job(job, FollowController(params), separate_cnc=separate)


def test_the_plate_with_a_separate_cnc_is_the_same_job_within_a_cycle():
    """Same program, pierces, holds and bar; the world one CNC sample behind the CNC."""
    a, b = run('plate_holes', False), run('plate_holes', True)
    fa, fb = a.figures, b.figures
    assert fb['finished'] and fb['contacts'] == 0 and fb['faults'] == 0
    assert fb['pierces'] == fa['pierces'] == 6
    assert fb['min_gap_over_target_cutting'] >= 0.7
    assert abs(fb['job_time_s'] - fa['job_time_s']) < 0.05 * fa['job_time_s']
    assert abs(fb['min_gap_over_target_cutting'] - fa['min_gap_over_target_cutting']) < 0.05
    # the world's XY: the CNC's, at most one cycle of motion (500 mm/s x 1 ms) away from the
    # headless path at the same time (the runs part slightly as their controllers differ)
    n = min(len(a.series['t_s']), len(b.series['t_s']), 4000)  # the first contour's rapid
    d = np.hypot(a.series['x_mm'][:n] - b.series['x_mm'][:n],
                 a.series['y_mm'][:n] - b.series['y_mm'][:n])
    assert d.max() <= 0.5 + 1e-9


def test_a_tipped_part_with_a_separate_cnc_still_ends_in_the_retract():
    f = run('tipping_pair', True).figures
    assert f['contacts'] >= 1 and f['faults'] == 1 and 'collision' in f['aborted']
