"""The emulated CiA 402 Z drive as a process of its own, without ROS.

    python -m ladrc_sim.cia402.emulator --bus ws://127.0.0.1:PORT/ [--device FILE] [--eds PATH]
        [--scenario NAME] [--free-running]

The scenario's world (axis, sheet, sensor; :func:`ladrc_sim.headless.runner.run`) behind a
CANopen node (:class:`~.can_drive.CanDrive`, which says what the drive does on the bus), for a
master of one's own: a driver under test, the conformance kit's bus tests. The scenario's follow
commands go nowhere (there is no controller to call); with ROS, the sim node plays scenarios and
jobs through the same drive (``-p drive:=cia402``), commands and truth included. Lock step by
default (one period per SYNC); ``--free-running``: the drive moves by its own clock. When the
scenario ends the drive stops answering SYNC (the master sees its TPDOs missing) and the process
exits 0.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
import sys

from ladrc_cia402 import PlanError
from ladrc_contract.node_entry import stop_signals

from ..headless.runner import run
from ..headless.scenario import ScenarioError, load_scenario
from .can_drive import CanDrive, LockstepAbort, StopDrive, connect


def main(argv: list[str] | None = None) -> int:
    """Run one emulated drive until SIGTERM / SIGINT."""
    p = argparse.ArgumentParser(prog='python -m ladrc_sim.cia402.emulator',
                                description='Emulated CiA 402 Z drive on a CAN bus.')
    p.add_argument('--bus', required=True, help='ws://127.0.0.1:PORT/ (python-can-remote) '
                   'or a socketcan channel (can0)')
    p.add_argument('--node-id', type=int, default=None, help="default: the device file's")
    p.add_argument('--eds', type=Path, default=None, help="default: the device file's")
    p.add_argument('--device', type=Path, default=None,
                   help="the drive's device file (default: the shipped one)")
    p.add_argument('--scenario', default='step', help='the world: a scenario of the library')
    p.add_argument('--free-running', action='store_true',
                   help="the drive's own clock instead of lock step")
    p.add_argument('--lockstep-timeout', type=float, default=30.0,
                   help='lock step: wall-clock wait for a SYNC before giving up [30 s]')
    a = p.parse_args(argv)
    if a.node_id is not None and not 1 <= a.node_id <= 127:
        p.error(f'--node-id {a.node_id}: 1..127')
    logging.basicConfig(level=logging.WARNING, format='emulator: %(levelname)s %(message)s')
    try:
        scenario = load_scenario(a.scenario)
    except ScenarioError as exc:
        print(f'emulator: {exc}', file=sys.stderr)
        return 2
    network = connect(a.bus)
    drive = None
    with stop_signals() as stop:
        try:
            try:
                drive = CanDrive(network, a.node_id, a.eds, device=a.device,
                                 lockstep=not a.free_running,
                                 lockstep_timeout_s=a.lockstep_timeout)
            except PlanError as exc:
                print(f'emulator: {exc}', file=sys.stderr)
                return 2

            def _stop() -> None:
                drive.running = False

            stop.on_stop(_stop)
            drive.boot()
            print(f'emulator: node {drive.node_id} on {a.bus}, h_s {drive.h_s:g} s, scenario '
                  f'{scenario.name}', flush=True)
            try:
                run(scenario, drive, h_s=drive.h_s)
                print(f'emulator: scenario {scenario.name} ended after {drive.seq} periods',
                      flush=True)
            except StopDrive:
                pass
            except LockstepAbort as exc:
                print(f'emulator: {exc}', file=sys.stderr)
                return 3
            return 0
        finally:
            if drive is not None:
                drive.node.nmt.stop_heartbeat()
            network.disconnect()


if __name__ == '__main__':
    sys.exit(main())
