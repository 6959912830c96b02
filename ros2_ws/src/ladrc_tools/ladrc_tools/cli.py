"""``ladrc``: the user CLI (simulate, replay, report, export, suite, params, analyze, tune, ...).

Every subcommand of this package is one entry of :data:`COMMANDS` (name -> :class:`Command`:
help, add-arguments, run); the packages above it add theirs under the entry-point group
``ladrc.commands`` (ladrc_bringup: conform, calibrate; ladrc_fleet: fleet, fleet-gen), found by
:func:`commands`. Bad input (missing file, truncated/foreign bag, missing topic,
unknown parameter) ends with ONE line on stderr and exit code 2, no traceback, and nothing
half-written (outputs are built under a temporary name and renamed when complete).
"""

from __future__ import annotations

import argparse
from importlib.metadata import entry_points
import sys

from ladrc_bags import BagError

from .cli_cia402 import _add_cia402, _run_cia402
from .cli_commissioning import _add_excite, _add_identify, _run_excite, _run_identify
from .cli_common import COMMAND_GROUP, EXIT_USAGE, CliError, Command
from .cli_job import _add_job, _add_post, _run_job, _run_post
from .cli_offline import (
    _add_analyze,
    _add_export,
    _add_params,
    _add_replay,
    _add_report,
    _add_simulate,
    _add_suite,
    _add_tune,
    _run_analyze,
    _run_export,
    _run_params,
    _run_replay,
    _run_report,
    _run_simulate,
    _run_suite,
    _run_tune,
    make_controller,
    parameters_doc,
)

__all__ = ['COMMANDS', 'CliError', 'Command', 'EXIT_USAGE', 'build_parser', 'commands', 'main',
           'make_controller', 'parameters_doc']


# ---- the subcommands ----------------------------------------------------------------------
# name -> (help, add arguments, run). Extend here (or, from a package above: ladrc.commands).
_TABLE = {
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
    'job': ('run a cutting job headless (sheet in XY, part program from DXF, the simulated '
            'CNC): per-job figures; --compare a CNC-partner feature on and off; -o job.png',
            _add_job, _run_job),
    'post': ("a job's part program as G-code for LinuxCNC (pre-offset path, M3/M5 $0, G64 P, "
             'M62/M63 P2 around the edge-ahead holds): bringup --cnc linuxcnc runs it',
             _add_post, _run_post),
    'cia402': ("a CiA 402 drive's plan before power (plan DEVICE.yaml): SDO writes, PDO "
               'layouts, watchdog, bus load; or the first refusal in one line',
               _add_cia402, _run_cia402),
    'suite': ('run the scenario library for PID and LADRC variants; comparison table '
              "(suite.md, suite.json, suite.csv) beside the notes' measured figures",
              _add_suite, _run_suite),
}
COMMANDS: dict[str, Command] = {name: Command(*entry) for name, entry in _TABLE.items()}


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line + exit 2, as for every bad input
        self.exit(EXIT_USAGE, f'{self.prog}: {message}\n')


def commands(only: str | None = None) -> dict[str, Command]:
    """Return :data:`COMMANDS` and the registered subcommands (group ``ladrc.commands``).

    ``only``: the subcommand about to run; when it is one, no other registered one is imported.
    """
    found = dict(COMMANDS)
    if only in found:
        return found
    registered = sorted(entry_points(group=COMMAND_GROUP), key=lambda e: e.name)
    if any(ep.name == only for ep in registered):
        registered = [ep for ep in registered if ep.name == only]
    for ep in registered:
        found.setdefault(ep.name, Command(*ep.load()))
    return found


def build_parser(table: dict[str, Command] | None = None) -> argparse.ArgumentParser:
    """Return the ``ladrc`` argument parser with one subparser per subcommand of ``table``.

    ``table`` defaults to :func:`commands`.
    """
    parser = _Parser(prog='ladrc', description='LADRC height-follow tools: headless '
                     'simulation, bag replay, reports, CSV export and the quality suite.')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', required=True,
                                parser_class=_Parser)
    for name, (help_text, add, _) in (commands() if table is None else table).items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        add(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``ladrc`` console script."""
    words = sys.argv[1:] if argv is None else argv
    table = commands(words[0] if words and not words[0].startswith('-') else None)
    args = build_parser(table).parse_args(argv)
    try:
        return table[args.command].run(args)
    except (CliError, BagError) as exc:
        print(f'ladrc {args.command}: {exc}', file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f'ladrc {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
