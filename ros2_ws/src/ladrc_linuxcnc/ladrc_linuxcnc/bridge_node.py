"""The bridge node: LinuxCNC on the CNC interface, as the CNC node is (in the venv's Python).

``ros2 run ladrc_linuxcnc bridge_node --ros-args -p socket_path:=SOCKET`` connects to the
bridge's HAL component inside a running LinuxCNC (:mod:`.hal_component`, started by LinuxCNC's
HAL file on the system's Python) and plays the CNC's part of the CNC interface
(docs/interfaces.md, "CNC interface"; docs/linuxcnc.md, "The bridge"): per LinuxCNC sample
(1 kHz) it publishes ``cnc/motion``, calls the follow services its logic
(:class:`.sequence.Sequencer`) asks for, reads the controller's answers on ``follow/status``
and sends the HAL outputs back (at-speed, feed hold, adaptive feed, beam, pause).

**Two processes, one bridge.** LinuxCNC's ``hal`` and ``linuxcnc`` modules import only in the
Python minor version they were built for (the system's: 3.11 on Debian 12), while this node
runs in the project's venv, which may be made from another (3.10-3.13) and holds rclpy. So the
HAL side is a process of its own under ``/usr/bin/python3``, and this node talks to it over a
Unix socket (:mod:`.protocol`). Either one gone is seen by the other at once (the socket
closes): the component drives its safe outputs (feed hold, beam off, pause); this node aborts
the job and lifts the head.

At the job's end (the program's end, or an abort with its reason) it publishes the job's log
on ``cnc/job`` (JSON, latched: the simulated CNC's keys and LinuxCNC's own: the contours with
their program lines, the holds on FAULT with how fast LinuxCNC stopped), prints it as its last
line and exits 0. No LinuxCNC within ``wait_for_linuxcnc_s`` or no height controller within
``wait_for_controller_s``: one line, exit 3. A bad parameter: one line, exit 2. Every other
exception: the safe outputs first, then one line, exit 1.
"""

from __future__ import annotations

from dataclasses import replace
import json
import math
import select
import socket
import sys
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from ladrc_contract import qos
from ladrc_contract.cdr import CdrPacker
from ladrc_contract.loop_io import LoopNode
from ladrc_contract.node_entry import NodeRun, StartError, run_node
from ladrc_contract.qos import to_rclpy, wait_acknowledged
from ladrc_contract.realtime import apply_realtime
from ladrc_contract.ros_params import descriptor, ros_value
from ladrc_contract.schema import entries, first_problem
from ladrc_contract.service_thread import ServiceThread
from ladrc_contract.services import FOLLOW_SERVICES, fill_request, service_class
from ladrc_contract.topics import (
    CNC_JOB_TOPIC,
    CNC_MOTION_TOPIC,
    DIAGNOSTICS_TOPIC,
    STATUS_TOPIC,
)
from ladrc_msgs.msg import CncMotion, FollowStatus
from rclpy.clock import Clock, ClockType
from std_msgs.msg import String

from . import protocol as p
from .sequence import BridgeParams, Sequencer

COMMANDS = ('pierce', 'lift', 'hold', 'leapfrog', 'stop_follow')
"""The follow commands the bridge sends (ladrc_contract.services names)."""
ANSWERS = ('state', 'substate', 'in_position', 'ready_to_move', 'feed_hold_request',
           'feed_override_request', 'fault_reason', 'velocity_mm_s', 'gap_seq')
"""The ``FollowStatus`` fields the bridge reads."""
ACK_TIMEOUT_S = 10.0
"""The job's log (cnc/job) is kept until every reader acknowledged it, this long at most: the
latched sample goes with its writer, and on a loaded machine the sim may take seconds."""
MOTION_FIELDS = ('x_mm', 'y_mm', 'commanded_feed_mm_s', 'actual_feed_mm_s', 'segment',
                 'beam_on', 'contour', 'segment_left_mm', 'edge_ahead_mm')


def declare(node: Any, section: Any) -> Any:
    """Declare every parameter of ``section`` on ``node``; return the values given.

    ``ladrc_contract.ros_params.declare_section``'s rule (the descriptor and the check from the
    one declaration), with ROS's double arrays read back as the tuples the section declares.
    """
    values = {}
    for e in entries(section):
        node.declare_parameter(e.name, ros_value(e, e.value), descriptor(e))
        v = node.get_parameter(e.name).value
        values[e.name] = tuple(float(x) for x in v) if isinstance(e.value, tuple) else v
    out = replace(section, **values)
    problem = first_problem(out)
    if problem is not None:
        raise ValueError(f'parameter {problem[0]}: {problem[1]}')
    return out


