"""``bringup --cnc linuxcnc``: a job cut with LinuxCNC as its CNC.

Real processes: LinuxCNC (the shipped XY machine, headless), the bridge (its HAL component in
LinuxCNC, its node on the graph), the sim node taking XY from ``cnc/motion``, the follow node.

* a small job (three contours) to its end: every contour pierced and cut, 0 contacts, the true
  gap >= 0.7 x the target while cutting, and XY never starting a contour before the height
  controller is in position (LinuxCNC's own pins: the position did not leave the pierce point
  before the bridge raised ``spindle.0.at-speed``);
* a contact injected at a known point of the job: the controller's COLLISION FAULT (retract),
  and the FAULT in LinuxCNC's feed hold and pause, in every run;
* a fault row of bench/fault_matrix.py: LinuxCNC killed mid-job: the bridge sees its component
  gone, the controller lifts the head and stops; no contact; LinuxCNC's processes and shared
  memory are gone afterwards.

Free-running on a loaded machine a timing guard of the simulation may stop a run early, safely
(tests/support/linuxcnc_runs.py): every run's safety is asserted; a run's end is asked of one
no guard stopped, at most ``ATTEMPTS`` runs.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
import subprocess

from ladrc_linuxcnc.sequence import MOVED_MM
from linuxcnc_runs import (
    ATTEMPTS,
    bringup_linuxcnc,
    first_fault,
    report,
    small_job,
    summary,
    timing_abort,
)
import pytest
from system import require

pytestmark = pytest.mark.ros
ROOT = Path(__file__).resolve().parents[2]
BAR = 0.7


@pytest.fixture(scope='module')
def ros_env() -> dict[str, str]:
    """Return the environment of the ROS tests (own ROS_DOMAIN_ID, localhost discovery)."""
    spec = importlib.util.spec_from_file_location(
        'ros_conftest_for_linuxcnc', ROOT / 'tests' / 'ros' / 'conftest.py')
    ros = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ros)  # sets ROS_DOMAIN_ID / localhost discovery (or skips)
    return dict(os.environ)


def domain(env: dict[str, str]) -> list[str]:
    return ['--domain-id', env['ROS_DOMAIN_ID']]


def check_safety(f: dict) -> None:
    """Assert what holds for every run, to its end or stopped by a guard."""
    bridge = f['linuxcnc']['bridge']
    assert f['contacts'] == 0, summary(f)
    assert bridge['moved_before_ready'] == 0, bridge['contours']
    for c in bridge['contours']:  # (0.1 um seen once: the position settling, not a start)
        if 'moved_before_ready_mm' in c:
            assert c['moved_before_ready_mm'] <= MOVED_MM, c
    for hold in bridge['fault_holds']:  # every FAULT: LinuxCNC's feed hold, then the pause
        assert hold.get('feed_hold_after_ms', 1e9) < 500.0, hold
    if bridge['fault_holds']:
        assert f['linuxcnc']['paused'], f['linuxcnc']['events']


def test_a_small_job_runs_to_its_end_under_linuxcnc(tmp_path, ros_env):
    require('linuxcnc')
    job = small_job(tmp_path / 'job')
    for attempt in range(1, ATTEMPTS + 1):
        rc, f, err = bringup_linuxcnc(job, tmp_path / f'run{attempt}', *domain(ros_env),
                                      timeout_s=300.0, env=ros_env)
        report(f'attempt {attempt}: exit {rc} {summary(f)}')
        assert f, err
        check_safety(f)
        if f.get('finished') or not timing_abort(f):
            break
    assert rc == 0 and f['finished'] and not f['aborted'], (summary(f), err)
    assert f['pierces'] == 3 and len(f['min_true_gap_per_contour_mm']) == 3
    assert f['min_gap_over_target_cutting'] >= BAR
    bridge = f['linuxcnc']['bridge']
    assert [c['contour'] for c in bridge['contours']] == [1, 2, 3]
    assert all(c['ready_after_s'] > 0 for c in bridge['contours'])
    assert bridge['leapfrogs'] == 2 and bridge['holds'] == 3  # the post's M62 P2 stretches
    assert f['allowance']['file'].endswith('linuxcnc_allowance.yaml')


def test_a_contact_faults_and_linuxcnc_holds_its_feed_and_pauses(tmp_path, ros_env):
    """A contact at a known point holds LinuxCNC's feed and pauses the program.

    The job's ``contact``: the material under the nozzle rises 4 mm 0.3 s into the second
    contour's cut. The controller's COLLISION FAULT must hold LinuxCNC's feed and pause the
    program, in every run a timing guard did not stop before that point (``ATTEMPTS`` at most,
    each counted).
    """
    require('linuxcnc')
    job = small_job(tmp_path / 'job', contact=True)
    stopped = 0
    for attempt in range(1, ATTEMPTS + 1):
        rc, f, err = bringup_linuxcnc(job, tmp_path / f'run{attempt}', *domain(ros_env),
                                      timeout_s=300.0, env=ros_env)
        report(f'attempt {attempt}: exit {rc} {summary(f)}')
        assert f, err
        assert f['linuxcnc']['bridge']['moved_before_ready'] == 0
        if first_fault(f).get('code') == 'COLLISION':
            break
        assert timing_abort(f), summary(f)  # anything else fails at once
        stopped += 1
    report(f'runs stopped by a timing guard before the contact: {stopped} of {attempt}')
    assert first_fault(f).get('code') == 'COLLISION' and f['faults'] >= 1, summary(f)
    assert rc == 0, (summary(f), err)  # the job declares its FAULT (expect_fault)
    bridge = f['linuxcnc']['bridge']
    assert bridge['aborted_code'] == 'controller_fault' and bridge['fault_holds'], bridge
    hold = bridge['fault_holds'][0]
    assert hold['feed_hold_after_ms'] < 500.0 and hold.get('stopped_after_ms', 1e9) < 1000.0
    assert f['linuxcnc']['paused'] and bridge['moved_before_ready'] == 0


def test_linuxcnc_killed_mid_job_the_head_lifts_and_stops(tmp_path, ros_env):
    require('linuxcnc')
    # the kill comes 2.5 s after cycle start by the bring-up's clock, which a loaded machine
    # delays by a second or more: a job of 12 holes more (about 23 s) is still cutting then. A
    # run that a timing guard stopped before the kill is safe and says nothing of it: another
    # (ATTEMPTS at most, its basis in linuxcnc_runs.py; such a run ends within seconds).
    job = small_job(tmp_path / 'job', small_holes=12)
    for attempt in range(1, ATTEMPTS + 1):
        rc, f, err = bringup_linuxcnc(job, tmp_path / f'run{attempt}', '--fault',
                                      'kill-linuxcnc@2.5', *domain(ros_env), timeout_s=300.0,
                                      env=ros_env)
        report(f'attempt {attempt}: exit {rc} {summary(f)}')
        assert f, err
        bridge = f['linuxcnc']['bridge']
        assert f['contacts'] == 0 and bridge['moved_before_ready'] == 0
        if bridge['aborted_code'] == 'linuxcnc_gone' or not timing_abort(f):
            break
    fault = f['linuxcnc'].get('fault') or {}  # (none: every attempt stopped before the kill)
    assert fault.get('kind') == 'kill-linuxcnc' and fault.get('killed_pids'), summary(f)
    assert bridge['aborted_code'] == 'linuxcnc_gone', bridge
    assert bridge['lifts'] >= 1 and not f['finished']
    keys = subprocess.run(['ipcs', '-m'], capture_output=True, text=True).stdout
    assert '0x48414c32' not in keys and not Path('/tmp/linuxcnc.lock').exists()
