"""A drive on a CAN bus as one command: the test bus, the emulated CiA 402 drive, its driver.

    cia402_stack [--scenario NAME|YAML] [--bus URL] [--watchdog-timeout-s S] [--lockstep]

For the tools that check a driver (``ladrc conform --drive cia402``, ``ladrc calibrate`` and
``ladrc identify`` through it): it starts python-can-remote on 127.0.0.1 (unless ``--bus``
names a running bus), the sim node with its drive on that bus (``drive:=cia402``, the scenario's
world, no follow commands of its own for the kit's flat-sheet scenario) and the CiA 402 driver
node, on the ROS domain of its environment; on SIGINT or SIGTERM it stops them in the safe order
(the driver first, which quick-stops the drive, then the drive, then the bus), each by its PID,
and exits 0. A process that exits early ends the stack with code 1 and names it.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import sys
import time

from ladrc_contract.node_entry import take_stop_signals

from .bringup import Bringup, NodeSpec, bus_interface, emulated_drive_device


def stack_specs(scenario: str, bus: str, watchdog_timeout_s: float, lockstep: bool = False,
                node_id: int = 5, exit_at_end: bool = True, period_s: float = 0.0005,
                raw_only: bool = False, device: str = '') -> list[NodeSpec]:
    """Return the emulated drive (the sim node on the bus) and the CiA 402 driver node.

    ``device``: the drive's device file, which both load (default: the shipped drive's).
    """
    device = device or emulated_drive_device()
    sim = NodeSpec('ladrc_sim', 'sim_node', 'ladrc_sim', parameters={
        'scenario': scenario, 'exit_at_end': exit_at_end, 'drive': 'cia402', 'can_bus': bus,
        'can_device': device, 'lockstep': lockstep, 'h_s': period_s})
    driver = NodeSpec('ladrc_cia402', 'driver_node', 'ladrc_driver', parameters={
        'device': device, 'bus_interface': bus_interface(bus), 'bus_channel': bus,
        'watchdog_timeout_s': watchdog_timeout_s, 'lockstep': lockstep,
        'period_s': period_s, 'raw_only': raw_only,
        # the drive's own deadline is behind the driver's watchdog (a dead driver, not a
        # silent controller): at least twice it
        'rpdo_deadline_ms': max(10, int(round(2e3 * watchdog_timeout_s)))})
    return [sim, driver]


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``cia402_stack``."""
    ap = argparse.ArgumentParser(prog='cia402_stack', description=__doc__.split('\n\n')[0])
    ap.add_argument('--scenario', default='step', help="the drive's world [step]")
    ap.add_argument('--bus', default=None, help='a running bus (default: start one here)')
    ap.add_argument('--watchdog-timeout-s', type=float, default=0.005,
                    help="the driver's command watchdog [0.005]")
    ap.add_argument('--lockstep', action='store_true', help='one period per SYNC')
    ap.add_argument('--raw-only', action='store_true',
                    help='the driver publishes the analog count as raw_hz and no gap_mm')
    ap.add_argument('--period-s', type=float, default=0.0005,
                    help="the SYNC period = the drive world's h_s [0.0005]")
    ap.add_argument('--device', default='', help="the drive's device file (both load it) "
                    '[the shipped drive]')
    ap.add_argument('--logs', default=None, help="folder for the processes' output")
    a = ap.parse_args(argv)
    stop = take_stop_signals()  # SIGINT/SIGTERM: the nodes are stopped, the run reported
    logs = Path(a.logs) if a.logs else None
    server = None
    if not a.bus:
        from ladrc_sim import start_bus_server

        if logs is not None:
            logs.mkdir(parents=True, exist_ok=True)
        try:
            server = start_bus_server(logs / 'can_bus.log' if logs else None)
        except (OSError, RuntimeError) as exc:
            print(f'cia402_stack: cannot start the CAN bus server: {exc}', file=sys.stderr)
            return 2
    bus = a.bus or server.url
    up = Bringup(stack_specs(a.scenario, bus, a.watchdog_timeout_s, a.lockstep,
                             period_s=a.period_s, raw_only=a.raw_only,
                             device=str(Path(a.device).resolve()) if a.device else ''),
                 dict(os.environ), logs)
    print(f'cia402_stack: bus {bus}', file=sys.stderr, flush=True)
    code = 0
    try:
        up.start()
        while not stop.stop_requested:
            gone = {n: p.returncode for n, p in up.procs.items() if p.poll() is not None}
            if gone:
                print('cia402_stack: exited early: '
                      + ', '.join(f'{n}={c}' for n, c in gone.items()), file=sys.stderr)
                code = 1
                break
            time.sleep(0.1)
    finally:
        up.stop(['ladrc_driver', 'ladrc_sim'])
        if server is not None:
            server.stop()
    return code


if __name__ == '__main__':
    sys.exit(main())
