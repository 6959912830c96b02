"""``ladrc``: the user CLI (simulate, replay, report, export, suite, params, analyze, tune, ...).

Every subcommand is one entry of :data:`COMMANDS` (name -> (help, add-arguments, run)); add a
subcommand by adding an entry. Bad input (missing file, truncated/foreign bag, missing topic,
unknown parameter) ends with ONE line on stderr and exit code 2, no traceback, and nothing
half-written (outputs are built under a temporary name and renamed when complete).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
from typing import Any, Callable

from .bags.bag import BagError

EXIT_USAGE = 2


class CliError(Exception):
    """A user-facing error: printed as one line, exit code 2."""


# ---- report / export ----------------------------------------------------------------------
def _add_report(p: argparse.ArgumentParser) -> None:
    p.add_argument('bag', help='bag folder (or a file inside it)')
    p.add_argument('-o', '--output', help='output folder (default: <bag>_report)')
    p.add_argument('-q', '--quiet', action='store_true', help='no progress on stderr')


def _run_report(a: argparse.Namespace) -> int:
    from .offline.report import write_report

    out = write_report(a.bag, a.output, progress=not a.quiet)
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
        from ladrc_follow.control.follow import FollowController
    except ImportError as exc:
        raise CliError(f'the follow controller is not available yet ({exc})') from None
    try:
        return FollowController(params, mode=kind)
    except TypeError:
        return FollowController(params)


def _run_simulate(a: argparse.Namespace) -> int:
    from ladrc_follow.analysis.gate import check_gate
    from ladrc_follow.control.params import (
        ControllerParams,
        ParameterError,
        dump_params,
        load_params,
    )
    from ladrc_sim.headless.runner import run, summary
    from ladrc_sim.headless.scenario import ScenarioError, load_scenario

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
        from .bags.bag import write_run_bag

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
        from ladrc_sim.headless.scenario import list_scenarios

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
    from ladrc_follow.analysis.gate import check_gate
    from ladrc_follow.control.params import ParameterError, load_params

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


def _run_replay(a: argparse.Namespace) -> int:
    from ladrc_follow.control.params import ParameterError

    from .offline.replay import (
        OPEN_LOOP_NOTE,
        Replay,
        ReplayError,
        open_recording,
        parse_set,
        run_streamed,
        whatif_params,
        write_whatif,
    )
    from .offline.report import stderr_progress, strict_json

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
    from ladrc_follow.analysis.loop import AxisModel
    from ladrc_follow.control.params import ControllerParams, ParameterError, load_params

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


def _run_tune(a: argparse.Namespace) -> int:
    from ladrc_follow.analysis.gate import check_gate
    from ladrc_follow.control.params import ControllerParams, ParameterError, load_params
    from ladrc_sim.headless.batch import BatchUnsupported, batchable_scenarios, check_batchable
    from ladrc_sim.headless.scenario import ScenarioError, load_scenario

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
    cands = sweep(base, w0s, kps, b0s, names, stderr_progress('scenarios'), td_rs)
    try:
        out, summary = write_tune(cands, names, out)
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


# ---- identify / excite (commissioning a real axis, docs/identification.md) ---------------
def _add_identify(p: argparse.ArgumentParser) -> None:
    p.add_argument('bag', help='bag with axis/velocity_command and axis/feedback (and '
                   'axis/capacitive_height over a flat sheet for the sensor)')
    p.add_argument('-o', '--output', help='output folder (default: <bag>_identify); never '
                   'overwritten')
    p.add_argument('--flat-sheet-window', metavar='T0:T1',
                   help='seconds after the first feedback sample where the nozzle is over a '
                   'flat sheet, for the sensor fit (default: the whole bag)')
    p.add_argument('--max-dead-time-ms', type=float, default=20.0,
                   help='longest dead time searched [20 ms]')


def _run_identify(a: argparse.Namespace) -> int:
    import numpy as np

    from .commissioning.identify import IdentifyError
    from .commissioning.identify_report import identify_bag, parse_window, write_outputs
    from .offline.report import strict_json

    bag = Path(a.bag)
    base = bag.parent if bag.is_file() else bag  # a bag folder, or a file inside it
    out = Path(a.output) if a.output else base.with_name(base.name + '_identify')
    if out.exists():
        raise CliError(f'{out} exists already: outputs are never overwritten')
    try:
        ident = identify_bag(bag, parse_window(a.flat_sheet_window), a.max_dead_time_ms * 1e-3)
        summ = write_outputs(ident, out)
    except IdentifyError as exc:
        raise CliError(' '.join(str(exc).split())) from None
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:  # extreme data
        raise CliError(f"the bag's data cannot be fitted ({type(exc).__name__}: "
                       f'{" ".join(str(exc).split())[:200]})') from None
    ax = ident.axis
    print(f'axis: b0 {ax.b0.value:.6g} [{ax.b0.ci[0]:.6g}, {ax.b0.ci[1]:.6g}], T1 '
          f'{ax.t1_s.value * 1e3:.4g} ms, dead time {ax.dead_time_s.value * 1e3:.4g} ms, '
          f'residual RMS {ax.residual_rms_mm * 1e3:.3g} µm')
    if ident.sensor is not None:
        se = ident.sensor
        print(f'sensor: gain {se.gain.value:.4g}, lag {se.lag_s.value * 1e3:.3g} ms, noise '
              f'{se.noise_mm * 1e3:.3g} µm')
    sg = ident.suggestion
    print(f'suggested: eso.b0 {sg.eso_b0:g}, eso.w0_rad_s {sg.w0_rad_s:g}, law.wc_rad_s '
          f'{sg.wc_rad_s:g} (gate passed)')
    print(f'written: {out}/identification.md, fit.png, params.yaml, identification.json')
    print(json.dumps(strict_json(summ)))
    return 0


def _add_excite(p: argparse.ArgumentParser) -> None:
    from .commissioning.excitation import KINDS, Excitation

    d = Excitation()
    p.add_argument('-o', '--output', required=True, help='bag folder to write (never '
                   'overwritten)')
    p.add_argument('--scenario', help='scenario YAML file or shipped name (default: the '
                   'built-in identification scenario: 5 mm above a flat sheet)')
    p.add_argument('--set', action='append', default=[], metavar='KEY=VALUE',
                   help='scenario override, repeatable: axis.b0=1.3, axis.t1_s=0.004, '
                   'axis.dead_time_ticks=6, sensor.lag_s=0.001, seed=3, ...')
    p.add_argument('--kind', choices=KINDS, default=d.kind, help=f'[{d.kind}]')
    p.add_argument('--amplitude-mm-s', type=float, default=d.amplitude_mm_s,
                   help=f'velocity amplitude [{d.amplitude_mm_s:g}]')
    p.add_argument('--max-travel-mm', type=float, default=d.max_travel_mm,
                   help=f'travel bound around the start [{d.max_travel_mm:g}]')
    p.add_argument('--f-low-hz', type=float, default=d.f_low_hz, help=f'[{d.f_low_hz:g}]')
    p.add_argument('--f-high-hz', type=float, default=d.f_high_hz, help=f'[{d.f_high_hz:g}]')
    p.add_argument('--duration-s', type=float, default=d.duration_s,
                   help=f'[{d.duration_s:g}]')
    p.add_argument('--seed', type=int, default=d.seed, help=f'[{d.seed}]')
    p.add_argument('--settle-s', type=float, default=0.2,
                   help='rest before the excitation [0.2]')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                   help='bag storage (default: mcap)')


def _run_excite(a: argparse.Namespace) -> int:
    from .commissioning.excitation import Excitation
    from .commissioning.player import PlayerLimits
    from .commissioning.simrun import (
        SimRunError,
        apply_overrides,
        run_excitation,
        scenario_dict,
        write_bag,
    )
    from .offline.report import strict_json

    if Path(a.output).exists():
        raise CliError(f'{a.output} exists already: a bag is never overwritten')
    exc = Excitation(kind=a.kind, amplitude_mm_s=a.amplitude_mm_s,
                     max_travel_mm=a.max_travel_mm, f_low_hz=a.f_low_hz,
                     f_high_hz=a.f_high_hz, duration_s=a.duration_s, seed=a.seed)
    try:
        data = apply_overrides(scenario_dict(a.scenario), a.set)
        played = run_excitation(data, exc, PlayerLimits(settle_s=a.settle_s),
                                source=a.scenario or '')
    except SimRunError as err:
        raise CliError(str(err)) from None
    write_bag(played, a.output, a.storage)
    sc, pl = played.result.scenario, played.player
    out = {'bag': a.output, 'scenario': sc.name, 'axis_b0': sc.axis.b0,
           'axis_t1_s': sc.axis.t1_s, 'axis_dead_time_ticks': sc.axis.dead_time_ticks,
           'sensor_lag_s': sc.sensor.lag_s, 'sensor_noise_mm': sc.sensor.noise_std_mm,
           'excitation': exc.as_dict(), 'finished': pl.finished,
           'aborted': pl.abort_reason or None, 'max_excursion_mm': pl.max_excursion_mm}
    if pl.abort_reason:
        print(f'excitation aborted: {pl.abort_reason}', file=sys.stderr)
    print(json.dumps(strict_json(out)))
    return 0 if pl.finished else 1


# ---- conform (the driver conformance kit, docs/conformance.md) ----------------------------
def _add_conform(p: argparse.ArgumentParser) -> None:
    from .commissioning.conformance import Plan

    d = Plan()
    g = p.add_mutually_exclusive_group()
    g.add_argument('--sim', action='store_true',
                   help='start the sim node as the drive (flat sheet, no follow commands) on an '
                   'isolated DDS domain and check it')
    g.add_argument('--driver-cmd', metavar='"CMD ..."',
                   help='start this command (the driver) on an isolated DDS domain and check it '
                   '(default without --sim: the driver already running on ROS_DOMAIN_ID)')
    p.add_argument('-o', '--output', help='output folder: report.md, conform.json, bag/ '
                   '(default: conform-<date>-<time>); never overwritten')
    p.add_argument('--min-gap-mm', type=float, default=d.min_gap_mm,
                   help=f'abort below this gap reading; the tests start only when the gap '
                   f'minus --max-travel-mm stays above it [{d.min_gap_mm:g}]')
    p.add_argument('--max-travel-mm', type=float, default=d.max_travel_mm,
                   help=f'abort when the encoder leaves ±this around its start '
                   f'[{d.max_travel_mm:g}]')
    p.add_argument('--max-speed-mm-s', type=float, default=d.max_speed_mm_s,
                   help=f'abort above this encoder speed; never commanded '
                   f'[{d.max_speed_mm_s:g}]')
    p.add_argument('--test-speed-mm-s', type=float, default=d.test_speed_mm_s,
                   help=f'speed of the units-and-signs and watchdog tests '
                   f'[{d.test_speed_mm_s:g}]')
    p.add_argument('--test-travel-mm', type=float, default=d.test_travel_mm,
                   help=f'travel up, then down, of the units-and-signs test '
                   f'[{d.test_travel_mm:g}]')
    p.add_argument('--no-excitation', action='store_true',
                   help='skip the excitation segment (the bag then serves no identification)')
    p.add_argument('--watchdog-timeout-ms', type=float, default=5.0,
                   help="the drive's documented command timeout [5, docs/safety.md]")
    p.add_argument('--sim-scenario', metavar='YAML',
                   help='with --sim: this scenario instead of the built-in one (e.g. other '
                   'axis parameters; keep it free of follow commands)')
    p.add_argument('--domain-id', type=int, help='ROS_DOMAIN_ID of the run (with --sim or '
                   '--driver-cmd default: random 1..101)')
    p.add_argument('--discovery-timeout-s', type=float, default=30.0,
                   help="wait this long for the driver's topics [30]")


def _run_conform(a: argparse.Namespace) -> int:
    import dataclasses
    import time

    from .commissioning.conformance import Plan, Tolerances
    from .node.conform_node import ConformError, ConformOptions, run_conform

    d = Plan()
    plan = dataclasses.replace(
        d, min_gap_mm=a.min_gap_mm, max_travel_mm=a.max_travel_mm,
        max_speed_mm_s=a.max_speed_mm_s, test_speed_mm_s=a.test_speed_mm_s,
        test_travel_mm=a.test_travel_mm, excitation=None if a.no_excitation else d.excitation)
    if a.sim_scenario and not a.sim:
        raise CliError('--sim-scenario needs --sim')
    if not 0.0 < a.watchdog_timeout_ms <= 1000.0:
        raise CliError(f'--watchdog-timeout-ms {a.watchdog_timeout_ms:g}: must be in (0, 1000]')
    out = Path(a.output or time.strftime('conform-%Y%m%d-%H%M%S'))
    opts = ConformOptions(output=out, sim=a.sim, driver_cmd=a.driver_cmd, plan=plan,
                          tolerances=Tolerances(watchdog_timeout_s=a.watchdog_timeout_ms * 1e-3),
                          domain_id=a.domain_id, discovery_timeout_s=a.discovery_timeout_s,
                          sim_scenario=a.sim_scenario)
    try:
        result, out = run_conform(opts)
    except ConformError as exc:
        raise CliError(' '.join(str(exc).split())) from None
    for r in result.results:
        print(f'{"pass" if r.passed else "FAIL"}  {r.name}: {r.reason}')
    print(f'written: {out}/report.md, conform.json, bag/')
    line = {'output': str(out), 'passed': result.passed,
            'rules_passed': len(result.rules_passed), 'rules_failed': result.rules_failed,
            'rules_total': len(result.results), 'aborted': result.aborted or None,
            'not_run': result.not_run or None,
            'figures': {r.name: r.as_dict()['figure'] for r in result.results}}
    print(json.dumps(line))
    return 0 if result.passed else 1


# ---- calibrate (capacitive calibration, docs/calibration.md) -----------------------------
def _add_calibrate(p: argparse.ArgumentParser) -> None:
    from .commissioning.calibration import SweepMotion

    d = SweepMotion()
    p.add_argument('--sim', action='store_true',
                   help='start the sim node on a DDS domain of its own and calibrate it '
                   '(default: the driver on the current domain)')
    p.add_argument('-o', '--output', default='calibration',
                   help='output folder [calibration]; never overwritten')
    p.add_argument('--descent-mm-s', type=float, default=d.descent_mm_s,
                   help=f'descent speed to contact [{d.descent_mm_s:g}]')
    p.add_argument('--retract-mm-s', type=float, default=d.retract_mm_s,
                   help=f'retract speed back to the start [{d.retract_mm_s:g}]')
    p.add_argument('--max-travel-mm', type=float, default=d.max_travel_mm,
                   help=f'travel below the start without contact that ends the sweep '
                   f'[{d.max_travel_mm:g}]')
    p.add_argument('--min-start-gap-mm', type=float, default=d.min_start_gap_mm,
                   help='smallest gap reading accepted at the start (where the driver '
                   f'publishes one) [{d.min_start_gap_mm:g}]')
    p.add_argument('--stale-ms', type=float, default=d.stale_timeout_s * 1e3,
                   help=f'input age that aborts the sweep [{d.stale_timeout_s * 1e3:g}]')
    p.add_argument('--sim-gap-mm', type=float, default=5.0,
                   help='--sim: the start gap of the simulated axis [5]')
    p.add_argument('--sim-noise-mm', type=float, default=0.005,
                   help='--sim: sensor noise [0.005]')
    p.add_argument('--lockstep', action='store_true',
                   help='in lock step with the sim node (its --sim, or one the caller started '
                   'with lockstep:=true): deterministic, no drive watchdog (docs/follow-node.md)')
    p.add_argument('--sim-watchdog-ms', type=float, default=50.0,
                   help="--sim: the simulated drive's command watchdog [50; the product's 5 ms "
                   'trips on a loaded 2-core machine, docs/calibration.md]')


def _run_calibrate(a: argparse.Namespace) -> int:
    from .commissioning.calibration import CalibrationError
    from .offline.report import strict_json

    out = Path(a.output)
    if out.exists():
        raise CliError(f'{out} exists already: outputs are never overwritten')
    motion = {'descent_mm_s': a.descent_mm_s, 'retract_mm_s': a.retract_mm_s,
              'max_travel_mm': a.max_travel_mm, 'min_start_gap_mm': a.min_start_gap_mm,
              'stale_timeout_s': a.stale_ms * 1e-3}
    sim = None
    if a.sim:
        if not (0.5 <= a.sim_gap_mm <= 19.0 and 0.0 <= a.sim_noise_mm <= 1.0
                and 0.5 <= a.sim_watchdog_ms <= 1000.0):
            raise CliError('--sim-gap-mm must be in [0.5, 19], --sim-noise-mm in [0, 1], '
                           '--sim-watchdog-ms in [0.5, 1000]')
    try:
        from .node.calibrate_node import SimOptions, run_calibration

        if a.sim:
            sim = SimOptions(a.sim_gap_mm, a.sim_noise_mm, a.sim_watchdog_ms * 1e-3)
        result = run_calibration(str(out), motion, sim, lockstep=a.lockstep)
    except (CalibrationError, FileNotFoundError) as exc:
        raise CliError(' '.join(str(exc).split())) from None
    except ImportError as exc:
        raise CliError(f'the ROS workspace is not built ({exc}): scripts/setup-env') from None
    if result.get('problems'):
        print('table rejected: ' + '; '.join(result['problems']), file=sys.stderr)
    else:
        print(f'table: {result["table_file"]} ({result["points"]} points, '
              f'{result["gap_min_mm"]:.3f}–{result["gap_max_mm"]:.3f} mm, grade '
              f'{result["grade"]})')
    print(f'written: {result["output"]}/calibration.md, calibration.png, calibration.json, '
          'sweep.csv')
    print(json.dumps(strict_json(result)))
    return 0 if result.get('ok') else 1


# ---- params -------------------------------------------------------------------------------
PARAMETERS_DOC_HEAD = """# Parameters

