"""The ``ladrc`` subcommands of the offline tools (no ROS needed).

simulate, report, export, suite, replay, analyze, tune, params: each an add-arguments function
and a run function (``cli.py``'s table).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
from typing import Any

from .cli_common import CliError


# ---- report / export ----------------------------------------------------------------------
def _add_report(p: argparse.ArgumentParser) -> None:
    p.add_argument('bag', help='bag folder (or a file inside it)')
    p.add_argument('-o', '--output', help='output folder (default: <bag>_report)')
    p.add_argument('-q', '--quiet', action='store_true', help='no progress on stderr')
    p.add_argument('--no-html', action='store_true',
                   help='no report.html (the plots zoomable in a browser, from the same pass)')


def _run_report(a: argparse.Namespace) -> int:
    from .offline.report import write_report

    out = write_report(a.bag, a.output, progress=not a.quiet, html=not a.no_html)
    report = json.loads((out / 'report.json').read_text())
    print(json.dumps({'report': str(out), 'messages_lost': report['messages_lost'],
                      **report['metrics'], 'timing': report['timing']}))
    return 0


def _add_export(p: argparse.ArgumentParser) -> None:
    p.add_argument('bag', help='bag folder (or a file inside it)')
    p.add_argument('-o', '--output', help='output folder (default: <bag>_csv)')
    p.add_argument('-q', '--quiet', action='store_true', help='no progress on stderr')


def _run_export(a: argparse.Namespace) -> int:
    from .offline.export import export_csv
    from .offline.report import stderr_progress

    files = export_csv(a.bag, a.output, progress=None if a.quiet else (
        lambda topic: stderr_progress(f'reading {topic}')))
    for f in files:
        print(f)
    return 0


# ---- simulate -----------------------------------------------------------------------------
def _add_simulate(p: argparse.ArgumentParser) -> None:
    p.add_argument('scenario', help='scenario YAML file or shipped scenario name')
    p.add_argument('--params', help='controller parameter YAML (default: built-in defaults)')
    p.add_argument('--controller', choices=('ladrc', 'pid'), default='ladrc',
                   help='follow mode of the controller (default: ladrc)')
    p.add_argument('-o', '--output', help='bag folder to write (default: no bag)')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                   help='bag storage (default: mcap)')


def make_controller(kind: str, params: Any) -> Any:
    """Return a FollowController for ``kind`` (``ladrc`` | ``pid``) with ``params``."""
    try:
        from ladrc_follow import FollowController
    except ImportError as exc:
        raise CliError(f'the follow controller is not available yet ({exc})') from None
    try:
        return FollowController(params, mode=kind)
    except TypeError:
        return FollowController(params)


def _run_simulate(a: argparse.Namespace) -> int:
    from ladrc_follow import ControllerParams, ParameterError, check_gate, dump_params, load_params
    from ladrc_sim import ScenarioError, load_scenario, run, summary

    try:
        scenario = load_scenario(a.scenario)
    except (ScenarioError, OSError) as exc:
        raise CliError(str(exc).splitlines()[0]) from None
    try:
        params = check_gate(load_params(a.params)) if a.params else ControllerParams()
    except ParameterError as exc:
        raise CliError(' '.join(str(exc).split())) from None
    if a.output and Path(a.output).exists():
        raise CliError(f'{a.output} exists already: a bag is never overwritten')
    controller = make_controller(a.controller, params)
    result = run(scenario, controller, record_internals=True)
    out = summary(result)
    if a.output:
        from ladrc_bags import write_run_bag

        scenario_text = _scenario_text(a.scenario, scenario)
        write_run_bag(result, a.output, dump_params(params), scenario_text,
                      storage=a.storage, controller=a.controller)
        out = {'bag': a.output, **out}
    from .offline.report import strict_json

    print(json.dumps(strict_json(dict(out))))
    return 0


def _scenario_text(arg: str, scenario: Any) -> str:
    p = Path(arg)
    if p.is_file():
        return p.read_text(encoding='utf-8')
    source = getattr(scenario, 'source', None)
    if source and Path(source).is_file():
        return Path(source).read_text(encoding='utf-8')
    try:
        from ladrc_sim import list_scenarios

        for f in list_scenarios():
            if f.stem == arg:
                return f.read_text(encoding='utf-8')
    except ImportError:
        pass
    return f'name: {getattr(scenario, "name", arg)}\n'


# ---- suite --------------------------------------------------------------------------------
def _add_suite(p: argparse.ArgumentParser) -> None:
    p.add_argument('--scenarios', help='comma-separated scenario names or YAML paths '
                   '(default: the whole shipped library)')
    p.add_argument('--variants', help='comma-separated controller variants (default: all: '
                   'pid, ladrc, ladrc_comp, ladrc_kalman, ladrc_98, ladrc_146)')
    p.add_argument('--params', help='base parameter YAML the variants modify '
                   '(default: the shipped defaults)')
    p.add_argument('-o', '--output', default='suite_results',
                   help='folder for suite.md, suite.json, suite.csv (default: suite_results)')
    p.add_argument('--jobs', type=int, default=2, help='worker processes (default: 2)')
    p.add_argument('--quick', action='store_true',
                   help='cut every scenario to 3 s (smoke test, not the quality figures)')
    p.add_argument('--law-only', action='store_true',
                   help="the control laws alone: the edge verification's moves up off, as in "
                        'the seed firmware (docs/quality.md tables; docs/safety.md: its cost)')
    p.add_argument('-q', '--quiet', action='store_true', help='no progress on stderr')


def _run_suite(a: argparse.Namespace) -> int:
    from ladrc_follow import ParameterError, check_gate, load_params

    from .offline.suite import SuiteError, markdown_table, summary, timed_suite, write_outputs

    def split(v: str | None) -> list[str] | None:
        return [x.strip() for x in v.split(',') if x.strip()] if v else None

    try:
        base = check_gate(load_params(a.params)) if a.params else None
    except (ParameterError, OSError) as exc:
        raise CliError(' '.join(str(exc).split())) from None
    if a.jobs < 1:
        raise CliError(f'--jobs must be >= 1, got {a.jobs}')

    def progress(row) -> None:
        if not a.quiet:
            print(f'{row.scenario}/{row.variant}: {row.final_state} ({row.wall_s:.1f} s)',
                  file=sys.stderr)

    try:
        rows, wall = timed_suite(scenarios=split(a.scenarios), variants=split(a.variants),
                                 base_params=base, jobs=a.jobs, quick=a.quick,
                                 laws_only=a.law_only, progress=progress)
    except SuiteError as exc:
        raise CliError(str(exc)) from None
    command = ' '.join(['ladrc suite'] + [f'--{k} {v}' for k, v in (
        ('scenarios', a.scenarios), ('variants', a.variants), ('params', a.params),
        ('jobs', a.jobs)) if v] + (['--quick'] if a.quick else [])
        + (['--law-only'] if a.law_only else []) + ['-o', str(a.output)])
    write_outputs(rows, a.output, command)
    print(markdown_table(rows))
    print(json.dumps({'output': str(a.output), **summary(rows, wall)}))
    return 0


# ---- replay -------------------------------------------------------------------------------
def _add_replay(p: argparse.ArgumentParser) -> None:
    p.add_argument('bag', help='bag folder (or a file inside it)')
    p.add_argument('--params', metavar='FILE',
                   help="what-if: replay with this parameter YAML instead of the bag's own")
    p.add_argument('--set', metavar='KEY=VALUE', action='append', default=[],
                   help='what-if: override one parameter (repeatable), e.g. --set law.kp=12')
    p.add_argument('--controller', choices=('ladrc', 'pid'),
                   help='what-if: follow mode (default: as recorded)')
    p.add_argument('-o', '--output', metavar='DIR',
                   help='output folder (what-if default: <bag>_whatif; own replay: '
                        'replay.json only when given)')
    p.add_argument('--no-internals', action='store_true',
                   help='compare the command only (faster; skips the ESO/state fields)')


def _print_whatif(rec: Any, run: Any, summary: dict[str, Any], wi: Any,
                  out: Path | None) -> int:
    """Write and print a what-if's outputs (open loop: always exit code 0)."""
    from .offline.replay import OPEN_LOOP_NOTE, write_whatif
    from .offline.report import strict_json

    table = wi.table(run.rejected)
    written = write_whatif(rec.path, table, wi.plot.result(), run.params,
                           run.params_source, out)
    print(f'what-if ({OPEN_LOOP_NOTE})')
    print(f'command RMS recorded {table["command_rms_recorded_mm_s"]:.4g} mm/s, what-if '
          f'{table["command_rms_whatif_mm_s"]:.4g} mm/s; difference RMS '
          f'{table["command_rms_difference_mm_s"]:.4g} mm/s, max '
          f'{table["command_max_difference_mm_s"]:.4g} mm/s')
    print(f'limit hits (v, a) recorded {tuple(table["limit_hits_recorded"].values())}, '
          f'what-if {tuple(table["limit_hits_whatif"].values())}')
    print(f'written: {written}/whatif.md, whatif.png, whatif.json, params.yaml')
    line = {'mode': 'what-if', **summary, 'open_loop': True,
            'command_rms_difference_mm_s': table['command_rms_difference_mm_s'],
            'command_max_difference_mm_s': table['command_max_difference_mm_s'],
            'output': str(written)}
    print(json.dumps(strict_json(line)))
    return 0


