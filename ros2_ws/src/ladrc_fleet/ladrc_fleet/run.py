"""A fleet run: find the bags, key them, compute the new ones on the engine, write the tables.

Two rounds of tasks on the cluster: the content key of every bag (bag_task.content_key, a read
of its bytes), then the row of each bag whose key the cache (cache.py) does not hold
(bag_task.bag_row). The driver only joins rows: nothing of a bag but its row crosses to it.
"""

from __future__ import annotations

from dataclasses import dataclass
import json
import os
from pathlib import Path
import time
from typing import Any, Callable

from ladrc_tools.offline.engine import client, in_order

from . import fleet_report, rules, tables
from .bag_task import ROW_FIELDS, bag_row, content_key, empty_row
from .cache import RowCache
from .discover import SETTLE_S, find_bags


@dataclass(frozen=True)
class FleetResult:
    """The run's summary (the CLI's last line) and its tables."""

    summary: dict[str, Any]
    rows: list[dict[str, Any]]
    days: list[dict[str, Any]]
    flags: list[dict[str, Any]]


def peak_rss_mb() -> float:
    """Return this process' peak resident memory [MB] (run on each worker).

    Linux's ``VmHWM`` (the high-water mark of this program's memory, reset by exec), not
    ``getrusage``'s ``ru_maxrss``, which survives exec: a worker spawned by a driver that had
    held 3.7 GB reported 3.7 GB.
    """
    try:
        with open('/proc/self/status', encoding='ascii') as f:
            for line in f:
                if line.startswith('VmHWM:'):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _key_or_error(path: str) -> str:
    try:
        return content_key(path)
    except OSError as exc:
        return f'!{type(exc).__name__}: {exc}'


def run_fleet(paths: list[str], out: str | Path, *, scheduler: str | None = None,
              workers: int | None = None, cache_dir: str | Path | None = None,
              use_cache: bool = True, settle_s: float = SETTLE_S,
              progress: Callable[[int, int], None] | None = None) -> FleetResult:
    """Read the fleet's bags under ``paths`` into ``out`` (tables, report); return the result."""
    t0 = time.perf_counter()
    out = Path(out)
    found = find_bags(paths, settle_s)
    cache = RowCache(cache_dir or out / 'cache')
    bags = [str(b) for b in found.bags]
    with client(scheduler, workers) as c:
        n_workers = len(c.scheduler_info().get('workers', {}))
        keys = in_order(c, _key_or_error, bags)
        rows: list[dict[str, Any] | None] = [None] * len(bags)
        todo = []
        for i, (bag, key) in enumerate(zip(bags, keys, strict=True)):
            if key.startswith('!'):
                rows[i] = empty_row(bag, 'error', key[1:])
                continue
            cached = cache.get(key) if use_cache else None
            if cached is not None:
                rows[i] = {**cached, 'bag': bag}
            else:
                todo.append(i)
        fresh = in_order(c, bag_row, [bags[i] for i in todo], progress=progress) if todo else []
        peak_mb = max(c.run(peak_rss_mb).values(), default=0.0)
    for i, row in zip(todo, fresh, strict=True):
        row['key'] = keys[i]
        cache.put(keys[i], row)
        rows[i] = row
    rows_ok: list[dict[str, Any]] = [r for r in rows if r is not None]
    rows_ok += [empty_row(p, 'missing', 'no such file, folder or glob match')
                for p in found.missing]
    days = tables.machine_days(rows_ok)
    machines = tables.machines(days)
    flags = rules.flags(days)
    changes = rules.param_changes(rows_ok)
    out.mkdir(parents=True, exist_ok=True)
    tables.write_parquet(rows_ok, out / 'bags.parquet', ROW_FIELDS)
    tables.write_parquet(days, out / 'machine_days.parquet')
    tables.write_parquet(machines, out / 'machines.parquet')
    tables.write_parquet(flags, out / 'flags.parquet', ('machine_id', 'day', 'rule', 'figure',
                                                         'value', 'fleet_median', 'why'))
    failed = sum(r['status'] != 'ok' for r in rows_ok)
    summary = {
        'out': str(out), 'bags': len(rows_ok), 'ok': len(rows_ok) - failed, 'failed': failed,
        'writing': len(found.writing), 'computed': len(todo), 'cached': len(bags) - len(todo)
        - sum(1 for k in keys if k.startswith('!')), 'workers': n_workers,
        'machines': len(machines), 'machine_days': len(days),
        'flagged_machines': sorted({f['machine_id'] for f in flags}),
        'flags': len(flags), 'param_changes': len(changes),
        'worker_peak_rss_mb': round(peak_mb, 1),
        'wall_s': round(time.perf_counter() - t0, 2)}
    plots = [p for p in (fleet_report.heatmap(days, flags, out),
                         fleet_report.flagged_series(days, flags, out)) if p]
    text = fleet_report.markdown({**summary, 'writing_paths': [str(p) for p in found.writing]},
                                 rows_ok, machines, flags, changes, plots)
    _write(out / 'fleet.md', text)
    _write(out / 'fleet.json', json.dumps({**summary, 'writing_paths': [
        str(p) for p in found.writing], 'param_changes': changes}, indent=1) + '\n')
    return FleetResult(summary, rows_ok, days, flags)


def _write(path: Path, text: str) -> None:
    tmp = path.with_name(f'.{path.name}.tmp')
    tmp.write_text(text, encoding='utf-8')
    os.replace(tmp, path)
