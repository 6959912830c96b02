"""The sim node: the simulated Z axis as a drive on the ROS graph, in real time at 2 kHz.

It runs a scenario with the *same* headless runner (:func:`ladrc_sim.headless.runner.run`) and
the same models, or a cutting job (``-p job:=NAME``) with the *same* job runner
(:func:`ladrc_sim.job.runner.run_job`: the simulated CNC, the sheet in XY; :mod:`.job_drive`
sends the CNC's ``cnc/motion`` and its commands and reads the controller's answers on
``follow/status``): the "controller" the runner steps is a :class:`DriveBridge` that, at each
0.5 ms deadline, takes the velocity commands that arrived (straight from the reader, raw:
:mod:`ladrc_contract.loop_io`), publishes the tick's capacitive height, axis feedback and truth
(pre-serialized CDR), and returns the latest command (one tick of transport delay, as on a
fieldbus). The loop thread spins no executor: ``axis/reset_drive``, the scenario's follow
commands (service calls to the controller, as a CNC would send them) and /diagnostics are served
by a thread of their own (:mod:`ladrc_contract.service_thread`).

Like a drive, it stops the axis when commands stop: no command for longer than
``watchdog_timeout_s`` (default 5 ms, counted in the drive's own cycles) → quick stop (the axis
brakes at its maximum deceleration, not through its velocity lag) and a drive fault with a
readable reason, until commands are back for ``watchdog_recover_s``.

One commander (``ladrc_contract.commander_lock``): the drive executes the commands of one
commander only; the first foreign command quick-stops the axis and faults the drive with a
reason naming both senders, until ``axis/reset_drive`` (``ResetFault``). Every drive cycle
counts whose command it executed (``cycles_by_commander`` on /diagnostics and in the log at
the end).

At a scenario's end the controller is stopped before its inputs are
(:meth:`DriveBridge.wind_down`): ``stop_follow``, then a few steps with the world held at its
last tick, so the run ends with the controller IDLE and commanding zero, not with a stale-input
FAULT.

A sample is published only when the runner has a fresh one: during a ``sensor_dropout`` or
``encoder_dropout`` nothing is sent, as a driver sends nothing (seq counts published samples).

Lock step (``lockstep: true``, docs/follow-node.md "Lock step"): step k publishes its samples
and ``sim/lockstep`` k, stamped with the sim's time k·h_s, and steps the plant only when the
command answering k (``sample_seq`` k) has arrived; a scenario's follow command is answered by
the controller before the step's samples go out. Reliable traffic; no drive watchdog (the plant
cannot move without the answer); no answer within ``lockstep_timeout_s`` of wall time ends the
run with one line and exit code 3. It is the headless runner's convention: command k acts at
step k, no transport delay (a live run acts one tick later).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
import sys
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from ladrc_contract import qos
from ladrc_contract.cdr import CdrPacker, Outgoing
from ladrc_contract.commander_lock import describe
from ladrc_contract.loop_io import LoopNode
from ladrc_contract.node_entry import NodeRun, StartError, run_node
from ladrc_contract.qos import to_rclpy, wait_acknowledged
from ladrc_contract.realtime import apply_realtime
from ladrc_contract.service_thread import ServiceThread
from ladrc_contract.services import FOLLOW_SERVICES, fill_request, service_class
from ladrc_contract.topics import (
    CNC_JOB_TOPIC,
    CNC_LOCKSTEP_TOPIC,
    CNC_MOTION_TOPIC,
    COMMAND_TOPIC,
    DIAGNOSTICS_TOPIC,
    FEEDBACK_TOPIC,
    GAP_TOPIC,
    LOCKSTEP_TOPIC,
    SCENARIO_TOPIC,
    STATUS_TOPIC,
    TRUTH_TOPIC,
)
from ladrc_msgs.msg import (
    AxisFeedback,
    CapacitiveHeight,
    CncMotion,
    FollowStatus,
    LockStep,
    SimTruth,
    VelocityCommand,
)
from ladrc_msgs.srv import ResetFault
from rclpy.clock import Clock, ClockType
from std_msgs.msg import String

from ..headless.runner import run
from ..headless.scenario import (
    ScenarioError,
    list_scenarios,
    load_scenario,
)
from ..job.cnc import COMMANDS as CNC_COMMANDS
from ..job.jobfile import JobError, find_job, run_text
from ..job.runner import run_job
from ..models.sensor import oscillator_hz_scalar
from .drive_bridge import COMMAND_FIELDS, DriveBridge, LockstepAbort, StopSimulation
from .job_drive import JobDrive
from .remote_cnc import RemoteCnc


class SimNode(LoopNode):
    """Publishes the simulated axis; subscribes to velocity commands; plays a scenario."""

    def __init__(self) -> None:
        super().__init__('ladrc_sim')
        self.declare_parameter('scenario', 'showcase')
        # a cutting job instead of a scenario: a shipped job's name or a job file (YAML)
        self.declare_parameter('job', '')
        # a job's CNC is the CNC node (or a bridge to a real CNC): XY, beam and the contours cut
        # come from cnc/motion (remote_cnc.py), the commands from it to the controller
        self.declare_parameter('separate_cnc', False)
        # a job's figures (job/runner.py job_figures, with wall_s and realtime_x) as JSON here
        self.declare_parameter('figures_file', '')
        self.declare_parameter('exit_at_end', True)
        self.declare_parameter('realtime', True)
        self.declare_parameter('watchdog_timeout_s', 0.005)
        self.declare_parameter('watchdog_recover_s', 0.1)
        self.declare_parameter('wait_for_controller_s', 10.0)
        # With a recorder: wait until it subscribes to sim/truth, then let discovery settle
        # (start_delay_s), so the bag holds the scenario from its first tick.
        self.declare_parameter('wait_for_recorder_s', 0.0)
        self.declare_parameter('start_delay_s', 0.0)
        self.declare_parameter('frame_id', 'z_axis')
        # raw_only: publish the oscillator frequency only (gap_mm NaN), as a driver that
        # leaves the raw -> gap table to the controller (docs/calibration.md)
        self.declare_parameter('raw_only', False)
        # real-time settings of the loop, as the follow node's (ladrc_contract/realtime.py)
        self.declare_parameter('thread_priority', 50)
        self.declare_parameter('cpu', -1)
        self.declare_parameter('lock_memory', True)
        # lock step (module docstring): the sim waits for each answer, its clock is the step
        self.declare_parameter('lockstep', False)
        self.declare_parameter('lockstep_timeout_s', 10.0)
        # the drive: '' = on ROS (this node publishes the axis topics), 'cia402' = the emulated
        # CiA 402 drive on a CAN bus (can_bridge.py), mastered by a driver node
        self.declare_parameter('drive', '')
        self.declare_parameter('can_bus', 'ws://127.0.0.1:54701/')
        self.declare_parameter('can_node_id', 5)
        self.declare_parameter('can_eds', '')
        self.declare_parameter('can_device', '')  # the drive's device file (default: shipped)
        self.drive_kind = str(self.get_parameter('drive').value)
        if self.drive_kind not in ('', 'cia402'):
            raise ValueError(f"drive {self.drive_kind!r}: '' (ROS) or 'cia402'")
        on_ros = self.drive_kind == ''
        self.lockstep = bool(self.get_parameter('lockstep').value)
        self.lockstep_timeout_s = float(self.get_parameter('lockstep_timeout_s').value)
        if not self.lockstep_timeout_s > 0:
            raise ValueError('lockstep_timeout_s must be > 0')
        job = str(self.get_parameter('job').value)
        self.job = find_job(job) if job else None
        self.scenario = None if self.job else load_scenario(self.get_parameter('scenario').value)
        self.run_name = self.job.name if self.job else self.scenario.name
        self.sensor = self.job.sensor if self.job else self.scenario.sensor
        # the drive's period: a scenario runs at it (a job at the job world's 0.5 ms); the
        # emulated CiA 402 drive's SYNC period (0x1006) must equal it
        self.declare_parameter('h_s', 0.0005)
        self.h_s = float(self.get_parameter('h_s').value)
        if not 1e-4 <= self.h_s <= 0.01:
            raise ValueError(f'h_s {self.h_s:g}: must be in [0.0001, 0.01] s')
        if self.job is not None and abs(self.h_s - 0.0005) > 1e-12:
            raise ValueError("h_s: a job runs at 0.0005 s (the job world's period)")
        self.watchdog_timeout_s = float(self.get_parameter('watchdog_timeout_s').value)
        self.watchdog_recover_s = float(self.get_parameter('watchdog_recover_s').value)
        if not self.watchdog_timeout_s > 0:
            raise ValueError('watchdog_timeout_s must be > 0')
        self.frame_id = self.get_parameter('frame_id').value
        self.raw_only = bool(self.get_parameter('raw_only').value)
        high_rate = to_rclpy(qos.LOCKSTEP_HIGH_RATE if self.lockstep else qos.HIGH_RATE)
        self.pub_gap = (self.create_publisher(CapacitiveHeight, GAP_TOPIC, high_rate)
                        if on_ros else None)
        self.pub_fb = (self.create_publisher(AxisFeedback, FEEDBACK_TOPIC, high_rate)
                       if on_ros else None)
        self.pub_truth = self.create_publisher(SimTruth, TRUTH_TOPIC, high_rate)
        self.pub_step = (self.create_publisher(LockStep, LOCKSTEP_TOPIC, high_rate)
                         if self.lockstep else None)
        # a job: the CNC's motion out, the controller's answers in (job_drive.py); with a
        # separate CNC its motion, lock steps and end in (remote_cnc.py)
        self.separate_cnc = bool(self.job) and bool(self.get_parameter('separate_cnc').value)
        self.pub_cnc = (self.create_publisher(CncMotion, CNC_MOTION_TOPIC, high_rate)
                        if self.job and not self.separate_cnc else None)
        command_in = to_rclpy(qos.LOCKSTEP_COMMAND_INPUT if self.lockstep
                              else qos.CONTROL_INPUT)
        self.cnc_reader = (self.create_loop_reader(CncMotion, CNC_MOTION_TOPIC, command_in)
                           if self.separate_cnc else None)
        self.cnc_step_reader = (self.create_loop_reader(LockStep, CNC_LOCKSTEP_TOPIC, command_in)
                                if self.separate_cnc and self.lockstep else None)
        self.cnc_job_reader = (self.create_loop_reader(String, CNC_JOB_TOPIC,
                                                       to_rclpy(qos.RUN_TEXT))
                               if self.separate_cnc else None)
        self.status_reader = (self.create_loop_reader(
            FollowStatus, STATUS_TOPIC,
            to_rclpy(qos.LOCKSTEP_COMMAND_INPUT if self.lockstep else qos.CONTROL_INPUT))
            if self.job else None)
        self.cnc_seq, self.cnc_fresh = 0, False  # LockStep.cnc_seq / cnc_fresh of the step
        self.pub_diag = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC,
                                              to_rclpy(qos.DIAGNOSTICS))
        # The scenario text, latched: a recorder puts it into the bag (self-describing runs).
        self.pub_scenario = self.create_publisher(String, SCENARIO_TOPIC,
                                                  to_rclpy(qos.RUN_TEXT))
        self.pub_scenario.publish(String(data=self.scenario_text()))
        self.follow_clients = {name: self.create_client(service_class(srv), service)
                               for name, (srv, service, _) in FOLLOW_SERVICES.items()}
        self.bridge: DriveBridge | None = None
        # the drive's command input, taken from by the loop thread (DriveBridge.take_commands)
        self.cmd_reader = self.create_loop_reader(
            VelocityCommand, COMMAND_TOPIC,
            to_rclpy(qos.LOCKSTEP_COMMAND_INPUT if self.lockstep else qos.DRIVE_COMMAND_INPUT)
        ) if on_ros else None
        self.cmd_cdr = CdrPacker('ladrc_msgs/msg/VelocityCommand')
        self.cmd_fields = [self.cmd_cdr.index[n] for n in COMMAND_FIELDS]
        # what the loop publishes: pre-serialized CDR from one value list per message
        self._out = {name: Outgoing(f'ladrc_msgs/msg/{name}', frame)
                     for name, frame in (('CapacitiveHeight', self.frame_id),
                                         ('AxisFeedback', self.frame_id),
                                         ('SimTruth', self.frame_id), ('LockStep', ''),
                                         ('CncMotion', 'machine'))}
        self.gap_seq = 0  # seq of the newest capacitive sample (LockStep.gap_seq)
        self.enc_seq = 0
        self.create_timer(1.0, self._publish_diagnostics,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

    def scenario_text(self) -> str:
        """YAML text of the scenario being played (its file as written), or of the job."""
        if self.job is not None:
            return run_text(self.job)
        source = getattr(self.scenario, 'source', '') or ''
        shipped = {q.stem: q for q in list_scenarios()}
        for path in (Path(source), shipped.get(source)):
            if path is not None and path.is_file():
                return path.read_text(encoding='utf-8')
        return f'name: {self.scenario.name}\n'

    def attach(self, bridge: DriveBridge) -> None:
        """Wire the bridge's command callback and the drive's reset."""
        self.bridge = bridge
        self.create_service(ResetFault, 'axis/reset_drive', self._srv_reset_drive)

    def _srv_reset_drive(self, request, response):
        """Clear the commander fault (the explicit reset) and the watchdog's (next commander)."""
        b = self.bridge
        with b.mutex:
            was = b.lock.reset()
            b.fault_reason = ''
        response.accepted = True
        response.message = f'drive reset ({was or "no commander fault"})'
        self.get_logger().info(response.message)
        return response

    def commander_summary(self) -> dict:
        """Return the drive's record of its commands' sources (cycles executed, refused)."""
        b = self.bridge
        out = b.lock.summary()
        out['cycles_executed'] = {describe(k): v for k, v in b.cycles_by_commander.items()}
        return out

    def send_follow_command(self, name: str, args: dict[str, Any]):
        """Call the controller's service for a scenario follow command; return the future."""
        future = self.follow_clients[name].call_async(fill_request(name, args))
        future.add_done_callback(lambda f, n=name: self._command_done(n, f))
        return future

    def _command_done(self, name: str, future) -> None:
        result = future.result()
        if result is not None and not result.accepted:
            self.get_logger().warning(f'{name} rejected by the controller: {result.message}')

    def publish_samples(self, seq: int, tick, fault: bool, reason: str, truth: tuple,
                        stamp_ns: int | None = None) -> None:
        """Publish one step's capacitive height and axis feedback (when fresh) and truth.

        A sample is fresh when the runner took it at this step (its stamp is the step's
        time); a held one (dropout) is not sent. ``seq`` is the step; each topic's own seq
        counts its published samples. Lock step: then ``sim/lockstep``, all stamped
        ``stamp_ns`` (the sim's time). The samples go out back to back (a reader's
        middleware thread takes them in one wake-up).
        """
        # header stamps: the node clock (ROS time: system clock, or /clock with use_sim_time)
        if stamp_ns is None:
            stamp_ns = self.get_clock().now().nanoseconds
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        bridge = self.bridge
        out = self._out
        gap_fresh = tick.gap_stamp_s == tick.t_s
        enc_fresh = tick.encoder_stamp_s == tick.t_s
        if gap_fresh:
            self.gap_seq = bridge.gap_seq
            bridge.gap_seq += 1
        if enc_fresh:
            self.enc_seq = bridge.enc_seq
            bridge.enc_seq += 1
        reading = float(tick.gap_mm)
        # the raw value behind the reading: the sensor model's oscillator (docs/simulator.md),
        # falls as the capacitance rises (as the nozzle approaches)
        gap = out['CapacitiveHeight'].pack(
            sec, nsec, seq=self.gap_seq, gap_mm=math.nan if self.raw_only else reading,
            raw_hz=oscillator_hz_scalar(reading, self.sensor),
            valid=bool(tick.gap_valid),
            status=int(getattr(tick, 'gap_status', 0 if tick.gap_valid else 1)))
        dt = tick.t_s - bridge._prev_t
        # differentiated since the last published sample: over the drive's cycle, as the
        # headless bag writer does, or over the silent cycles caught up before it
        velocity = 0.0
        if dt > 0 and math.isfinite(bridge._prev_enc):  # (dt NaN: the first sample)
            cycles = max(1, round(dt / self.h_s))  # times h_s: bit for bit with headless
            velocity = (tick.encoder_mm - bridge._prev_enc) / (cycles * self.h_s)
        bridge._prev_enc, bridge._prev_t = tick.encoder_mm, tick.t_s
        fb = out['AxisFeedback'].pack(
            sec, nsec, seq=self.enc_seq, position_mm=float(tick.encoder_mm),
            velocity_mm_s=velocity, drive_enabled=bool(tick.drive_enabled), drive_fault=fault,
            fault_reason=reason)
        if gap_fresh:
            self.pub_gap.publish(gap)
        if enc_fresh:
            self.pub_fb.publish(fb)
        if self.pub_step is not None:
            # the step goes out before the truth: the controller computes while the sim
            # publishes what only the recorder reads
            self.pub_step.publish(out['LockStep'].pack(
                sec, nsec, step=seq, gap_seq=self.gap_seq, gap_fresh=gap_fresh,
                encoder_seq=self.enc_seq, encoder_fresh=enc_fresh, cnc_seq=self.cnc_seq,
                cnc_fresh=self.cnc_fresh))
        self.cnc_fresh = False
        true_gap, sheet, nozzle, coverage, plate_velocity = (float(v) for v in truth[:5])
        # seq: truth messages published (the step in lock step; silent cycles send none)
        self.pub_truth.publish(out['SimTruth'].pack(
            sec, nsec, seq=bridge.truth_seq, true_gap_mm=true_gap, sheet_mm=sheet,
            nozzle_mm=nozzle, edge_coverage=coverage, plate_velocity_mm_s=plate_velocity,
            collision=bool(true_gap <= 0.0), x_mm=float(truth[6]), y_mm=float(truth[7])))
        bridge.truth_seq += 1

    def publish_step_truth(self, seq: int, tick, truth: tuple, stamp_ns: int | None = None
                           ) -> None:
        """Publish step ``seq``'s lock step and truth only: the drive is on a CAN bus.

        The driver publishes one sample pair per SYNC (``seq`` = the step), both fresh.
        """
        if stamp_ns is None:
            stamp_ns = self.get_clock().now().nanoseconds
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        out = self._out
        if self.pub_step is not None:
            self.pub_step.publish(out['LockStep'].pack(
                sec, nsec, step=seq, gap_seq=seq, gap_fresh=True, encoder_seq=seq,
                encoder_fresh=True, cnc_seq=self.cnc_seq, cnc_fresh=self.cnc_fresh))
        self.cnc_fresh = False
        true_gap, sheet, nozzle, coverage, plate_velocity = (float(v) for v in truth[:5])
        bridge = self.bridge
        self.pub_truth.publish(out['SimTruth'].pack(
            sec, nsec, seq=bridge.truth_seq, true_gap_mm=true_gap, sheet_mm=sheet,
            nozzle_mm=nozzle, edge_coverage=coverage, plate_velocity_mm_s=plate_velocity,
            collision=bool(true_gap <= 0.0), x_mm=float(truth[6]), y_mm=float(truth[7])))
        bridge.truth_seq += 1

    def publish_cnc(self, cnc, x_mm: float, y_mm: float) -> None:
        """Publish the CNC's motion sample of this tick (``CncInput``) on ``cnc/motion``.

        Stamped with the node clock; lock step: with the sim's time of the CNC's cycle (its
        ``stamp_s``, whole periods), and named in the step's ``LockStep`` (the controller's
        tick waits for it).
        """
        if self.lockstep:
            stamp_ns = round(cnc.stamp_s / self.h_s) * self.bridge.period_ns
            self.cnc_seq, self.cnc_fresh = cnc.seq, True
        else:
            stamp_ns = self.get_clock().now().nanoseconds
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        self.pub_cnc.publish(self._out['CncMotion'].pack(
            sec, nsec, seq=cnc.seq, x_mm=float(x_mm), y_mm=float(y_mm),
            commanded_feed_mm_s=float(cnc.commanded_feed_mm_s),
            actual_feed_mm_s=float(cnc.actual_feed_mm_s), segment=int(cnc.segment),
            beam_on=bool(cnc.beam_on), contour=int(cnc.contour),
            segment_left_mm=float(cnc.segment_left_mm), edge_ahead_mm=float(cnc.edge_ahead_mm)))

    def wait_for_controller(self, timeout_s: float) -> bool:
        """Wait until the controller's follow services are up (so no command is lost)."""
        needed = (set() if self.separate_cnc else set(CNC_COMMANDS) if self.job is not None else
                  {e.name for e in self.scenario.timeline if e.name in FOLLOW_SERVICES})
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if all(self.follow_clients[n].service_is_ready() for n in needed) and (
                    not self.lockstep or self.lockstep_matched()):
                return True
            time.sleep(0.05)  # the service thread serves the graph meanwhile
        return not needed and not self.lockstep

    def lockstep_matched(self) -> bool:
        """Lock step: a controller reads the samples and the steps, and commands."""
        drive_ok = (self.drive_kind == 'cia402'  # the driver waits for the controller itself
                    or (self.pub_gap.get_subscription_count() > 0
                        and self.pub_fb.get_subscription_count() > 0
                        and self.count_publishers(self.cmd_reader.topic_name) > 0))
        return (self.pub_step.get_subscription_count() > 0 and drive_ok
                and (self.job is None or self.count_publishers(STATUS_TOPIC) > 0)
                and (self.pub_cnc is None or self.pub_cnc.get_subscription_count() > 0)
                and (not self.separate_cnc
                     or (self.count_publishers(CNC_MOTION_TOPIC) > 0
                         and self.count_publishers(CNC_LOCKSTEP_TOPIC) > 0)))

    def wait_for_recorder(self, timeout_s: float) -> bool:
        """Wait until something (the recorder) subscribes to sim/truth."""
        deadline = time.monotonic() + timeout_s
        while self.pub_truth.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        return self.pub_truth.get_subscription_count() > 0

    def _publish_diagnostics(self) -> None:
        b = self.bridge
        if b is None:
            return
        periods = sorted(b.periods_us[-2000:]) or [0.0]
        b.periods_us = b.periods_us[-2000:]
        p99 = periods[min(len(periods) - 1, int(0.99 * len(periods)))]
        # diagnostic_updater's naming: the node's fully qualified name, then the task
        st = DiagnosticStatus(name=f'{self.get_fully_qualified_name().lstrip("/")}: drive',
                              hardware_id='z_axis_sim')
        reason = b.lock.fault_reason or b.fault_reason
        st.level = DiagnosticStatus.ERROR if reason else DiagnosticStatus.OK
        st.message = reason or 'running'
        values = {'seq': b.seq, 'period_p99_us': round(p99, 1), 'late_ticks': b.late_ticks,
                  'commands_received': b.cmd_count, 'watchdog_trips': b.watchdog_trips,
                  'scenario': self.run_name,
                  'commander': describe(b.lock.owner) if b.lock.owner else '',
                  'commanders': json.dumps(self.commander_summary())}
        st.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(arr)


