"""A collision injected at a known point of a job (the job file's ``contact``).

The material under the nozzle rises while the CNC cuts its n-th contour: the controller's
COLLISION FAULT, its retract and the feed hold follow in every run, whatever the CNC's timing
(tests/linuxcnc/test_bringup_linuxcnc.py drives the same job under LinuxCNC).
"""

from __future__ import annotations

from pathlib import Path
import sys

from ladrc_contract.codes import SubState
from ladrc_follow.control.follow import FollowController
from ladrc_follow.control.params import ControllerParams
from ladrc_sim.job.jobfile import JobError, load_job
from ladrc_sim.job.runner import run_job
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'support'))
from linuxcnc_runs import small_job  # noqa: E402 (the same job as the LinuxCNC test)


@pytest.mark.parametrize('separate_cnc', [False, True])
def test_the_injected_contact_faults_retracts_and_holds_the_feed(tmp_path, separate_cnc):
    job = load_job(small_job(tmp_path, contact=True))
    res = run_job(job, FollowController(ControllerParams()), record_internals=True,
                  separate_cnc=separate_cnc)
    faults = res.run['faults']
    assert [f['code'] for f in faults] == ['COLLISION'], faults
    assert res.figures['contacts'] >= 1 and not res.figures['finished']
    # the first contour was cut clean; the contact came in the second one
    per_contour = res.figures['min_true_gap_per_contour_mm']
    assert per_contour[min(per_contour)] > 0.7 and min(per_contour.values()) <= 0.0
    sub = res.internals['substate']
    hold = res.internals['feed_hold_request']
    k = int(next(i for i, s in enumerate(res.internals['state']) if s == 5))
    assert hold[k:].any() and (sub[k:] == SubState.RETRACT).any()


def test_a_bad_contact_section_is_one_line(tmp_path):
    path = small_job(tmp_path)
    path.write_text(path.read_text() + 'contact: {nth_cut: 0}\n')
    with pytest.raises(JobError, match=r'contact\.nth_cut'):
        load_job(path)