def _print_own_replay(summary: dict[str, Any], out: Path | None) -> int:
    """Print (and write) the verdict of a replay with the bag's own set: 0 when bit for bit."""
    from .offline.report import strict_json

    ok = summary['mismatches'] == 0 and summary['missing_ticks'] == 0
    if summary['mismatches']:
        fm = summary['first_mismatch']
        print(f'MISMATCH: {summary["mismatches"]} tick(s) differ bit for bit, first at tick '
              f'{summary["first_mismatch_tick"]} (recorded {fm["recorded_mm_s"]!r}, replayed '
              f'{fm["replayed_mm_s"]!r} mm/s)')
    elif summary['missing_ticks']:
        print(f'bit-for-bit up to tick {summary["exact_until_tick"]} (the first missing tick); '
              'NOT verified after it')
    else:
        print(f'bit-for-bit: all {summary["ticks"]} commands reproduced')
    if summary['internal_mismatch_ticks']:
        print(f'internals differ on {summary["internal_mismatch_ticks"]} tick(s): '
              f'{summary["internal_mismatch_fields"]}')
    line = {'mode': 'own', **summary}
    if out is not None:
        from .offline.outdir import building

        with building(out) as tmp:
            (tmp / 'replay.json').write_text(json.dumps(strict_json(line), indent=1))
        line['output'] = str(out)
    print(json.dumps(strict_json(line)))
    return 0 if ok else 1