class BridgeError(Exception):
    """The bridge cannot start (no LinuxCNC, no controller); one line, exit 3."""


class BridgeNode(LoopNode):
    """LinuxCNC's bridge to the height controller (module docstring)."""

    def __init__(self) -> None:
        super().__init__('ladrc_linuxcnc_bridge')
        self.p: BridgeParams = declare(self, BridgeParams())
        p_ = self.p
        if not p_.socket_path:
            raise ValueError("socket_path is empty: the HAL component's socket ([LADRC]SOCKET "
                             "of the run's INI)")
        if len(p_.pierce_heights_mm) != len(p_.pierce_dwell_s) or not p_.pierce_heights_mm:
            raise ValueError(f'pierce_heights_mm ({len(p_.pierce_heights_mm)}) and '
                             f'pierce_dwell_s ({len(p_.pierce_dwell_s)}): one dwell per stage, '
                             'at least one stage')
        self.running = True
        self.pub_motion = self.create_publisher(CncMotion, CNC_MOTION_TOPIC,
                                                to_rclpy(qos.HIGH_RATE))
        self.pub_job = self.create_publisher(String, CNC_JOB_TOPIC, to_rclpy(qos.RUN_TEXT))
        self.pub_diag = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC,
                                              to_rclpy(qos.DIAGNOSTICS))
        self.status_reader = self.create_loop_reader(FollowStatus, STATUS_TOPIC,
                                                     to_rclpy(qos.CONTROL_INPUT))
        self.follow_clients = {n: self.create_client(service_class(FOLLOW_SERVICES[n][0]),
                                              FOLLOW_SERVICES[n][1]) for n in COMMANDS}
        self._status = CdrPacker('ladrc_msgs/msg/FollowStatus')
        self._answer_idx = [self._status.index[n] for n in ANSWERS]
        self._motion = CdrPacker('ladrc_msgs/msg/CncMotion')
        self._mvalues = self._motion.defaults()
        self._mvalues[self._motion.index['header.frame_id']] = 'machine'
        self._midx = [self._motion.index[n] for n in MOTION_FIELDS]
        self._seq_idx = self._motion.index['seq']
        self.motion_seq = 0
        self.answers: dict[str, Any] | None = None
        self.answer_ns = 0
        self.seq = Sequencer(p_)
        self.pending: list[tuple[str, Any]] = []
        self.sock: socket.socket | None = None
        self.reader = p.FrameReader()
        self.hello: dict[str, Any] = {}
        self.last: p.LcncSample | None = None
        self.create_timer(1.0, self._diagnostics, clock=Clock(clock_type=ClockType.STEADY_TIME))

    # ---- the two sides ------------------------------------------------------------------------
    def connect(self) -> None:
        """Connect to the HAL component's socket (waits up to ``wait_for_linuxcnc_s``)."""
        end = time.monotonic() + self.p.wait_for_linuxcnc_s
        while True:
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                s.connect(self.p.socket_path)
                s.setblocking(False)
                self.sock = s
                return
            except OSError as exc:
                s.close()
                if time.monotonic() > end or not self.running:
                    raise BridgeError(f'no LinuxCNC bridge component at {self.p.socket_path} '
                                      f'within {self.p.wait_for_linuxcnc_s:g} s '
                                      f'({exc.strerror or exc})') from None
                time.sleep(0.1)

    def drain(self) -> None:
        """Before the job: read what the component sent (its hello; the samples are dropped).

        Else they would wait in the socket and be stepped through late, seconds of them.
        """
        if self.sock is None:
            return
        while True:
            try:
                data = self.sock.recv(1 << 16)
            except (BlockingIOError, InterruptedError):
                return
            if not data:
                raise BridgeError('the LinuxCNC bridge component closed the connection')
            self.reader.feed(data)
            try:
                for kind, value in self.reader.frames():
                    if kind == p.HELLO:
                        self.hello = value
                        self.seq.hello(value)
            except ValueError as exc:
                raise BridgeError(f'not the bridge protocol: {exc}') from None

    def controller_ready(self) -> bool:
        """Return whether the controller's services are up and its status has a sensor sample."""
        if not all(c.service_is_ready() for c in self.follow_clients.values()):
            return False
        self.take_status()
        return self.answers is not None and int(self.answers.get('gap_seq', 0)) > 0

    def take_status(self) -> None:
        """Take the statuses that arrived; keep the newest (only it is decoded)."""
        for data, _ in reversed(self.status_reader.take_all()):
            try:
                values = self._status.unpack(data)
            except ValueError:
                continue  # not the contract's message: nobody's answer
            self.answers = dict(zip(ANSWERS, (values[i] for i in self._answer_idx),
                                    strict=True))
            self.answer_ns = time.monotonic_ns()
            return

    def send_command(self, name: str, args: dict[str, Any]) -> None:
        """Call a follow service (not awaited: a refusal, when its answer comes, aborts)."""
        future = self.follow_clients[name].call_async(fill_request(name, args))
        self.pending.append((name, future))

    def refusals(self, now_s: float) -> None:
        """Abort the job on a refused command whose answer has come."""
        still = []
        for name, future in self.pending:
            if not future.done():
                still.append((name, future))
                continue
            result = future.result()
            if result is None or not result.accepted:
                self.seq.refused(name, result.message if result is not None else 'no answer',
                                 now_s)
        self.pending = still

    def publish_motion(self, motion: dict[str, Any]) -> None:
        """Publish ``cnc/motion``, stamped when it goes out (as the CNC node stamps its own).

        The controller times a CNC sample by its reception and checks the stamp only for
        plausibility; how old LinuxCNC's pins were (the component's 1 ms poll and the socket)
        is in the log (``linuxcnc_max_gap_ms``).
        """
        stamp = self.get_clock().now().nanoseconds
        v = self._mvalues
        v[0], v[1] = divmod(stamp, 1_000_000_000)
        self.motion_seq += 1
        v[self._seq_idx] = self.motion_seq
        for i, name in zip(self._midx, MOTION_FIELDS, strict=True):
            value = motion[name]
            v[i] = (bool(value) if name == 'beam_on' else int(value)
                    if name in ('segment', 'contour') else float(value))
        self.pub_motion.publish(self._motion.pack(v))

    def send_outputs(self, out: p.HalOutputs) -> None:
        """Send the HAL outputs to the component (a full socket buffer drops nothing: waits)."""
        if self.sock is None:
            return
        data = out.pack()
        try:
            self.sock.sendall(data)
        except (BlockingIOError, InterruptedError):
            self.sock.setblocking(True)
            self.sock.settimeout(0.05)
            try:
                self.sock.sendall(data)
            finally:
                self.sock.setblocking(False)

    # ---- the loop ------------------------------------------------------------------------------
    def run(self) -> None:
        """Run until the job's log is out (or a stop)."""
        seq = self.seq
        link_ns = int(self.p.link_timeout_s * 1e9)
        last_rx = time.monotonic_ns()
        while self.running:
            now_ns = time.monotonic_ns()
            now_s = now_ns * 1e-9
            samples: list[p.LcncSample] = []
            if self.sock is not None:
                r, _, _ = select.select([self.sock], [], [], 0.002)
                if r:
                    try:
                        data = self.sock.recv(1 << 16)
                    except (BlockingIOError, InterruptedError):
                        data = b''
                        r = []
                    except OSError as exc:
                        data, why = b'', f'socket error: {exc.strerror or exc}'
                        self._gone(why, now_s)
                    if r and not data and self.sock is not None:
                        self._gone('its HAL component closed the connection', now_s)
                    elif data:
                        last_rx = now_ns
                        self.reader.feed(data)
                        try:
                            for kind, value in self.reader.frames():
                                if kind == p.SAMPLE:
                                    samples.append(value)
                                elif kind == p.HELLO:
                                    self.hello = value
                                    seq.hello(value)
                        except ValueError as exc:
                            self._gone(f'not the bridge protocol: {exc}', now_s)
                if self.sock is not None and now_ns - last_rx > link_ns:
                    self._gone(f'no sample for {(now_ns - last_rx) * 1e-6:.0f} ms (limit '
                               f'{link_ns * 1e-6:g} ms)', now_s)
            else:
                time.sleep(0.002)
            self.take_status()
            if self.sock is None:  # LinuxCNC gone: the end's commands without samples
                for name, args in seq.end_step(self.answers, now_s):
                    self.send_command(name, args)
            self.refusals(now_s)
            age_s = (now_ns - self.answer_ns) * 1e-9 if self.answers is not None else math.inf
            out = None
            for sample in samples:
                # (one machine, one monotonic clock: the component's and this node's)
                step = seq.step(sample, self.answers, age_s, now_s,
                                (time.monotonic_ns() - sample.t_ns) * 1e-9)
                for name, args in step.commands:
                    self.send_command(name, args)
                out = step
                self.last = sample
            if out is not None:
                self.publish_motion(out.motion)
                try:
                    self.send_outputs(out.outputs)
                except OSError as exc:  # (BrokenPipe, reset: the component died meanwhile)
                    self._gone(f'socket error: {exc.strerror or exc}', now_s)
            if seq.end_ready(self.answers, now_s) and self.p.exit_at_end:
                return

    def _gone(self, why: str, now_s: float) -> None:
        """LinuxCNC's side is gone: close the socket, abort and lift (the sequencer's rule)."""
        if self.sock is not None:
            try:
                self.sock.close()
            except OSError:
                pass
            self.sock = None
        for name, args in self.seq.linuxcnc_gone(why, now_s, self.answers):
            self.send_command(name, args)

    def publish_log(self) -> str:
        """Publish the job's log on ``cnc/job`` (latched); return its JSON."""
        text = json.dumps({'job': self.p.job, **self.seq.log.as_dict()})
        self.pub_job.publish(String(data=text))
        return text

    def safe_stop(self) -> None:
        """Send the safe outputs (feed hold, beam off) and close the socket."""
        if self.sock is not None:
            try:
                self.send_outputs(p.HalOutputs(self.seq.seq + 1, 1.0, p.O_FEED_HOLD,
                                               self.seq.pause_count))
            except OSError:
                pass
            try:
                self.sock.close()
            except OSError:
                pass
            self.sock = None

    def _diagnostics(self) -> None:
        s, q = self.last, self.seq
        st = DiagnosticStatus(name=f'{self.get_fully_qualified_name().lstrip("/")}: LinuxCNC',
                              hardware_id='linuxcnc')
        st.level = DiagnosticStatus.ERROR if q.log.aborted else DiagnosticStatus.OK
        st.message = q.log.aborted or q.phase
        values = {'phase': q.phase, 'contour': q.contour, 'pierces': q.log.pierces,
                  'linuxcnc_samples': q.log.linuxcnc_samples,
                  'linuxcnc_max_gap_ms': round(q.log.linuxcnc_max_gap_ms, 1),
                  'connected': self.sock is not None}
        if s is not None:
            values.update({'program_line': s.program_line, 'motion_type': s.motion_type,
                           'x_mm': round(s.x_mm, 3), 'y_mm': round(s.y_mm, 3)})
        st.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(arr)


