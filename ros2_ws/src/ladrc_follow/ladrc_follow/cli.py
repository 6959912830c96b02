"""``ladrc``: the user CLI (report, export, simulate; replay and suite to come).

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

from .bag import BagError

EXIT_USAGE = 2


class CliError(Exception):
    """A user-facing error: printed as one line, exit code 2."""


# ---- report / export ----------------------------------------------------------------------
def _add_report(p: argparse.ArgumentParser) -> None:
    p.add_argument('bag', help='bag folder (or a file inside it)')
    p.add_argument('-o', '--output', help='output folder (default: <bag>_report)')
    p.add_argument('-q', '--quiet', action='store_true', help='no progress on stderr')


def _run_report(a: argparse.Namespace) -> int:
    from .report import write_report

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
    from .export import export_csv
    from .report import stderr_progress

    files = export_csv(a.bag, a.output, progress=None if a.quiet else stderr_progress)
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
        from .control.follow import FollowController
    except ImportError as exc:
        raise CliError(f'the follow controller is not available yet ({exc})') from None
    try:
        return FollowController(params, mode=kind)
    except TypeError:
        return FollowController(params)


def _run_simulate(a: argparse.Namespace) -> int:
    from ladrc_sim.runner import run, summary
    from ladrc_sim.scenario import ScenarioError, load_scenario

    from .control.params import ControllerParams, ParameterError, dump_params, load_params

    try:
        scenario = load_scenario(a.scenario)
    except (ScenarioError, OSError) as exc:
        raise CliError(str(exc).splitlines()[0]) from None
    try:
        params = load_params(a.params) if a.params else ControllerParams()
    except ParameterError as exc:
        raise CliError(' '.join(str(exc).split())) from None
    if a.output and Path(a.output).exists():
        raise CliError(f'{a.output} exists already: a bag is never overwritten')
    controller = make_controller(a.controller, params)
    result = run(scenario, controller, record_internals=True)
    out = summary(result)
    if a.output:
        from .bag import write_run_bag

        scenario_text = _scenario_text(a.scenario, scenario)
        write_run_bag(result, a.output, dump_params(params), scenario_text,
                      storage=a.storage, controller=a.controller)
        out = {'bag': a.output, **out}
    from .report import strict_json

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
        from ladrc_sim.scenario import list_scenarios

        for f in list_scenarios():
            if f.stem == arg:
                return f.read_text(encoding='utf-8')
    except ImportError:
        pass
    return f'name: {getattr(scenario, "name", arg)}\n'


# ---- placeholders -------------------------------------------------------------------------
def _add_bag_only(p: argparse.ArgumentParser) -> None:
    p.add_argument('args', nargs='*', help='(not implemented yet)')


def _not_implemented(a: argparse.Namespace) -> int:
    print(f'ladrc {a.command}: not implemented yet', file=sys.stderr)
    return EXIT_USAGE


# name -> (help, add arguments, run). Extend here.
COMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None],
                          Callable[[argparse.Namespace], int]]] = {
    'simulate': ('run a scenario headless (no ROS), print metrics, optionally write a bag',
                 _add_simulate, _run_simulate),
    'report': ('metrics, loop timing, loss and plots of a bag (report.md, report.json, PNGs)',
               _add_report, _run_report),
    'export': ('one CSV per topic of a bag', _add_export, _run_export),
    'replay': ("re-run the controller on a bag's recorded inputs", _add_bag_only,
               _not_implemented),
    'suite': ('run the scenario suite and compare controllers', _add_bag_only,
              _not_implemented),
}


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line + exit 2, as for every bad input
        self.exit(EXIT_USAGE, f'{self.prog}: {message}\n')


def build_parser() -> argparse.ArgumentParser:
    """Return the ``ladrc`` argument parser with one subparser per :data:`COMMANDS` entry."""
    parser = _Parser(prog='ladrc', description='LADRC height-follow tools: headless '
                     'simulation, bag reports and CSV export.')
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
