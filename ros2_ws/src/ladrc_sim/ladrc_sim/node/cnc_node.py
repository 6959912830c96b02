"""The CNC node: the simulated laser CNC of a cutting job as a node of its own.

``ros2 run ladrc_sim cnc_node --ros-args -p job:=plate_holes`` runs the job's part program
(:class:`ladrc_sim.job.cnc_station.CncStation`: the CNC and its own model of the sheet) against
the height controller over the CNC interface (docs/interfaces.md, "CNC interface"): it
publishes ``cnc/motion`` at its cycle (XY, segment, beam, contour, feeds, distance to the
segment's end and to the first void ahead), sends its commands to the follow services and reads
the answers on ``follow/status``. The sim node with ``separate_cnc`` takes the nozzle's XY, the
beam and the contours cut from ``cnc/motion`` (:mod:`.remote_cnc`). A bridge to a real CNC
takes this node's place: it speaks the same topics and services (docs/job-world.md, "A separate
CNC").

When the job has ended (finished, or aborted with its reason; the run's end rule of
:class:`ladrc_sim.job.runner.JobEnd`), it publishes its log as JSON on ``cnc/job`` (latched),
prints it as its last line and exits (``exit_at_end``).

Live: a deadline loop at the CNC's cycle (``cycle_ticks`` controller ticks; the program steps
tick by tick inside it), starting once the controller's status shows a sensor sample (the axis
is up); the newest status; commands sent without waiting. Lock step (``lockstep: true``): step
k waits for the status answering k - 1, steps, and publishes ``cnc/lockstep`` k naming its
sample; the sim's step k waits for that (docs/follow-node.md, "Lock step"): equal to
``ladrc job --separate-cnc`` bit for bit.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

from ladrc_contract import qos
from ladrc_contract.cdr import CdrPacker
from ladrc_contract.loop_io import LoopNode, SampleWait
from ladrc_contract.node_entry import NodeRun, StartError, run_node
from ladrc_contract.qos import to_rclpy, wait_acknowledged
from ladrc_contract.realtime import apply_realtime
from ladrc_contract.service_thread import ServiceThread
from ladrc_contract.services import FOLLOW_SERVICES, fill_request, service_class
from ladrc_contract.topics import (
    CNC_JOB_TOPIC,
    CNC_LOCKSTEP_TOPIC,
    CNC_MOTION_TOPIC,
    STATUS_TOPIC,
)
from ladrc_msgs.msg import CncMotion, FollowStatus, LockStep
from std_msgs.msg import String

from ..job.cnc import COMMANDS
from ..job.cnc_station import CncStation
from ..job.jobfile import JobError, find_job
from ..job.runner import JobEnd
from ..models.axis import H_S
from .follow_link import FollowLink
from .remote_cnc import log_to_json


class LockstepTimeout(Exception):
    """Lock step: an answer did not come within ``lockstep_timeout_s`` (one line)."""


class CncNode(LoopNode):
    """Runs a job's part program against the height controller (module docstring)."""

    def __init__(self) -> None:
        super().__init__('ladrc_cnc')
        self.declare_parameter('job', '')
        self.declare_parameter('lockstep', False)
        self.declare_parameter('lockstep_timeout_s', 10.0)
        self.declare_parameter('wait_for_controller_s', 30.0)
        self.declare_parameter('exit_at_end', True)
        self.declare_parameter('thread_priority', 50)
        self.declare_parameter('lock_memory', True)
        name = str(self.get_parameter('job').value)
        if not name:
            raise JobError("no job given (-p job:=NAME: a shipped job's name or a job file)")
        self.job = find_job(name)
        self.program = self.job.program()
        self.lockstep = bool(self.get_parameter('lockstep').value)
        self.timeout_ns = int(float(self.get_parameter('lockstep_timeout_s').value) * 1e9)
        if not self.timeout_ns > 0:
            raise ValueError('lockstep_timeout_s must be > 0')
        self.running = True
        high_rate = to_rclpy(qos.LOCKSTEP_HIGH_RATE if self.lockstep else qos.HIGH_RATE)
        self.pub_motion = self.create_publisher(CncMotion, CNC_MOTION_TOPIC, high_rate)
        self.pub_step = (self.create_publisher(LockStep, CNC_LOCKSTEP_TOPIC, high_rate)
                         if self.lockstep else None)
        self.pub_job = self.create_publisher(String, CNC_JOB_TOPIC, to_rclpy(qos.RUN_TEXT))
        self.status_reader = self.create_loop_reader(
            FollowStatus, STATUS_TOPIC,
            to_rclpy(qos.LOCKSTEP_COMMAND_INPUT if self.lockstep else qos.CONTROL_INPUT))
        self.follow_clients = {name: self.create_client(service_class(FOLLOW_SERVICES[name][0]),
                                                        FOLLOW_SERVICES[name][1])
                               for name in COMMANDS}
        self._wait = SampleWait(self.context, (self.status_reader,))
        self._motion = CdrPacker('ladrc_msgs/msg/CncMotion')
        self._motion_values = self._motion.defaults()
        self._motion_values[self._motion.index['header.frame_id']] = 'machine'
        self._step = CdrPacker('ladrc_msgs/msg/LockStep')
        self._step_values = self._step.defaults()
        self.link = FollowLink(self, self.lockstep, self.wait)
        self.station = CncStation(self.job, self.program, self.link.command, H_S)
        self.period_ns = int(round(H_S * 1e9))

    # ---- the wire ---------------------------------------------------------------------------
    def send_follow_command(self, name: str, args: dict[str, Any]):
        """Call the controller's service for a CNC command; return the future."""
        return self.follow_clients[name].call_async(fill_request(name, args))

    def wait(self, condition, what: str) -> None:
        """Wait until ``condition()`` (wall clock ``lockstep_timeout_s`` at most)."""
        limit = time.monotonic_ns() + self.timeout_ns
        while not condition():
            if not self.running:
                raise KeyboardInterrupt
            now = time.monotonic_ns()
            if now > limit:
                raise LockstepTimeout(f'{what} within {self.timeout_ns * 1e-9:g} s (wall clock)')
            self._wait.wait(min(limit - now, 2_000_000))

    def publish_sample(self, sample: Any, stamp_ns: int) -> None:
        """Publish the CNC's motion sample (``CncInput``) with the CNC's XY now."""
        values, index = self._motion_values, self._motion.index
        values[0], values[1] = divmod(stamp_ns, 1_000_000_000)
        x, y = self.station.xy
        for name, value in (('seq', sample.seq), ('x_mm', float(x)), ('y_mm', float(y)),
                            ('commanded_feed_mm_s', float(sample.commanded_feed_mm_s)),
                            ('actual_feed_mm_s', float(sample.actual_feed_mm_s)),
                            ('segment', int(sample.segment)), ('beam_on', bool(sample.beam_on)),
                            ('contour', int(sample.contour)),
                            ('segment_left_mm', float(sample.segment_left_mm)),
                            ('edge_ahead_mm', float(sample.edge_ahead_mm))):
            values[index[name]] = value
        self.pub_motion.publish(self._motion.pack(values))

    def publish_step(self, step: int, cnc_seq: int, fresh: bool) -> None:
        """Lock step: step ``step`` is done; its sample (if ``fresh``) is ``cnc_seq``."""
        values, index = self._step_values, self._step.index
        values[0], values[1] = divmod(step * self.period_ns, 1_000_000_000)
        values[index['step']], values[index['cnc_seq']] = step, cnc_seq
        values[index['cnc_fresh']] = fresh
        self.pub_step.publish(self._step.pack(values))

    def ready(self) -> bool:
        """Return whether the controller's services are up and (lock step) every reader matched."""
        if not all(c.service_is_ready() for c in self.follow_clients.values()):
            return False
        if self.count_publishers(STATUS_TOPIC) == 0:
            return False
        if self.lockstep:  # the controller and the sim read the motion, the sim the steps
            return (self.pub_motion.get_subscription_count() >= 2
                    and self.pub_step.get_subscription_count() >= 1)
        return True

    # ---- the job ------------------------------------------------------------------------------
    def run_lockstep(self, budget: int) -> None:
        """Lock step (module docstring)."""
        station, link, end = self.station, self.link, JobEnd()
        seq = 0
        for k in range(budget):
            if k > 0:
                link.await_status(k - 1)
                if end.done(k - 1, station.log, link.answers):
                    return
            sample = station.step(link.answers)
            if sample is not None:  # stamped with its own time, whole periods (the sim's)
                seq = sample.seq
                self.publish_sample(sample, round(sample.stamp_s / H_S) * self.period_ns)
            self.publish_step(k, seq, sample is not None)
        self._out_of_budget()

    def run_live(self, budget: int) -> None:
        """Live: a deadline loop at the CNC's cycle (module docstring)."""
        station, link, end = self.station, self.link, JobEnd()
        cycle = max(1, int(self.job.cnc.cycle_ticks))
        period = cycle * self.period_ns
        start = time.monotonic_ns()
        k = 0
        while k < budget:
            deadline = start + (k // cycle) * period
            now = time.monotonic_ns()
            if now < deadline:
                time.sleep((deadline - now) * 1e-9)
            if not self.running:
                raise KeyboardInterrupt
            link.take_status()
            for name, message in link.refusals():
                station.refused(name, message)
            for _ in range(cycle):  # the program steps tick by tick
                sample = station.step(link.answers)
                if sample is not None:
                    self.publish_sample(sample, self.get_clock().now().nanoseconds)
                if end.done(k, station.log, link.answers):
                    return
                k += 1
        self._out_of_budget()

    def _out_of_budget(self) -> None:
        log = self.station.log
        if not log.finished and not log.aborted:
            log.aborted = f'not done within its time budget ({self._budget_s:g} s)'

    def run(self) -> None:
        """Run the job to its end."""
        self._budget_s = self.job.time_budget_s(self.program)
        budget = int(self._budget_s / H_S)
        if self.lockstep:
            self.run_lockstep(budget)
        else:
            self.run_live(budget)

    def publish_log(self) -> str:
        """Publish the CNC's log on ``cnc/job`` (latched); return its JSON."""
        text = log_to_json(self.station.log)
        self.pub_job.publish(String(data=text))
        return text


def _make_node() -> CncNode:
    try:
        return CncNode()
    except (JobError, ValueError) as exc:
        raise StartError(str(exc)) from None


def _run(node: CncNode, node_run: NodeRun) -> int:
    """Wait for the height controller, run the job, publish and print its log; the exit code."""
    priority = 0 if node.lockstep else int(node.get_parameter('thread_priority').value)
    _, warnings = apply_realtime(priority, [], bool(node.get_parameter('lock_memory').value))
    for text in warnings:
        node.get_logger().warning(text)
    services = ServiceThread(node.context, (node,))
    node_run.defer(services.close)
    services.start(0)

    def _stop() -> None:
        node.running = False

    node_run.on_stop(_stop)
    wait_s = float(node.get_parameter('wait_for_controller_s').value)
    deadline = time.monotonic() + wait_s
    while not node.ready():
        if time.monotonic() > deadline or not node.running:
            print(f'cnc_node: no height controller within {wait_s:g} s (follow services, '
                  'follow/status' + (', the sim reading cnc/lockstep' if node.lockstep
                                     else '') + ')', file=sys.stderr)
            return 3
        time.sleep(0.05)
    if not node.lockstep:  # the axis is up: the controller holds a sensor sample
        while node.link.take_status() < 0 or node.link.gap_seq == 0:
            if time.monotonic() > deadline or not node.running:
                print(f'cnc_node: the height controller had no sensor sample within '
                      f'{wait_s:g} s', file=sys.stderr)
                return 3
            time.sleep(0.01)
    node.get_logger().info(f'job {node.job.name}: {len(node.program.contours)} contours')
    code = 0  # the job ran: finished, or aborted with its reason (a job's outcome)
    try:
        node.run()
    except LockstepTimeout as exc:
        node.station.log.aborted = f'lock step: {exc}'
        print(f'cnc_node: lock step aborted: {exc}', file=sys.stderr)
        code = 3
    except KeyboardInterrupt:
        node.station.log.aborted = node.station.log.aborted or 'interrupted'
    text = node.publish_log()
    late = wait_acknowledged(tuple(p for p in (node.pub_motion, node.pub_step, node.pub_job)
                                   if p is not None), node.timeout_ns * 1e-9)
    if late:
        node.get_logger().warning(f'messages on {", ".join(late)} not acknowledged by every '
                                  'reader')
    print(json.dumps({'job': node.job.name, **json.loads(text)}), flush=True)
    while node.running and not node.get_parameter('exit_at_end').value:
        time.sleep(0.1)
    return code


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``ros2 run ladrc_sim cnc_node --ros-args -p job:=NAME``.

    The CNC has no command of its own to zero (the axis's zero command is the follow node's):
    a stop request ends the job as interrupted, its log published.
    """
    return run_node('cnc_node', _make_node, _run, args=argv)


if __name__ == '__main__':
    sys.exit(main())