def _run_replay(a: argparse.Namespace) -> int:
    from ladrc_follow import ParameterError

    from .offline.replay import (
        Replay,
        ReplayError,
        open_recording,
        parse_set,
        run_streamed,
        whatif_params,
    )
    from .offline.report import stderr_progress

    whatif = bool(a.params or a.set or a.controller)
    try:
        overrides = parse_set(a.set)
        out = Path(a.output) if a.output else None
        if whatif and out is None:
            out = Path(str(Path(a.bag)).rstrip('/') + '_whatif')
        if out is not None and out.exists():
            raise CliError(f'{out} exists already: outputs are never overwritten')
        rec = open_recording(a.bag)
        if whatif:
            params = whatif_params(rec, a.params, overrides)
            source = ' + '.join(x for x in (
                f'--params {a.params}' if a.params else f'bag set ({rec.params_source})',
                ' '.join(f'--set {s}' for s in a.set),
                f'--controller {a.controller}' if a.controller else '') if x)
            run = Replay(rec, params, overrides=overrides or None, mode=a.controller,
                         params_source=source)
        else:
            run = Replay(rec, record_internals=not a.no_internals)
        # one pass: the bag is read, stepped and compared a batch at a time
        summary, wi = run_streamed(rec, run, whatif, stderr_progress(
            'what-if' if whatif else 'replay'))
    except (ReplayError, ParameterError) as exc:
        raise CliError(' '.join(str(exc).split())) from None
    print(f'bag: {rec.path} ({rec.source or "unknown source"}, ticks {summary["start_tick"]}'
          f'..{summary["end_tick"]}, {summary["ticks"]} replayed at '
          f'{summary["ticks_per_s"]:.0f} ticks/s)')
    print(f'parameters: {run.params_source}')
    for note in rec.notes + run.notes:
        print(f'note: {note}')
    for r in run.rejected:
        print(f'rejected by the replayed controller: {r}')
    if summary['missing_ticks']:
        print(f'{summary["missing_ticks"]} tick(s) missing: exact replay holds only up to tick '
              f'{summary["exact_until_tick"]}; {summary["mismatches_after_gap"]} mismatch(es) '
              'after it (the controller cannot be stepped over ticks the bag lacks)')
    if wi is not None:
        return _print_whatif(rec, run, summary, wi, out)
    return _print_own_replay(summary, out)


