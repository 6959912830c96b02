"""The ``ladrc`` subcommands of identifying a real axis from a bag: identify, excite.

Each is an add-arguments function and a run function (``cli.py``'s table);
docs/identification.md. ``conform`` and ``calibrate`` start node processes: ladrc_bringup's.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys

from .cli_common import CliError


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