def write_figures(path: str, figures: dict) -> None:
    """Write a job's figures as JSON to ``path`` (whole or not at all); '' writes nothing."""
    if not path:
        return
    tmp = Path(f'{path}.part')
    tmp.write_text(json.dumps(figures, default=str) + '\n', encoding='utf-8')
    tmp.replace(path)


def _can_bridge(node: SimNode, realtime: bool):
    """Return the emulated CiA 402 drive on the node's CAN bus (can_bridge.py), booted."""
    from ..cia402.can_drive import CanDrive, connect
    from .can_bridge import CanDriveBridge

    network = connect(str(node.get_parameter('can_bus').value))
    eds = str(node.get_parameter('can_eds').value) or None
    device = str(node.get_parameter('can_device').value) or None
    node_id = None if device else int(node.get_parameter('can_node_id').value)
    drive = CanDrive(network, node_id, None if device else eds,
                     lockstep=node.lockstep, lockstep_timeout_s=node.lockstep_timeout_s,
                     h_s=node.h_s, device=device)
    drive.boot()
    node.network = network
    return CanDriveBridge(node, drive, realtime)


def _make_node() -> SimNode:
    try:
        return SimNode()
    except (ScenarioError, JobError, ValueError) as exc:
        raise StartError(str(exc)) from None


