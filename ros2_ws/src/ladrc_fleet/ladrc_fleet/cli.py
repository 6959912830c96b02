"""``ladrc fleet`` (a fleet's bags into tables and a report) and ``ladrc fleet-gen``.

Registered under ``ladrc.commands`` (setup.py) as :data:`FLEET` and :data:`FLEET_GEN`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
from typing import Any, Callable

from ladrc_tools.cli_common import CliError, Command

OUTPUT_NAMES = {'cache', 'bags.parquet', 'machine_days.parquet', 'machines.parquet',
                'flags.parquet', 'fleet.md', 'fleet.json', 'heatmap.png', 'flagged.png'}
"""What a fleet output folder holds: one holding only these is re-used (its cache)."""


def _add_fleet(p: argparse.ArgumentParser) -> None:
    p.add_argument('paths', nargs='+', help='folders searched for bags (recursively), bag '
                   'folders, or globs')
    p.add_argument('-o', '--output', required=True,
                   help='folder for bags.parquet, machine_days.parquet, machines.parquet, '
                   'flags.parquet, fleet.md/.json and the plots (re-used: its cache/ keeps '
                   'the rows of bags already read)')
    p.add_argument('--scheduler', help='address of an existing Dask scheduler '
                   '(tcp://host:8786); default: a local cluster')
    p.add_argument('--workers', type=int, help='local cluster: worker processes '
                   '(default: the cores)')
    p.add_argument('--no-cache', action='store_true', help='compute every bag again')
    p.add_argument('--settle-s', type=float, default=60.0,
                   help='a recorder bag without recording.json changed this recently is '
                   'still being written: skipped (default 60)')


def progress_line(label: str) -> Callable[[int, int], None]:
    """Return a callback showing ``label: done/total bags`` on a terminal's stderr."""
    def show(done: int, total: int) -> None:
        if sys.stderr.isatty():
            print(f'\r{label}: {done}/{total} bags', end='\n' if done >= total else '',
                  file=sys.stderr, flush=True)
    return show


def _run_fleet(a: argparse.Namespace) -> int:
    from ladrc_tools.offline.engine import EngineError

    from .run import run_fleet

    out = Path(a.output)
    if out.exists() and (not out.is_dir() or any(p.name not in OUTPUT_NAMES
                                                 for p in out.iterdir())):
        raise CliError(f'{out} exists and is not a fleet output folder: nothing is overwritten')
    if a.workers is not None and not 1 <= a.workers <= 256:
        raise CliError(f'--workers must be 1..256, got {a.workers}')
    if not a.settle_s >= 0:
        raise CliError(f'--settle-s must be >= 0, got {a.settle_s}')
    try:
        result = run_fleet(a.paths, out, scheduler=a.scheduler, workers=a.workers,
                           use_cache=not a.no_cache, settle_s=a.settle_s,
                           progress=progress_line('ladrc fleet'))
    except (OSError, EngineError) as exc:  # the cluster, the output not writable
        raise CliError(' '.join(str(exc).split())) from None
    print(json.dumps(result.summary))
    return 1 if result.summary['failed'] else 0


def _add_fleet_gen(p: argparse.ArgumentParser) -> None:
    import dataclasses

    from .generate import CLI_FIELDS, FleetSpec

    p.add_argument('output', help='folder for the bags (<machine>/<bag>) and fleet_truth.json '
                   '(must not exist)')
    for f in dataclasses.fields(FleetSpec):
        if f.name in CLI_FIELDS:  # from the one declaration: type, default, unit, meaning
            spec = f.metadata['spec']
            unit = f' [{spec.unit}]' if spec.unit not in ('', '1') else ''
            p.add_argument('--' + f.name.replace('_', '-'), type=type(f.default),
                           default=f.default, help=f'{spec.description}{unit} '
                           f'(default {f.default})')
    p.add_argument('--scheduler', help='address of an existing Dask scheduler')
    p.add_argument('--workers', type=int, help='local cluster: worker processes')


def _run_fleet_gen(a: argparse.Namespace) -> int:
    from ladrc_tools.offline.engine import EngineError, client, in_order

    from .generate import CLI_FIELDS, FleetSpec, plan, write_bag, write_truth

    out = Path(a.output)
    if out.exists():
        raise CliError(f'{out} exists already: nothing is overwritten')
    if a.workers is not None and not 1 <= a.workers <= 256:
        raise CliError(f'--workers must be 1..256, got {a.workers}')
    try:
        spec = FleetSpec(**{k: getattr(a, k) for k in CLI_FIELDS})
    except ValueError as exc:
        raise CliError(str(exc)) from None
    fleet = plan(spec)
    tmp = out.with_name(f'.{out.name}.partial')
    tmp.mkdir(parents=True, exist_ok=True)
    try:
        with client(a.scheduler, a.workers) as c:
            paths: list[Any] = in_order(c, write_bag, fleet.bags, str(tmp),
                                        progress=progress_line('ladrc fleet-gen'))
    except EngineError as exc:  # what was written stays in the .partial folder: a re-run
        raise CliError(f'{exc} (the bags written so far are in {tmp})') from None
    write_truth(fleet, tmp)
    tmp.rename(out)
    print(json.dumps({'out': str(out), 'bags': len(paths), 'machines': spec.machines,
                      'days': spec.days, 'degraded': fleet.truth['degraded'],
                      'truth': str(out / 'fleet_truth.json')}))
    return 0


FLEET = Command("a fleet's bags (folders, globs) on a Dask cluster: one row per bag, machine-day "
              'and machine (Parquet), machines and days that stand out flagged with the rule, '
              'parameter-set changes before/after; fleet.md with plots; only new bags are '
              'computed again',
                _add_fleet, _run_fleet)
FLEET_GEN = Command('generate a fleet of simulated machines over days (headless bags with '
                  'machine ids and dates; a few machines degrading; a parameter change)',
                    _add_fleet_gen, _run_fleet_gen)
