"""The fleet's tables: one row per bag, per machine-day and per machine, written as Parquet.

``bags.parquet``: :data:`~.bag_task.ROW_FIELDS` (docs/fleet.md gives each column's unit).
``machine_days.parquet``: per machine and day (the bag's start date, UTC) the bags and hours
recorded and the day's figures: error RMS (time-weighted over the bags), faults and faults per
hour, holds, overruns, the worst p99 period and input age, messages lost, and the medians of
the sensor gain, sensor noise and axis T1 over the day's bags; the parameter set(s) run.
``machines.parquet``: per machine the trend of each day figure (least-squares slope per day)
and its first and last day's value. Plain numpy grouping; pyarrow writes the files.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from .bag_task import ROW_FIELDS

INT_COLUMNS = {'ticks', 'collisions', 'limit_v_ticks', 'limit_a_ticks', 'faults',
               'void_lock_count', 'edge_ahead_count', 'retract_count', 'overruns',
               'messages_lost', 'gain_approaches', 'noise_samples', 'bytes', 'bags'}
STR_COLUMNS = {'bag', 'key', 'status', 'error', 'machine_id', 'start_utc', 'day', 'param_hash',
               'version', 'provenance_fallback', 'source', 'scenario', 'error_against',
               'fault_reasons', 'param_hashes', 'first_day', 'last_day', 'rule', 'figure',
               'why'}
TREND = ('error_rms_mm', 'faults_per_h', 'sensor_gain', 'sensor_noise_mm', 'axis_t1_ms',
         'overruns', 'period_p99_us', 'input_age_p99_us')
"""The day figures a machine's trend is given for."""


def _num(rows: list[dict[str, Any]], key: str) -> np.ndarray:
    return np.array([np.nan if r.get(key) is None else float(r[key]) for r in rows])


def _median(values: np.ndarray) -> float | None:
    v = values[np.isfinite(values)]
    return float(np.median(v)) if v.size else None


def _max(values: np.ndarray) -> float | None:
    v = values[np.isfinite(values)]
    return float(v.max()) if v.size else None


def machine_days(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Return one row per (machine, day) of the readable bags, sorted."""
    ok = [r for r in rows if r['status'] == 'ok']
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in ok:
        groups.setdefault((r['machine_id'], r['day']), []).append(r)
    out = []
    for (machine, day), rs in sorted(groups.items()):
        dur = np.nan_to_num(_num(rs, 'duration_s'))
        rms = _num(rs, 'error_rms_mm')
        m = np.isfinite(rms) & (dur > 0)
        hours = float(dur.sum()) / 3600.0
        faults = int(np.nansum(_num(rs, 'faults')))
        out.append({
            'machine_id': machine, 'day': day, 'bags': len(rs), 'hours': hours,
            'error_rms_mm': float(math.sqrt((rms[m] ** 2 * dur[m]).sum() / dur[m].sum()))
            if m.any() else None,
            'faults': faults, 'faults_per_h': faults / hours if hours > 0 else None,
            'void_lock_count': int(np.nansum(_num(rs, 'void_lock_count'))),
            'edge_ahead_count': int(np.nansum(_num(rs, 'edge_ahead_count'))),
            'overruns': int(np.nansum(_num(rs, 'overruns'))),
            'period_p99_us': _max(_num(rs, 'period_p99_us')),
            'input_age_p99_us': _max(_num(rs, 'input_age_p99_us')),
            'messages_lost': int(np.nansum(_num(rs, 'messages_lost'))),
            'sensor_gain': _median(_num(rs, 'sensor_gain')),
            'sensor_noise_mm': _median(_num(rs, 'sensor_noise_mm')),
            'axis_t1_ms': _median(_num(rs, 'axis_t1_ms')),
            'param_hashes': ','.join(sorted({r['param_hash'] or '' for r in rs})),
        })
    return out


def machines(days: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Return one row per machine: each :data:`TREND` figure's slope per day, first and last."""
    out = []
    for machine in sorted({d['machine_id'] for d in days}):
        ds = [d for d in days if d['machine_id'] == machine]
        row: dict[str, Any] = {'machine_id': machine, 'days': len(ds),
                               'bags': sum(d['bags'] for d in ds),
                               'first_day': ds[0]['day'], 'last_day': ds[-1]['day']}
        x = np.arange(len(ds), dtype=float)
        for key in TREND:
            y = _num(ds, key)
            m = np.isfinite(y)
            row[f'{key}_first'] = float(y[m][0]) if m.any() else None
            row[f'{key}_last'] = float(y[m][-1]) if m.any() else None
            row[f'{key}_per_day'] = (float(np.polyfit(x[m], y[m], 1)[0]) if m.sum() >= 2
                                     else None)
        out.append(row)
    return out


def _arrow_type(key: str) -> Any:
    import pyarrow as pa

    if key in STR_COLUMNS:
        return pa.string()
    if key in INT_COLUMNS or key == 'days':
        return pa.int64()
    return pa.float64()


def write_parquet(rows: list[dict[str, Any]], path: Path, columns: tuple[str, ...] | None = None
                  ) -> Path:
    """Write ``rows`` as a Parquet file (typed columns, in ``columns`` order); return its path."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = list(columns or (rows[0].keys() if rows else ROW_FIELDS))
    schema = pa.schema([(c, _arrow_type(c)) for c in cols])
    data = {c: [r.get(c) for r in rows] for c in cols}
    for c in cols:
        if c in INT_COLUMNS or c == 'days':
            data[c] = [None if v is None else int(v) for v in data[c]]
        elif c not in STR_COLUMNS:
            data[c] = [None if v is None or (isinstance(v, float) and not math.isfinite(v))
                       else float(v) for v in data[c]]
    table = pa.table(data, schema=schema)
    tmp = path.with_name(f'.{path.name}.tmp')
    pq.write_table(table, tmp)
    tmp.replace(path)
    return path
