"""The ``ladrc`` subcommands that start node processes: conform, calibrate.

Registered under ``ladrc.commands`` (setup.py) as :data:`CONFORM` and :data:`CALIBRATE`;
docs/conformance.md, docs/calibration.md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys

from ladrc_tools.cli_common import CliError, Command


# ---- conform (the driver conformance kit, docs/conformance.md) ----------------------------
def _add_conform(p: argparse.ArgumentParser) -> None:
    from ladrc_tools.commissioning.conformance import Plan

    d = Plan()
    g = p.add_mutually_exclusive_group()
    g.add_argument('--sim', action='store_true',
                   help='start the sim node as the drive (flat sheet, no follow commands) on an '
                   'isolated DDS domain and check it')
    g.add_argument('--drive', choices=['cia402'],
                   help='start a drive path of the project and check it: cia402 = the CiA 402 '
                   'driver node with the emulated CiA 402 drive on the test bus')
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
    p.add_argument('--period-ms', type=float, default=None,
                   help='with --drive: the SYNC period, and the rate the kit expects [1: the '
                   'test bus does not hold 0.5 ms free-running on 2 cores, docs/real-axis.md]')
    p.add_argument('--device', metavar='YAML', default=None,
                   help="with --drive cia402: the drive's device file (its EDS beside it; the "
                   'emulated drive loads the same; default: the shipped drive, docs/cia402.md)')
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

    from ladrc_tools.commissioning.conformance import Plan, Tolerances

    from .conform_node import ConformError
    from .conform_run import ConformOptions, run_conform

    d = Plan()
    plan = dataclasses.replace(
        d, min_gap_mm=a.min_gap_mm, max_travel_mm=a.max_travel_mm,
        max_speed_mm_s=a.max_speed_mm_s, test_speed_mm_s=a.test_speed_mm_s,
        test_travel_mm=a.test_travel_mm, excitation=None if a.no_excitation else d.excitation)
    if a.sim_scenario and not (a.sim or a.drive):
        raise CliError('--sim-scenario needs --sim or --drive')
    if not 0.0 < a.watchdog_timeout_ms <= 1000.0:
        raise CliError(f'--watchdog-timeout-ms {a.watchdog_timeout_ms:g}: must be in (0, 1000]')
    if a.period_ms is not None and not a.drive:
        raise CliError('--period-ms needs --drive')
    if a.device and not a.drive:
        raise CliError('--device needs --drive cia402')
    if a.device and not Path(a.device).is_file():
        raise CliError(f'--device {a.device}: no such file')
    period_s = (a.period_ms if a.period_ms is not None else 1.0) * 1e-3
    if a.drive and not 0.25 <= period_s * 1e3 <= 10.0:
        raise CliError(f'--period-ms {a.period_ms:g}: must be in [0.25, 10]')
    watchdog_s = a.watchdog_timeout_ms * 1e-3
    tolerances = (Tolerances.for_period(period_s, watchdog_timeout_s=watchdog_s) if a.drive
                  else Tolerances(watchdog_timeout_s=watchdog_s))
    out = Path(a.output or time.strftime('conform-%Y%m%d-%H%M%S'))
    opts = ConformOptions(output=out, sim=a.sim, driver_cmd=a.driver_cmd, plan=plan,
                          tolerances=tolerances, period_s=period_s,
                          domain_id=a.domain_id, discovery_timeout_s=a.discovery_timeout_s,
                          sim_scenario=a.sim_scenario, drive=a.drive or '',
                          device=str(Path(a.device).resolve()) if a.device else '')
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
    from ladrc_tools.commissioning.calibration import SweepMotion

    d = SweepMotion()
    p.add_argument('--sim', action='store_true',
                   help='start the sim node on a DDS domain of its own and calibrate it '
                   '(default: the driver on the current domain)')
    p.add_argument('--drive', choices=['cia402'],
                   help='with --sim: the simulated axis behind the CiA 402 path (the emulated '
                   'drive, the driver node, the test bus; the raw value is the analog count)')
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
    from ladrc_tools.commissioning.calibration import CalibrationError
    from ladrc_tools.offline.report import strict_json

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
        from .calibrate_node import SimOptions, run_calibration

        if a.drive and not a.sim:
            raise CliError('--drive needs --sim (a drive of your own: start its driver and '
                           'calibrate without --sim)')
        if a.sim:
            sim = SimOptions(a.sim_gap_mm, a.sim_noise_mm, a.sim_watchdog_ms * 1e-3,
                             drive=a.drive or '')
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


CONFORM = Command('check a driver against the contract (topics, QoS, rate, seq, stamps, units '
                'and signs, enable, watchdog) rule by rule; report.md, conform.json and the '
                'motion-test bag',
                  _add_conform, _run_conform)
CALIBRATE = Command('capacitive calibration: descend slowly to contact, retract, build, check '
                  'and grade the raw → gap table (cap_table.yaml, calibration.md/.json/.png)',
                    _add_calibrate, _run_calibrate)
