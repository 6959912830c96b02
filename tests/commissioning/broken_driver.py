"""A deliberately broken drive for the conformance kit's tests: the sim node with defects.

A real rclpy process: the sim node's own ``main`` (``ladrc_sim.node.sim_node``), its drive
bridge and its models, with the classes it instantiates swapped for subclasses that add the
defects chosen on the command line::

    python tests/commissioning/broken_driver.py --defect wrong_sign [--defect ...] [--ros-args ...]

Defects (each breaks what a real driver gets wrong, and nothing else):

``wrong_sign``     the drive moves down on a positive (up) command; the encoder is right
``gap_um``         ``gap_mm`` carries micrometres (an amplifier set to µm output)
``future_stamps``  header stamps 50 ms ahead of the clock
``no_watchdog``    commands stop: the drive keeps the last one, no fault, no stop
``seq_gaps``       ``seq`` skips one number every 200 samples (both topics)
``reliable_only``  RELIABLE publishers and a RELIABLE command subscription
``ignore_enable``  ``enable=false`` is ignored (the velocity is executed)
``any_commander``  commands from any sender are executed (no commander lock: a second
                   commander's commands interleave with the first's, no fault)
``speed_x3``       the drive moves three times the commanded speed (b0 = 3; trips the kit's
                   speed bound in the excitation)
``one_fault``      one transient drive fault (quick stop, cleared 0.1 s later) 0.6 s after the
                   first command: not a defect of the contract, but what a stall of the host
                   looks like to the kit (it repeats the motion tests)

Without ``-p scenario:=...`` it plays the conformance scenario of ``ladrc conform --sim`` (flat
resting sheet, no follow commands, 5 mm above the sheet).
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
import tempfile

ROOT = Path(__file__).resolve().parents[2]
for _pkg in ('ladrc_sim', 'ladrc_tools', 'ladrc_bags', 'ladrc_follow'):
    _src = str(ROOT / 'ros2_ws' / 'src' / _pkg)
    if _src not in sys.path:
        sys.path.insert(0, _src)

from ladrc_contract import qos  # noqa: E402
from ladrc_sim.node import sim_node as sn  # noqa: E402
from ladrc_tools.commissioning.conformance import sim_scenario_yaml  # noqa: E402

DEFECTS = ('wrong_sign', 'gap_um', 'future_stamps', 'no_watchdog', 'seq_gaps', 'reliable_only',
           'ignore_enable', 'any_commander', 'speed_x3', 'one_fault')
FAULT_AFTER_TICKS = 1200  # 0.6 s after the first command: in the kit's 'up' test
FUTURE_NS = 50_000_000
SEQ_SKIP_EVERY = 200


class _Tampered:
    """An outgoing message type of the sim whose fields are altered just before packing."""

    def __init__(self, outgoing, alter) -> None:
        self._outgoing = outgoing
        self._alter = alter

    def pack(self, sec: int, nsec: int, **fields) -> bytes:
        stamp_ns = self._alter(sec * 1_000_000_000 + nsec, fields)
        return self._outgoing.pack(*divmod(stamp_ns, 1_000_000_000), **fields)


def make_classes(defects: set[str]):
    """Return the (SimNode, DriveBridge) subclasses with ``defects``."""
    base_node, base_bridge = sn.SimNode, sn.DriveBridge

    class BrokenBridge(base_bridge):
        def __init__(self, node, realtime: bool = True) -> None:
            super().__init__(node, realtime)
            if 'no_watchdog' in defects:
                self.watchdog_ticks = 2**62  # never trips: the last command stays in force
            self._ticks_commanded = 0
            if 'any_commander' in defects:
                self.lock.admit = lambda commander, session, release: True

        def step(self, tick) -> float:
            if 'one_fault' in defects and self.cmd_count:
                self._ticks_commanded += 1
                if self._ticks_commanded == FAULT_AFTER_TICKS:
                    # latched like a watchdog fault: cleared after watchdog_recover_s of commands
                    self.fault_reason = 'injected transient fault (test)'
            u = super().step(tick)
            if 'speed_x3' in defects:
                u = 3.0 * u
            return -u if 'wrong_sign' in defects else u

        def on_command(self, data: bytes, received_ns: int) -> None:
            super().on_command(data, received_ns)
            if 'ignore_enable' in defects:
                self.cmd_enable = True

    class BrokenNode(base_node):
        def __init__(self) -> None:
            super().__init__()
            def each(stamp_ns: int, fields: dict) -> int:
                if 'seq_gaps' in defects:
                    fields['seq'] += fields['seq'] // SEQ_SKIP_EVERY
                return stamp_ns + (FUTURE_NS if 'future_stamps' in defects else 0)

            def gap_alter(stamp_ns: int, fields: dict) -> int:
                if 'gap_um' in defects:
                    fields['gap_mm'] *= 1000.0
                return each(stamp_ns, fields)

            out = self._out
            out['CapacitiveHeight'] = _Tampered(out['CapacitiveHeight'], gap_alter)
            out['AxisFeedback'] = _Tampered(out['AxisFeedback'], each)

    return BrokenNode, BrokenBridge


def main(argv: list[str] | None = None) -> int:
    """Run the sim node with the defects of the command line."""
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args = argv[argv.index('--ros-args'):] if '--ros-args' in argv else []
    ours = argv[:len(argv) - len(ros_args)]
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--defect', action='append', choices=DEFECTS, default=[])
    ap.add_argument('--start-gap-mm', type=float, default=5.0)
    a = ap.parse_args(ours)
    defects = set(a.defect)
    if 'reliable_only' in defects:  # the contract's profiles, reliable, in this process
        qos.HIGH_RATE = qos.Qos(reliable=True, transient_local=False, depth=100)
        qos.CONTROL_INPUT = qos.Qos(reliable=True, transient_local=False, depth=1)
        qos.DRIVE_COMMAND_INPUT = qos.Qos(reliable=True, transient_local=False, depth=10)
    sn.SimNode, sn.DriveBridge = make_classes(defects)
    with tempfile.TemporaryDirectory(prefix='broken-driver-') as tmp:
        if not any(x.startswith('scenario:=') for x in ros_args):
            scenario = Path(tmp) / 'conform_drive.yaml'
            scenario.write_text(sim_scenario_yaml(a.start_gap_mm), encoding='utf-8')
            ros_args = (ros_args or ['--ros-args']) + ['-p', f'scenario:={scenario}']
        return sn.main([sys.argv[0], *ros_args])


if __name__ == '__main__':
    sys.exit(main())