# ---- analyze ------------------------------------------------------------------------------
def _add_analyze(p: argparse.ArgumentParser) -> None:
    p.add_argument('--params', help='controller parameter YAML (default: built-in defaults)')
    p.add_argument('--controller', choices=('ladrc', 'pid'),
                   help='loop to analyse (default: follow.controller of the set)')
    p.add_argument('--b0', type=float, default=1.0,
                   help='axis gain, mm/s per mm/s of command [1, the simulator]')
    p.add_argument('--t1-ms', type=float, default=8.0,
                   help='axis velocity-loop time constant [8 ms, the simulator]')
    p.add_argument('--dead-time-ticks', type=int, default=0,
                   help='whole ticks of command delay [0, the simulator]')
    p.add_argument('--lag-ms', type=float, default=0.0,
                   help='sensor first-order lag [0, the simulator]')
    p.add_argument('-o', '--output', default='analysis',
                   help='output folder [analysis]; never overwritten')


def _run_analyze(a: argparse.Namespace) -> int:
    from ladrc_follow import AxisModel, ControllerParams, ParameterError, load_params

    from .offline.analyze import write_analysis
    from .offline.report import strict_json

    try:  # not gated: analyze is how one sees why a set fails the gate
        params = load_params(a.params) if a.params else ControllerParams()
    except ParameterError as exc:
        raise CliError(' '.join(str(exc).split())) from None
    if not (0.0 < a.b0 <= 1e5 and 0.0 < a.t1_ms <= 1e4 and 0 <= a.dead_time_ticks <= 1000
            and 0.0 <= a.lag_ms <= 1e4):
        raise CliError('axis model out of range: 0 < b0 <= 1e5, 0 < t1-ms <= 1e4, '
                       '0 <= dead-time-ticks <= 1000, 0 <= lag-ms <= 1e4')
    axis = AxisModel(a.b0, a.t1_ms * 1e-3, a.dead_time_ticks, a.lag_ms * 1e-3)
    try:
        out, fig = write_analysis(params, a.params or 'built-in defaults', a.controller, axis,
                                  Path(a.output))
    except FileExistsError as exc:
        raise CliError(str(exc)) from None
    except ValueError as exc:
        raise CliError(' '.join(str(exc).split())) from None
    print(f'written: {out}/analysis.md, analysis.json, bode.png')
    print(json.dumps(strict_json({'output': str(out), **fig})))
    return 0


# ---- tune ---------------------------------------------------------------------------------
LARGE_GRID = 2000
"""``ladrc tune``: a grid of more points runs on a local cluster by default."""


def _add_tune(p: argparse.ArgumentParser) -> None:
    p.add_argument('--w0', default='30:150:5',
                   help='observer bandwidths ω0 [rad/s]: a:b:n or a value [30:150:5]')
    p.add_argument('--kp', default='4:24:5', help='law.kp [1/s]: a:b:n or a value [4:24:5]')
    p.add_argument('--b0', default='1', help='eso.b0: a:b:n or a value [1]')
    p.add_argument('--td-r', default=None,
                   help='td_b.r_per_s, the reference TD speed [1/s]: a:b:n or a value '
                        "[the base set's]")
    p.add_argument('--scenarios', default=None,
                   help='comma-separated scenario names [every one the batch loop models]')
    p.add_argument('--params', help='base parameter YAML (default: built-in defaults)')
    p.add_argument('-o', '--output', default='tune', help='output folder [tune]')
    p.add_argument('--scheduler', help='run the grid in parts on this Dask scheduler '
                   '(tcp://host:8786); default: on this core, or on a local cluster for a grid '
                   'of more than 2000 points')
    p.add_argument('--workers', type=int, help='local cluster: worker processes (default: '
                   'the cores); given, the local cluster is used whatever the grid')