GENERATED by `scripts/in-env ladrc params --markdown > docs/parameters.md` from the one
declaration of each parameter (`param(...)` fields in `ladrc_follow/control/`); a test fails
when this page is stale. The same declarations give the YAML loading and validation, the ROS
parameter descriptors of the follow node (range, unit, `read_only`) and the shipped parameter
file `ladrc_tools/config/follow.yaml` (`ladrc params --yaml`).

Ranges: `(a, b]` means a < value <= b. Every number has finite bounds; a value outside them,
a non-finite value or a wrong type is rejected with its reason and the running values stay.
The checks that relate several parameters (discrete stability of the TDs and the observer,
kp·h < 1, contradicting limits, the follow windows) are in `ladrc_follow/control/params.py`
(`CROSS_CHECKS`). "start-up" parameters are `read_only` on the node.

"""


def parameters_doc() -> str:
    """Return docs/parameters.md: the header and the generated table."""
    from ladrc_follow.control.params import ControllerParams
    from ladrc_follow.control.schema import markdown_table

    return PARAMETERS_DOC_HEAD + markdown_table(ControllerParams())


def _add_params(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument('--yaml', action='store_true',
                   help='the default parameter file (ROS 2 layout, commented)')
    g.add_argument('--markdown', action='store_true', help='docs/parameters.md')
    g.add_argument('--check', metavar='FILE', help='load and validate a parameter file')


def _run_params(a: argparse.Namespace) -> int:
    from ladrc_follow.analysis.gate import check_gate
    from ladrc_follow.control.params import ParameterError, load_params, parameter_file

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


# ---- the subcommands ----------------------------------------------------------------------
# name -> (help, add arguments, run). Extend here.
COMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None],
                          Callable[[argparse.Namespace], int]]] = {
    'simulate': ('run a scenario headless (no ROS), print metrics, optionally write a bag',
                 _add_simulate, _run_simulate),
    'report': ('metrics, loop timing, loss and plots of a bag (report.md, report.json, PNGs)',
               _add_report, _run_report),
    'export': ('one CSV per topic of a bag', _add_export, _run_export),
    'replay': ("re-run the controller on a bag's recorded inputs (bit-for-bit check, what-if)",
               _add_replay, _run_replay),
    'params': ('the controller parameters: default file, docs table, or check a file',
               _add_params, _run_params),
    'analyze': ('the linear loop of a parameter set around the axis model: margins, Ms, '
                'bandwidth, Bode plots (analysis.md, analysis.json, bode.png)',
                _add_analyze, _run_analyze),
    'tune': ('sweep a grid of LADRC sets (ω0, kp, b0) through the stability gate and the '
             'batch closed loop; Pareto front; the chosen set as tuned.yaml',
             _add_tune, _run_tune),
    'identify': ('identify the axis (b0, T1, dead time) and the sensor (gain, lag, noise) '
                 'from a bag; suggested, gate-checked parameters (identification.md, fit.png, '
                 'params.yaml)', _add_identify, _run_identify),
    'excite': ('play an excitation (PRBS, chirp) on the headless sim, no controller, and '
               'write the bag (the input of identify)', _add_excite, _run_excite),
    'conform': ('check a driver against the contract (topics, QoS, rate, seq, stamps, units '
                'and signs, enable, watchdog) rule by rule; report.md, conform.json and the '
                'motion-test bag', _add_conform, _run_conform),
    'calibrate': ('capacitive calibration: descend slowly to contact, retract, build, check '
                  'and grade the raw → gap table (cap_table.yaml, calibration.md/.json/.png)',
                  _add_calibrate, _run_calibrate),
    'suite': ('run the scenario library for PID and LADRC variants; comparison table '
              "(suite.md, suite.json, suite.csv) beside the notes' measured figures",
              _add_suite, _run_suite),
}


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line + exit 2, as for every bad input
        self.exit(EXIT_USAGE, f'{self.prog}: {message}\n')


def build_parser() -> argparse.ArgumentParser:
    """Return the ``ladrc`` argument parser with one subparser per :data:`COMMANDS` entry."""
    parser = _Parser(prog='ladrc', description='LADRC height-follow tools: headless '
                     'simulation, bag replay, reports, CSV export and the quality suite.')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', required=True,
                                parser_class=_Parser)
    for name, (help_text, add, _) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        add(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``ladrc`` console script."""
    args = build_parser().parse_args(argv)
    try:
        return COMMANDS[args.command][2](args)
    except (CliError, BagError) as exc:
        print(f'ladrc {args.command}: {exc}', file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f'ladrc {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
