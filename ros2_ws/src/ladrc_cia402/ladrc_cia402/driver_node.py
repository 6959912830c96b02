r"""The CiA 402 driver node: the drive contract on ROS, a CANopen master on the bus.

    ros2 run ladrc_cia402 driver_node --ros-args -p device:=DRIVE.yaml \\
        -p bus_interface:=socketcan -p bus_channel:=can0

ROS side (the contract, docs/interfaces.md): ``axis/velocity_command`` in (through the commander
lock, :mod:`ladrc_contract.commander_lock`), ``axis/feedback`` and ``axis/capacitive_height``
out (one sample pair per SYNC, ``seq`` +1 per sample, stamped at the SYNC), ``axis/reset_drive``
(the drive's fault reset, the commander lock's and the watchdog's), /diagnostics at 1 Hz.

Bus side: :mod:`.master` (plain Python) does everything CANopen: configuration by SDO from the
drive's EDS/DCF, RPDO + SYNC + the TPDOs of that SYNC per period, the power state machine, EMCY,
faults. This node only turns messages into :class:`~.master.Command` and samples into messages,
and keeps the drive contract's own guards:

* **watchdog**: no admitted command for ``watchdog_timeout_s`` (counted in the driver's cycles)
  -> quick stop and ``drive_fault`` with the reason, until commands are back for
  ``watchdog_recover_s``; if this process dies, the drive's own RPDO deadline (0x1400 sub 5,
  configured at start) brakes the axis;
* **one commander**: a second commander's first command quick-stops the drive and faults it,
  naming both, until ``axis/reset_drive``;
* **every exception path ends in a quick stop** (the master's cycle never raises; an exception
  here sends a quick-stop controlword with a zero target, then the node exits).

Lock step (``lockstep: true``): cycle k is sent only when the controller's command answering
sample k-1 has arrived; samples are stamped k·h_s (the sim's clock); the emulated drive advances
one period per SYNC (ladrc_sim/cia402/can_drive.py), so a run is independent of load. The
``sim/lockstep`` steps come from the simulation (the emulated drive's process).
"""

from __future__ import annotations

import json
import math
import sys
import threading
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from ladrc_contract import qos
from ladrc_contract.cdr import CdrPacker, Outgoing
from ladrc_contract.commander_lock import CommanderLock, describe
from ladrc_contract.loop_io import LoopNode, SampleWait
from ladrc_contract.node_entry import NodeRun, StartError, run_node
from ladrc_contract.qos import to_rclpy
from ladrc_contract.realtime import apply_realtime
from ladrc_contract.ros_params import declare_section
from ladrc_contract.service_thread import ServiceThread
from ladrc_contract.topics import COMMAND_TOPIC, DIAGNOSTICS_TOPIC, FEEDBACK_TOPIC, GAP_TOPIC
from ladrc_msgs.msg import AxisFeedback, CapacitiveHeight, VelocityCommand
from ladrc_msgs.srv import ResetFault
import rclpy
from rclpy.clock import Clock, ClockType

from . import ds402, mapping
from .master import Command, ConfigError, DriverParams, Master, Sample, configure

COMMAND_FIELDS = ('seq', 'velocity_mm_s', 'enable', 'sample_seq', 'commander', 'session',
                  'release')


class DriverAbort(Exception):
    """The driver cannot go on (lock step: a peer gone); one line, exit 3."""