def _disconnect(network) -> None:
    try:
        network.disconnect()
    except Exception:  # noqa: BLE001, S110 -- the bus is gone already
        pass


def _run(node: SimNode, node_run: NodeRun) -> int:
    """Attach the drive, start the services, play the scenario or the job; the exit code."""
    realtime = bool(node.get_parameter('realtime').value)
    bridge = None
    if node.drive_kind == 'cia402':
        # the bus first: its receive thread (python-can's notifier) is then scheduled as
        # the middleware's, one above the loop (it answers each SYNC)
        try:
            bridge = _can_bridge(node, realtime)
        except (ValueError, OSError) as exc:
            raise StartError(f'CiA 402 drive: {exc}') from None
        finally:
            if getattr(node, 'network', None) is not None:
                node_run.defer(_disconnect, node.network)
    cpu = int(node.get_parameter('cpu').value)
    # lock step: no SCHED_FIFO (ladrc_follow's follow_node._run says why)
    priority = 0 if node.lockstep else int(node.get_parameter('thread_priority').value)
    applied, warnings = apply_realtime(priority, [cpu] if cpu >= 0 else [],
                                       bool(node.get_parameter('lock_memory').value))
    for text in warnings:
        node.get_logger().warning(text)
    if bridge is None:
        bridge = DriveBridge(node, realtime)
    node.attach(bridge)
    # services, the scenario's service calls and /diagnostics: a thread of their own, one
    # below a real-time loop (ladrc_contract.service_thread)
    services = ServiceThread(node.context, (node,))
    fifo = any(a.startswith('SCHED_FIFO') for a in applied)
    node_run.defer(services.close)
    services.start(priority - 1 if fifo else 0)

    def _stop() -> None:
        bridge.running = False

    node_run.on_stop(_stop)
    wait_s = float(node.get_parameter('wait_for_controller_s').value)
    if not node.wait_for_controller(max(wait_s, node.lockstep_timeout_s)
                                    if node.lockstep else wait_s):
        if node.lockstep:
            print(f'sim_node: lock step: no controller in lock step within '
                  f'{max(wait_s, node.lockstep_timeout_s):g} s (a follow node with loop '
                  "'lockstep' subscribing to sim/lockstep and commanding the axis)",
                  file=sys.stderr)
            return 3
        node.get_logger().warning('controller services not found: playing the scenario '
                                  'anyway (its follow commands may be lost)')
    wait_rec = float(node.get_parameter('wait_for_recorder_s').value)
    if wait_rec > 0 and not node.wait_for_recorder(wait_rec):
        node.get_logger().warning('no recorder subscribed to sim/truth: playing anyway')
    settle = time.monotonic() + float(node.get_parameter('start_delay_s').value)
    while time.monotonic() < settle:
        time.sleep(0.05)
    try:
        if node.job is not None:
            node.get_logger().info(f'job {node.job.name}: '
                                   f'{len(node.job.program().contours)} contours')
            job = (run_job(node.job, JobDrive(node, bridge, remote_cnc=True),
                           cnc=RemoteCnc(node, bridge)) if node.separate_cnc
                   else run_job(node.job, JobDrive(node, bridge)))
            figures = {**job.figures, 'wall_s': round(job.wall_s, 3), 'realtime_x': round(
                job.figures['job_time_s'] / max(job.wall_s, 1e-9), 3)}
            node.get_logger().info(f'job done: {json.dumps(figures, default=str)}')
            write_figures(str(node.get_parameter('figures_file').value), figures)
        else:
            node.get_logger().info(f'scenario {node.scenario.name}: '
                                   f'{node.scenario.duration_s} s')
            # the runner calls bridge.wind_down() after the last tick (the controller stops
            # before its inputs do)
            result = run(node.scenario, bridge, h_s=node.h_s)
            node.get_logger().info(f'scenario done: collisions={result.metrics.collisions}')
            if bridge.wind_down_problem:
                node.get_logger().warning(f'wind-down: {bridge.wind_down_problem}')
    except StopSimulation:
        pass
    except LockstepAbort as exc:
        print(f'sim_node: {exc}', file=sys.stderr)
        return 3
    if node.lockstep:
        # reliable writers repair only while they exist: the readers (the recorder, which
        # may lag on a loaded machine) get every message before this node goes down
        late = wait_acknowledged(tuple(p for p in (node.pub_gap, node.pub_fb, node.pub_step,
                                                   node.pub_truth, node.pub_cnc)
                                       if p is not None), node.lockstep_timeout_s)
        if late:
            node.get_logger().warning(
                f'lock step: messages on {", ".join(late)} not acknowledged by every '
                f'reader within {node.lockstep_timeout_s:g} s (a reader gone?)')
    node.get_logger().info(f'commands by source: {json.dumps(node.commander_summary())}')
    if bridge.running and not node.get_parameter('exit_at_end').value:
        while bridge.running:
            bridge.take_commands()
            time.sleep(0.1)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``ros2 run ladrc_sim sim_node --ros-args -p scenario:=showcase``.

    The sim is the plant: it has no command of its own to zero (the axis stops with its
    controller's zero command, or on the drive's watchdog).
    """
    return run_node('sim_node', _make_node, _run, args=argv)


if __name__ == '__main__':
    sys.exit(main())
