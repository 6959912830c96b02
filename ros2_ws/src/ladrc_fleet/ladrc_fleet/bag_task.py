"""One bag of a fleet: its content key and its row of figures (one task on the engine).

:func:`bag_row` opens the bag, reads its provenance (bags/provenance.py) and makes the
report's one streaming pass (:func:`ladrc_tools.offline.report.analyse`: metrics, timing
quantiles, losses, holds) with the sensor check and the fault count riding on it; the bag is
never loaded whole. Whatever goes wrong becomes the row's ``status`` / ``error`` (one line),
never an exception: a corrupt, truncated or foreign bag must not stop a fleet's run.
Plain functions of a path, so any engine can run them in any process.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path
import time
from typing import Any

from ladrc_contract.codes import FollowState
import numpy as np

from .axis_check import AxisCheck
from .sensor_check import SensorCheck

FAULT = int(FollowState.FAULT)
KEY_CHUNK = 1 << 20


def content_key(path: str | Path) -> str:
    """Return a key of the bag's content: BLAKE2b over its files' names and bytes.

    Not its path: a bag copied or moved keeps its key, a bag rewritten gets a new one. Files
    beside the storage (``recording.json``) count too: they are the recording's summary.
    """
    p = Path(path)
    h = hashlib.blake2b(digest_size=16)
    for f in sorted(q for q in p.rglob('*') if q.is_file()):
        h.update(str(f.relative_to(p)).encode() + b'\0')
        with f.open('rb') as fh:
            while chunk := fh.read(KEY_CHUNK):
                h.update(chunk)
    return h.hexdigest()


class _FleetPass:
    """The sensor check and the FAULT entries, on the report's pass (``analyse(extra=)``)."""

    def __init__(self) -> None:
        self.sensor = SensorCheck()
        self.axis = AxisCheck()
        self.fields = {'follow/status': tuple(dict.fromkeys((
            *SensorCheck.fields['follow/status'], *AxisCheck.fields['follow/status'],
            'fault_reason')))}
        self.faults = 0
        self.fault_reasons: dict[str, int] = {}
        self._prev_state = -1

    def add(self, part: dict[str, dict[str, np.ndarray]]) -> None:
        self.sensor.add(part)
        self.axis.add(part)
        st = part.get('follow/status')
        if st is None or not st['state'].size:
            return
        state = st['state'].astype(int)
        before = np.r_[self._prev_state, state[:-1]]
        entries = np.flatnonzero((state == FAULT) & (before != FAULT))
        self.faults += entries.size
        for i in entries:
            reason = str(st['fault_reason'][i]).split(':')[0][:60] or 'unknown'
            self.fault_reasons[reason] = self.fault_reasons.get(reason, 0) + 1
        self._prev_state = int(state[-1])


ROW_FIELDS = ('bag', 'key', 'status', 'error', 'machine_id', 'start_utc', 'day', 'param_hash',
              'version', 'provenance_fallback', 'source', 'scenario', 'duration_s', 'ticks',
              'error_against', 'error_rms_mm', 'error_max_mm', 'followed_at_s',
              'time_to_follow_s', 'collisions', 'limit_v_ticks', 'limit_a_ticks', 'faults',
              'fault_reasons', 'void_lock_count', 'void_lock_s', 'edge_ahead_count',
              'edge_ahead_s', 'retract_count', 'overruns', 'period_p99_us', 'compute_p99_us',
              'input_age_p99_us', 'messages_lost', 'sensor_gain', 'sensor_noise_mm',
              'gain_approaches', 'noise_samples', 'axis_t1_ms', 'axis_gain', 'bytes', 'task_s')
"""The columns of a bag's row, in order (docs/fleet.md describes each)."""


def empty_row(path: str | Path, status: str, error: str = '') -> dict[str, Any]:
    """Return a row with only the bag, its status and why (the other columns empty)."""
    row: dict[str, Any] = dict.fromkeys(ROW_FIELDS)
    row.update(bag=str(path), status=status, error=error)
    return row


def _size(p: Path) -> int:
    return sum(f.stat().st_size for f in p.rglob('*') if f.is_file()) if p.is_dir() else (
        p.stat().st_size if p.exists() else 0)


def bag_row(path: str | Path, key: str = '') -> dict[str, Any]:
    """Return the row of figures of the bag at ``path`` (``status`` ``ok`` or ``error``)."""
    from ladrc_bags import BagError, open_bag
    from ladrc_bags.provenance import read_provenance
    from ladrc_tools.offline.report import analyse

    t0 = time.perf_counter()
    p = Path(path)
    try:
        with open_bag(p) as bag:
            prov = read_provenance(bag)
            extra = _FleetPass()
            report, _ = analyse(bag, extra=extra)
    except BagError as exc:
        row = empty_row(p, 'error', ' '.join(str(exc).split()))
        row.update(key=key, bytes=_size(p), task_s=time.perf_counter() - t0)
        return row
    except Exception as exc:  # a foreign or damaged bag: its reason, never the run's end
        row = empty_row(p, 'error', f'{type(exc).__name__}: {" ".join(str(exc).split())}'[:300])
        row.update(key=key, bytes=_size(p), task_s=time.perf_counter() - t0)
        return row
    m = report['metrics']
    timing = report['timing']
    holds = report.get('holds', {})
    sensor = extra.sensor.result()

    def hold(name: str, what: str) -> float:
        return holds.get(name, {}).get(what, 0)

    row = empty_row(p, 'ok')
    row.update({
        'key': key, 'machine_id': prov.machine_id, 'start_utc': prov.start_utc,
        'day': prov.day, 'param_hash': prov.param_hash, 'version': prov.version,
        'provenance_fallback': ','.join(prov.fallback), 'source': report['source'],
        'scenario': report['scenario'], 'duration_s': report['duration_s'],
        'ticks': report['ticks'], 'error_against': report['error_against'],
        'error_rms_mm': m['error_rms_mm'], 'error_max_mm': m['error_max_mm'],
        'followed_at_s': m['followed_at_s'], 'time_to_follow_s': m['time_to_follow_s'],
        'collisions': m['collisions'], 'limit_v_ticks': m['limit_v_ticks'],
        'limit_a_ticks': m['limit_a_ticks'], 'faults': extra.faults,
        'fault_reasons': ';'.join(f'{k}={v}' for k, v in sorted(extra.fault_reasons.items())),
        'void_lock_count': hold('void_lock', 'count'), 'void_lock_s': hold('void_lock', 'seconds'),
        'edge_ahead_count': hold('edge_ahead', 'count'),
        'edge_ahead_s': hold('edge_ahead', 'seconds'), 'retract_count': hold('retract', 'count'),
        'overruns': timing['overruns'], 'period_p99_us': timing['period_us']['p99'],
        'compute_p99_us': timing['compute_us']['p99'],
        'input_age_p99_us': timing['input_age_us']['p99'],
        'messages_lost': report['messages_lost'], **sensor, **extra.axis.result(),
        'bytes': _size(p),
        'task_s': time.perf_counter() - t0})
    for k, v in row.items():  # None for a figure the run has not (followed_at_s: never)
        if isinstance(v, float) and not math.isfinite(v):
            row[k] = None
    return row
