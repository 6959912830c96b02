"""A cutting job in a bag: its job file and DXF, its path in XY, its per-job figures.

A job bag (``ladrc job -o``) carries the job file and its DXF in ``run/scenario`` (a mapping
``job``, ``dxf``), the nozzle's XY in ``sim/truth`` (``x_mm``, ``y_mm``) and, in
``follow/status``, the CNC values each tick used (``cnc_*``). :func:`job_in_bag` rebuilds the
job from the bag alone (the DXF written beside the job file in a temporary folder) and the
series the job's figures and drawing need, so ``ladrc report`` draws and measures the job as
``ladrc job`` does. The segment, beam and contour are those of the CNC sample the controller
used (one CNC cycle behind the CNC's own state, ``job/runner.py``), so times at segment
boundaries can differ from ``ladrc job``'s by a cycle per boundary.

The series are read whole (13 columns per tick: 31 MB for the 150 s ``ezdxf_forms`` job); a
job lasts minutes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import tempfile
from typing import Any

from ladrc_bags import Bag, read_text_topic
from ladrc_contract.codes import FollowState, Segment
import numpy as np
import yaml

STATUS = ('stamp_s', 'state', 'substate', 'target_gap_mm', 'cnc_segment', 'cnc_beam_on',
          'cnc_contour', 'cnc_commanded_feed_mm_s', 'cnc_actual_feed_mm_s',
          'feed_override_request', 'feed_hold_request')
TRUTH = ('stamp_s', 'x_mm', 'y_mm', 'true_gap_mm')


@dataclass
class _Log:
    """What ``job_figures`` reads of the CNC's log, from the bag."""

    pierces: int
    feed_hold_ticks: int
    finished: bool
    aborted: str


@dataclass
class JobInBag:
    """A job read back from its bag: the job, the series and figures (``JobResult``'s names)."""

    job: Any
    series: dict[str, np.ndarray]
    figures: dict[str, Any]


def job_text(bag: Bag) -> tuple[str, str] | None:
    """Return the bag's (job file, DXF) texts; None when the bag is not a job's."""
    text = read_text_topic(bag, 'run/scenario')
    try:
        data = yaml.safe_load(text) if text else None
    except yaml.YAMLError:
        return None
    if not (isinstance(data, dict) and isinstance(data.get('job'), str)
            and isinstance(data.get('dxf'), str)):
        return None
    return data['job'], data['dxf']


def _load(job_yaml: str, dxf_text: str, folder: Path) -> Any:
    """Load the job from its texts, its DXF beside it in ``folder``."""
    from ladrc_sim import load_job

    data = yaml.safe_load(job_yaml)
    if not isinstance(data, dict):
        raise ValueError('its job file is not a mapping of keys')
    data['dxf'] = 'job.dxf'
    (folder / 'job.dxf').write_text(dxf_text, encoding='utf-8')
    path = folder / 'job.yaml'
    path.write_text(yaml.safe_dump(data), encoding='utf-8')
    job = load_job(path)
    job.program()  # read while the DXF is there
    return job


def _columns(bag: Bag) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], str]:
    """Return the status and truth columns, and the first FAULT's reason ('' if none)."""
    status: dict[str, list[np.ndarray]] = {c: [] for c in STATUS}
    truth: dict[str, list[np.ndarray]] = {c: [] for c in TRUTH}
    reason = ''
    fault = int(FollowState.FAULT)
    for part in bag.stream({'follow/status': [*STATUS, 'fault_reason'],
                            'sim/truth': list(TRUTH)}):
        for topic, into in (('follow/status', status), ('sim/truth', truth)):
            cols = part.get(topic)
            if cols is not None:
                for c in into:
                    into[c].append(cols[c])
        st = part.get('follow/status')
        if not reason and st is not None and np.any(st['state'] == fault):
            reason = str(st['fault_reason'][int(np.argmax(st['state'] == fault))])
    return ({c: np.concatenate(v) if v else np.zeros(0) for c, v in status.items()},
            {c: np.concatenate(v) if v else np.zeros(0) for c, v in truth.items()}, reason)


def _runs(mask: np.ndarray) -> int:
    return int(np.count_nonzero(np.diff(np.r_[0, mask.astype(np.int8)]) == 1))


def job_in_bag(bag: Bag, corner_ratio: float = 0.8) -> JobInBag | None:
    """Return the bag's job, series and per-job figures; None when it holds no job's XY.

    ``corner_ratio``: the run's ``cnc.corner_lock_ratio`` (what counts as a corner).
    """
    from ladrc_sim import job_figures

    texts = job_text(bag)
    if texts is None or not bag.has('sim/truth'):
        return None
    st, tr, fault_reason = _columns(bag)
    if st['stamp_s'].size < 2 or not np.isfinite(tr['x_mm']).any():
        return None  # a job's texts without its path (a live run without XY)
    with tempfile.TemporaryDirectory(prefix='ladrc-job-') as tmp:
        job = _load(*texts, Path(tmp))
    # each status row with the truth of its stamp, or the last one before it (live)
    k = np.clip(np.searchsorted(tr['stamp_s'], st['stamp_s'], side='right') - 1, 0, None)
    t = st['stamp_s'] - st['stamp_s'][0]
    h_s = float(np.median(np.diff(st['stamp_s'])))
    segment = st['cnc_segment'].astype(int)
    state = st['state'].astype(int)
    series = {
        't_s': t, 'x_mm': tr['x_mm'][k], 'y_mm': tr['y_mm'][k],
        'true_gap_mm': tr['true_gap_mm'][k],
        'target_gap_mm': st['target_gap_mm'], 'state': state, 'substate': st['substate'],
        'segment': segment, 'beam': st['cnc_beam_on'].astype(int),
        'contour': st['cnc_contour'], 'feed_mm_s': st['cnc_actual_feed_mm_s'],
        'commanded_feed_mm_s': st['cnc_commanded_feed_mm_s'],
        'feed_override': st['feed_override_request'],
    }
    moving = np.isin(segment, (int(Segment.RAPID), int(Segment.CUT)))
    log = _Log(pierces=_runs(segment == int(Segment.PIERCE)),
               feed_hold_ticks=int(np.count_nonzero(st['feed_hold_request'].astype(bool)
                                                    & moving)),
               finished=not fault_reason and int(state[-1]) == int(FollowState.IDLE),
               aborted=(f'the height controller faulted: {fault_reason}' if fault_reason
                        else ''))
    figures = job_figures(series, h_s, log, len(job.program().contours), corner_ratio)
    return JobInBag(job, series, figures)
