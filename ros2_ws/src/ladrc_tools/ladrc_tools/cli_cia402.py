"""``ladrc cia402 plan DEVICE.yaml``: what the CiA 402 driver will do with a drive, before power.

No bus: the device file and the drive's EDS (python-canopen reads it) give the SDO writes in
order, the PDO layouts, the watchdog chosen and the bus load at the period and bitrate
(:mod:`ladrc_cia402.device_file`); or the first refusal, one line, exit 2.
"""

from __future__ import annotations

import argparse

from .cli_common import CliError


def _add_cia402(p: argparse.ArgumentParser) -> None:
    p.add_argument('action', choices=['plan'], help='plan: print the plan (no bus)')
    p.add_argument('device', help="the drive's device file (YAML; docs/cia402.md)")
    p.add_argument('--period-ms', type=float, default=0.5,
                   help='the SYNC period = the controller period [0.5]')
    p.add_argument('--rpdo-deadline-ms', type=int, default=10,
                   help="the RPDO event timer when the file leaves it 0 [10, the driver's]")


def _run_cia402(args: argparse.Namespace) -> int:
    from ladrc_cia402 import PlanError, load_device, make_plan, plan_text

    if not 0.1 <= args.period_ms <= 100.0:
        raise CliError(f'--period-ms {args.period_ms:g}: must be in [0.1, 100]')
    try:
        plan = make_plan(load_device(args.device), args.period_ms * 1e-3,
                         args.rpdo_deadline_ms)
    except PlanError as exc:
        raise CliError(str(exc)) from None
    print(plan_text(plan))
    return 0