class DriverNode(LoopNode):
    """The CiA 402 driver (module docstring)."""

    def __init__(self) -> None:
        super().__init__('z_axis_driver')
        self.p: DriverParams = declare_section(self, DriverParams())
        p = self.p
        self.h_s = p.period_s
        self.period_ns = int(round(p.period_s * 1e9))
        self.lockstep = p.lockstep
        high_rate = to_rclpy(qos.LOCKSTEP_HIGH_RATE if self.lockstep else qos.HIGH_RATE)
        self.pub_gap = self.create_publisher(CapacitiveHeight, GAP_TOPIC, high_rate)
        self.pub_fb = self.create_publisher(AxisFeedback, FEEDBACK_TOPIC, high_rate)
        self.cmd_reader = self.create_loop_reader(
            VelocityCommand, COMMAND_TOPIC,
            to_rclpy(qos.LOCKSTEP_COMMAND_INPUT if self.lockstep else qos.DRIVE_COMMAND_INPUT))
        self.cmd_cdr = CdrPacker('ladrc_msgs/msg/VelocityCommand')
        self.cmd_index = [self.cmd_cdr.index[n] for n in COMMAND_FIELDS]
        self.out_gap = Outgoing('ladrc_msgs/msg/CapacitiveHeight', p.frame_id)
        self.out_fb = Outgoing('ladrc_msgs/msg/AxisFeedback', p.frame_id)
        self.pub_diag = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC,
                                              to_rclpy(qos.DIAGNOSTICS))
        self.create_service(ResetFault, 'axis/reset_drive', self._srv_reset)
        self.create_timer(1.0, self._publish_diagnostics,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.mutex = threading.Lock()  # the lock and the watchdog: loop thread vs reset service
        self.lock = CommanderLock()
        self.velocity_mm_s = 0.0
        self.enable = False
        self.admitted = False
        self.answer_seq = -1  # lock step: sample_seq of the newest admitted command
        self.malformed = 0
        self.commands = 0
        self.watchdog_cycles = max(1, int(round(p.watchdog_timeout_s / p.period_s)))
        self.recover_cycles = max(1, int(round(p.watchdog_recover_s / p.period_s)))
        self.cycles_since_cmd = 0
        self.cycles_back = 0
        self.watchdog_reason = ''
        self.watchdog_trips = 0
        self.seq = 0  # axis/feedback samples published (each topic counts its own)
        self.gap_seq = 0  # axis/capacitive_height samples published
        self.fb_stamp_ns = -1  # the newest feedback stamp published (stamps only increase)
        self.late_cycles = 0
        self.running = True
        self.master: Master | None = None
        self.config_line = ''
        self.last: Sample | None = None
        self.ever_commanded = False  # faults of the start are reset until the first motion
        self.has_commander = False
        self.publish_gap = True  # False: the gap comes from the sensor's own node (gap: topic)

    # ---- commands -------------------------------------------------------------------------
    def take_commands(self) -> bool:
        """Take the commands that arrived, oldest first; True if one was admitted."""
        got = False
        while (taken := self.cmd_reader.take()) is not None:
            try:
                values = self.cmd_cdr.unpack(taken[0])
                seq, vel, enable, sample_seq, commander, session, release = (
                    values[i] for i in self.cmd_index)
            except ValueError:
                self.malformed += 1
                continue
            with self.mutex:
                faulted = bool(self.lock.fault_reason)
                if not self.lock.admit(commander, session, release):
                    if not faulted:
                        self.get_logger().error(f'drive fault at cycle {self.seq}: '
                                                f'{self.lock.fault_reason}')
                    self.velocity_mm_s, self.enable, self.admitted = 0.0, False, False
                    if self.lockstep and (commander, session) == self.lock.owner:
                        self.answer_seq = max(self.answer_seq, int(sample_seq))
                    continue
                self.velocity_mm_s = float(vel)
                self.enable = bool(enable) and not release
                self.admitted = True
                self.answer_seq = max(self.answer_seq, int(sample_seq))
                self.commands += 1
                got = True
        return got

    def _command(self, fresh: bool) -> Command:
        """Return the cycle's command, the watchdog and the commander lock applied."""
        with self.mutex:
            if fresh:
                self.cycles_since_cmd = 0
            elif self.commands:
                self.cycles_since_cmd += 1
            if self.commands and not self.lockstep:
                if self.cycles_since_cmd > self.watchdog_cycles:
                    if not self.watchdog_reason:
                        self.watchdog_trips += 1
                        self.watchdog_reason = (
                            f'no velocity command for {self.cycles_since_cmd} cycles (watchdog '
                            f'{self.p.watchdog_timeout_s * 1e3:g} ms): quick stop')
                        self.get_logger().warning(self.watchdog_reason)
                    self.cycles_back = 0
                elif self.watchdog_reason:
                    self.cycles_back += 1
                    if self.cycles_back > self.recover_cycles:
                        self.watchdog_reason = ''
            stop = bool(self.lock.fault_reason or self.watchdog_reason)
            self.has_commander = self.lock.owner is not None or bool(self.commands)
            return Command(self.velocity_mm_s, self.enable and not stop,
                           admitted=self.admitted and not stop,
                           commanded=self.has_commander or self.p.power_at_start,
                           quick_stop=stop)

    def _srv_reset(self, request, response):
        with self.mutex:
            was = [r for r in (self.lock.reset(), self.watchdog_reason) if r]
            self.watchdog_reason = ''
        if self.master is not None:
            self.master.request_reset()
        response.accepted = True
        response.message = f'drive reset ({"; ".join(was) or "fault reset sent to the drive"})'
        self.get_logger().info(response.message)
        return response

    # ---- samples out ----------------------------------------------------------------------
    def publish(self, s: Sample, stamp_ns: int) -> None:
        """Publish one cycle's sample pair (``seq`` +1 each)."""
        if stamp_ns <= self.fb_stamp_ns:  # a late sample of a cycle already reported
            return
        self.fb_stamp_ns = stamp_ns
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        with self.mutex:
            reasons = [r for r in (self.lock.fault_reason, self.watchdog_reason) if r]
        reasons += [s.fault_reason] if s.fault_reason else []
        fault = bool(reasons)
        # the raw value of an analog amplifier is its count (docs/cia402.md, "The device file")
        if self.publish_gap:
            self.pub_gap.publish(self.out_gap.pack(
                sec, nsec, seq=self.gap_seq, gap_mm=math.nan if self.p.raw_only else s.gap_mm,
                raw_hz=float(s.analog_counts), valid=bool(s.gap_valid), status=int(s.gap_status)))
        self.pub_fb.publish(self.out_fb.pack(
            sec, nsec, seq=self.seq, position_mm=s.position_mm, velocity_mm_s=s.velocity_mm_s,
            drive_enabled=bool(s.enabled) and not fault, drive_fault=fault,
            fault_reason='; '.join(reasons)))
        self.seq += 1
        self.gap_seq += 1

    def publish_fault(self, s: Sample, stamp_ns: int) -> None:
        """Publish a feedback sample that carries only a fault: the last position, drive_fault."""
        if stamp_ns <= self.fb_stamp_ns:
            return
        self.fb_stamp_ns = stamp_ns
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        with self.mutex:
            reasons = [r for r in (self.lock.fault_reason, self.watchdog_reason) if r]
        reasons.append(s.fault_reason or 'drive lost')
        self.pub_fb.publish(self.out_fb.pack(
            sec, nsec, seq=self.seq, position_mm=s.position_mm, velocity_mm_s=0.0,
            drive_enabled=False, drive_fault=True, fault_reason='; '.join(reasons)))
        self.seq += 1

    # ---- the loop -------------------------------------------------------------------------
    def run_free(self, master: Master) -> None:
        """One cycle per period by the clock; a cycle more than one period late skips ahead."""
        mono = time.monotonic_ns
        next_ns = mono()
        stamp_ns = 0
        wait_s = 0.95 * self.h_s  # the TPDOs of this SYNC, until just before the next
        while self.running:
            now = mono()
            if now < next_ns:
                time.sleep((next_ns - now) * 1e-9)
                continue
            late = master.take_late()
            if late is not None:
                self.publish(late, stamp_ns)  # the previous SYNC's sample, with its stamp
            stamp_ns = self.get_clock().now().nanoseconds
            command = self._command(self.take_commands())
            if not self.ever_commanded:
                # until the first command to move (enable true), the axis has only been held:
                # a fault of the start (a stall while the processes came up) is reset as a
                # master does at start-up; from then on faults latch until axis/reset_drive
                self.ever_commanded = command.enable
                if not command.enable:
                    master.clear_faults_at_rest()
            sample = master.cycle(command, wait_s)
            self.last = sample
            if sample.fresh:
                self.publish(sample, stamp_ns)
            elif master.fault_reason:
                # the bus or the drive is lost (TPDOs missing, a bus error): the controller is
                # told why, in the feedback, instead of only seeing its inputs go stale
                self.publish_fault(sample, stamp_ns)
            next_ns += self.period_ns
            if mono() - next_ns > self.period_ns:
                self.late_cycles += 1
                next_ns = mono() + self.period_ns

    def run_lockstep(self, master: Master) -> None:
        """Cycle k once the command answering k-1 is here (module docstring)."""
        wait = SampleWait(self.context, (self.cmd_reader,))
        timeout_ns = int(self.p.lockstep_timeout_s * 1e9)
        k = 0
        while self.running:
            sample = master.cycle(self._command(False), self.p.lockstep_timeout_s,
                                  abort=lambda: not self.running)
            self.last = sample
            if not self.running:
                return
            if not sample.fresh:
                raise DriverAbort(f'lock step: no TPDO from node {master.node_id} within '
                                  f'{self.p.lockstep_timeout_s:g} s at cycle {k} '
                                  f'({master.fault_reason or "the drive stopped"})')
            self.publish(sample, k * self.period_ns)
            limit = time.monotonic_ns() + timeout_ns
            while self.answer_seq < k:
                self.take_commands()
                if self.answer_seq >= k:
                    break
                if not self.running:
                    return
                if time.monotonic_ns() > limit:
                    raise DriverAbort(f'lock step: no command answering sample {k} within '
                                      f'{self.p.lockstep_timeout_s:g} s')
                wait.wait(50_000_000)
            self._command(True)
            k += 1

    def wait_for_controller(self) -> bool:
        """Lock step: a controller commands and reads both samples (or the wait ends)."""
        end = time.monotonic() + self.p.wait_for_controller_s
        while time.monotonic() < end and self.running:
            if (self.count_publishers(self.cmd_reader.topic_name) > 0
                    and self.pub_fb.get_subscription_count() > 0
                    and self.pub_gap.get_subscription_count() > 0):
                return True
            time.sleep(0.05)
        return False

    def _publish_diagnostics(self) -> None:
        m = self.master
        st = DiagnosticStatus(name=f'{self.get_fully_qualified_name().lstrip("/")}: drive',
                              hardware_id=f'cia402 node {m.node_id if m else self.p.node_id}')
        last = self.last
        with self.mutex:
            reason = self.lock.fault_reason or self.watchdog_reason
        reason = reason or (last.fault_reason if last is not None else '')
        st.level = DiagnosticStatus.ERROR if reason else DiagnosticStatus.OK
        st.message = reason or ('running' if m is not None else 'configuring')
        values: dict[str, Any] = {'seq': self.seq, 'late_cycles': self.late_cycles,
                                  'commands_received': self.commands,
                                  'watchdog_trips': self.watchdog_trips,
                                  'malformed_commands': self.malformed,
                                  'configuration': self.config_line,
                                  'commander': describe(self.lock.owner) if self.lock.owner
                                  else '', 'commanders': json.dumps(self.lock.summary())}
        if m is not None:
            values.update(cycles=m.cycles, missed_tpdo_cycles=m.missed_total,
                          late_tpdo_cycles=m.late_total,
                          emcy_received=m.emcy_count,
                          state=m.state.value if m.state is not None else '',
                          statusword=f'0x{m.statusword:04X}')
        st.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(arr)


def _connect(p: DriverParams):
    import canopen

    net = canopen.Network()
    if p.bus_interface == 'remote':
        net.connect(channel=p.bus_channel, interface='remote')
    else:
        net.connect(channel=p.bus_channel, interface=p.bus_interface)
    return net


def _remote_node(net, node_id: int, eds: str, od=None):
    import canopen

    if od is None:
        try:
            od = canopen.import_od(str(eds), node_id)
        except Exception as exc:  # noqa: BLE001 -- a malformed file: one line
            raise ConfigError(f'{eds}: not a readable EDS/DCF ({exc})') from None
    dcf_id = getattr(od, 'node_id', None)
    if str(eds).lower().endswith('.dcf') and dcf_id not in (None, node_id):
        raise ConfigError(f'{eds}: the DCF is for node {dcf_id}, node_id is {node_id}')
    node = canopen.RemoteNode(node_id, od)
    net.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = 1.0
    return node


class Lifeline(threading.Thread):
    """The driver's side of the drive's watchdog: its heartbeat (producer) or node guarding.

    Heartbeat: every ``period_s`` the frame 0x700 + ``master_id`` with state 5 (operational);
    node guarding: every ``period_s`` a remote frame 0x700 + the drive's id. Stops with the
    process (a SIGKILLed driver sends no more: the drive's consumer time runs out).
    """

    def __init__(self, net, cob: int, period_s: float, remote: bool) -> None:
        super().__init__(name='cia402-lifeline', daemon=True)
        self.net, self.cob, self.period_s, self.remote = net, cob, period_s, remote
        self.stop = threading.Event()
        self.sent = 0

    def run(self) -> None:
        """Send until :attr:`stop`; a bus error ends the thread (the drive then stops)."""
        while not self.stop.is_set():
            try:
                if self.remote:
                    self.net.send_message(self.cob, b'', remote=True)
                else:
                    self.net.send_message(self.cob, b'\x05')
                self.sent += 1
            except Exception:  # noqa: BLE001 -- the bus is gone: the drive's watchdog acts
                return
            self.stop.wait(self.period_s)


def _make_node() -> DriverNode:
    try:
        return DriverNode()
    except (ValueError, rclpy.exceptions.ParameterException) as exc:
        raise StartError(str(exc)) from None


def _disconnect(net) -> None:
    try:
        net.disconnect()
    except Exception:  # noqa: BLE001, S110 -- the bus is gone already
        pass


def _run(node: DriverNode, node_run: NodeRun) -> int:
    """Plan, open the bus, configure the drive, run the cycle; the exit code."""
    p = node.p

    def _stop() -> None:
        node.running = False

    node_run.on_stop(_stop)
    # the plan before the bus: a drive the driver cannot run is refused in one line
    from .device_file import PlanError, plan_text
    try:
        plan = p.plan()
    except (PlanError, ConfigError) as exc:
        raise StartError(str(exc)) from None
    node.publish_gap = plan.gap_source != 'topic'
    for line in plan_text(plan).splitlines():
        node.get_logger().info(line)
    try:
        net = _connect(p)
    except Exception as exc:  # noqa: BLE001 -- one line
        raise StartError(f'cannot open the CAN bus {p.bus_interface}:{p.bus_channel}: '
                         f'{exc}') from None
    node_run.defer(_disconnect, net)
    # the cycle thread at its priority, the CAN receive thread (python-can's notifier,
    # made by the connect above) and the middleware's one above: a TPDO is taken in as
    # soon as it arrives, whatever else runs (ladrc_contract/realtime.py)
    applied, warnings = apply_realtime(p.thread_priority, [], p.lock_memory)
    for text in warnings:
        node.get_logger().warning(text)
    fifo = any(a.startswith('SCHED_FIFO') for a in applied)
    services = ServiceThread(node.context, (node,))
    node_run.defer(services.close)
    services.start(p.thread_priority - 1 if fifo else 0)
    try:
        remote = _remote_node(net, plan.node_id, plan.eds_path)
        io = None
        if plan.io_node_id:
            io_node = _remote_node(net, plan.io_node_id, plan.device.gap.dcf, plan.io_od)
            io = (io_node.sdo, io_node.nmt)
        if plan.heartbeat_producer_ms:
            lifeline = Lifeline(net, 0x700 + plan.device.master_node_id,
                                plan.heartbeat_producer_ms * 1e-3, remote=False)
            node_run.defer(lifeline.stop.set)
            lifeline.start()
        node.config_line = configure(remote.sdo, remote.nmt, p, plan=plan, io=io)
        if plan.guard_time_ms:
            lifeline = Lifeline(net, 0x700 + plan.node_id, plan.guard_time_ms * 1e-3,
                                remote=True)
            node_run.defer(lifeline.stop.set)
            lifeline.start()
    except ConfigError as exc:
        raise StartError(str(exc)) from None
    node.get_logger().info(node.config_line)

    def send(cob_id: int, data: bytes) -> None:
        net.send_message(cob_id, data)

    master = Master(p, send, plan)
    for cob in master.frame_ids:
        net.subscribe(cob, lambda can_id, data, ts: master.on_frame(can_id, data))
    node.master = master
    try:
        if node.lockstep:
            if not node.wait_for_controller():
                if not node.running:
                    return 0
                print(f'driver_node: lock step: no controller within '
                      f'{p.wait_for_controller_s:g} s (commanding axis/velocity_command '
                      'and reading both samples)', file=sys.stderr)
                return 3
            node.run_lockstep(master)
        else:
            node.run_free(master)
    except DriverAbort as exc:
        print(f'driver_node: {exc}', file=sys.stderr)
        return 3
    return 0


def _quick_stop(node: DriverNode, _reason: str) -> None:
    """Print what the bus did over the run; leave the drive at rest (quick stop, disabled)."""
    master = node.master
    if master is None:  # the drive never ran
        return
    # one line for the logs and the benches: what the bus did over the run
    print('driver_node: ' + json.dumps({
        'cycles': master.cycles, 'late_tpdo_cycles': master.late_total,
        'missed_tpdo_cycles': master.missed_total, 'emcy_received': master.emcy_count,
        'samples_published': node.seq, 'late_cycles': node.late_cycles}), flush=True)
    try:
        master.send_rpdos(ds402.CW_QUICK_STOP, 0)
        master.send(mapping.SYNC_COB_ID, b'')
    except Exception:  # noqa: BLE001, S110 -- the bus is gone: the deadline stops it
        pass


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``ros2 run ladrc_cia402 driver_node --ros-args -p eds:=…``.

    Every path once the drive ran ends in a quick stop (:func:`_quick_stop`), the bus's
    figures printed on one line.
    """
    return run_node('driver_node', _make_node, _run, args=argv, zero=_quick_stop)


if __name__ == '__main__':
    sys.exit(main())