def _run_tune(a: argparse.Namespace) -> int:
    from ladrc_follow import ControllerParams, ParameterError, check_gate, load_params
    from ladrc_sim import (
        BatchUnsupported,
        ScenarioError,
        batchable_scenarios,
        check_batchable,
        load_scenario,
    )

    from .offline.report import stderr_progress, strict_json
    from .offline.tune import parse_range, sweep, write_tune

    out = Path(a.output)
    if out.exists():
        raise CliError(f'{out} exists already: outputs are never overwritten')
    try:
        w0s, kps, b0s = (parse_range(a.w0, 'w0'), parse_range(a.kp, 'kp'),
                         parse_range(a.b0, 'b0'))
        td_rs = parse_range(a.td_r, 'td-r') if a.td_r else None
        base = check_gate(load_params(a.params)) if a.params else ControllerParams()
        names = a.scenarios.split(',') if a.scenarios else batchable_scenarios()
        for name in names:
            check_batchable(load_scenario(name))
    except (ValueError, ParameterError, ScenarioError, BatchUnsupported) as exc:
        raise CliError(' '.join(str(exc).split())) from None
    if a.workers is not None and not 1 <= a.workers <= 256:
        raise CliError(f'--workers must be 1..256, got {a.workers}')
    n_points = len(w0s) * len(kps) * len(b0s) * len(td_rs or [base.td_b.r_per_s])
    if a.scheduler or a.workers or n_points > LARGE_GRID:
        from .offline.engine import EngineError, client
        from .offline.tune import sweep_on

        try:
            with client(a.scheduler, a.workers) as c:
                cands = sweep_on(c, base, w0s, kps, b0s, names, stderr_progress('grid parts'),
                                 td_rs)
        except EngineError as exc:  # the cluster: unreachable, another environment
            raise CliError(str(exc)) from None
    else:
        cands = sweep(base, w0s, kps, b0s, names, stderr_progress('scenarios'), td_rs)
    try:
        out, summary = write_tune(cands, names, out, base)
    except ValueError as exc:
        raise CliError(' '.join(str(exc).split())) from None
    c = summary['chosen']
    print(f'{summary["grid"]} grid points, {summary["gated_in"]} through the stability gate, '
          f'{summary["front"]} on the Pareto front')
    print(f'chosen: w0 {c["w0_rad_s"]:g} rad/s, kp {c["kp"]:g} 1/s, b0 {c["b0"]:g}, TD R '
          f'{c["td_r_per_s"]:g} 1/s: '
          + ', '.join(f'{k} {c[k]:.4g}' for k in summary['objectives']))
    print(f'written: {out}/tuned.yaml, tune.md, tune.json, pareto.png')
    print(json.dumps(strict_json({'output': str(out), **summary})))
    return 0


# ---- params -------------------------------------------------------------------------------
PARAMETERS_DOC_HEAD = """# Parameters

GENERATED by `scripts/in-env ladrc params --markdown > docs/parameters.md` from the one
declaration of each parameter (`param(...)` fields in `ladrc_follow/control/`); a test fails
when this page is stale. The same declarations give the YAML loading and validation, the ROS
parameter descriptors of the follow node (range, unit, `read_only`) and the shipped parameter
file `ladrc_bringup/config/follow.yaml` (`ladrc params --yaml`).

Ranges: `(a, b]` means a < value <= b. Every number has finite bounds; a value outside them,
a non-finite value or a wrong type is rejected with its reason and the running values stay.
The checks that relate several parameters (discrete stability of the TDs and the observer,
kp·h < 1, contradicting limits, the follow windows) are in `ladrc_follow/control/params.py`
(`CROSS_CHECKS`). "start-up" parameters are `read_only` on the node.

"""


def parameters_doc() -> str:
    """Return docs/parameters.md: the header and the generated table."""
    from ladrc_contract.schema import markdown_table
    from ladrc_follow import ControllerParams

    return PARAMETERS_DOC_HEAD + markdown_table(ControllerParams())


def _add_params(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument('--yaml', action='store_true',
                   help='the default parameter file (ROS 2 layout, commented)')
    g.add_argument('--markdown', action='store_true', help='docs/parameters.md')
    g.add_argument('--check', metavar='FILE', help='load and validate a parameter file')


def _run_params(a: argparse.Namespace) -> int:
    from ladrc_follow import ParameterError, check_gate, load_params, parameter_file

    if a.check:
        try:
            check_gate(load_params(a.check))
        except ParameterError as exc:
            raise CliError(' | '.join(exc.reasons)) from None
        print(f'{a.check}: valid')
    elif a.yaml:
        sys.stdout.write(parameter_file())
    else:
        sys.stdout.write(parameters_doc())
    return 0