def _make_node() -> BridgeNode:
    try:
        return BridgeNode()
    except ValueError as exc:
        raise StartError(str(exc)) from None


def _run(node: BridgeNode, node_run: NodeRun) -> int:
    """Connect to LinuxCNC, wait for the height controller, bridge the job; the exit code."""
    _, warnings = apply_realtime(node.p.thread_priority, [], node.p.lock_memory)
    for text in warnings:
        node.get_logger().warning(text)
    services = ServiceThread(node.context, (node,))
    node_run.defer(services.close)
    services.start(node.p.thread_priority - 1 if node.p.thread_priority > 1 else 0)

    def _stop() -> None:
        node.running = False

    node_run.on_stop(_stop)
    try:
        node.connect()
        end = time.monotonic() + node.p.wait_for_controller_s
        while not node.controller_ready():
            if time.monotonic() > end or not node.running:
                raise BridgeError(f'no height controller within '
                                  f'{node.p.wait_for_controller_s:g} s (follow services '
                                  'and a follow/status with a sensor sample)')
            # meanwhile LinuxCNC waits: the component keeps its safe outputs
            try:
                node.drain()
                node.send_outputs(p.HalOutputs(0, 1.0, p.O_FEED_HOLD, 0))
            except OSError as exc:
                raise BridgeError(f'LinuxCNC gone before the job: {exc}') from None
            time.sleep(0.02)
    except BridgeError as exc:
        print(f'bridge_node: {exc}', file=sys.stderr)
        return 3
    node.get_logger().info(f'LinuxCNC bridge up: {json.dumps(node.hello)}')
    try:
        node.run()
    except Exception as exc:  # noqa: BLE001 (the safe outputs first, then one line)
        node.safe_stop()
        print(f'bridge_node: stopped by {type(exc).__name__}: {exc}', file=sys.stderr)
        return 1
    if not node.running and not node.seq.log.aborted and not node.seq.log.finished:
        node.seq.log.aborted = node.seq.log.aborted_code = 'interrupted'
    text = node.publish_log()
    node.safe_stop()
    late = wait_acknowledged((node.pub_job,), ACK_TIMEOUT_S)
    if late:
        node.get_logger().warning(f'cnc/job not acknowledged by every reader within '
                                  f'{ACK_TIMEOUT_S:g} s')
    print(text, flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``ros2 run ladrc_linuxcnc bridge_node --ros-args -p socket_path:=PATH``.

    Every path ends in the safe outputs to LinuxCNC (feed hold, beam off:
    :meth:`BridgeNode.safe_stop`).
    """
    return run_node('bridge_node', _make_node, _run, args=argv,
                    zero=lambda node, _reason: node.safe_stop())


if __name__ == '__main__':
    sys.exit(main())
