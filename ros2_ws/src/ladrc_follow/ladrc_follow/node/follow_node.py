"""The follow node: the 2 kHz loop around the pure :class:`FollowController`.

Thin by design (DESIGN.md): the loop thread takes the sensor samples straight from their
readers as raw CDR and keeps them as plain values (:mod:`ladrc_contract.loop_io`); each 0.5 ms
tick builds a :class:`TickInput`, steps the control core, and publishes one ``VelocityCommand``
and one ``FollowStatus`` (with the exact inputs used, for replay), both pre-serialized. Nothing
else happens on the loop thread: no executor, no logging, no I/O. The follow services, the
parameters, /diagnostics and the topology check are served by the housekeeping thread
(:mod:`.housekeeping`); a follow command takes the node's lock, so it lands between two ticks.

Loop (``loop``, :mod:`.loops`, docs/follow-node.md "The loop"): ``deadline``, an own 0.5 ms
deadline loop; ``sync``, one tick per new pair of sensor samples, as soon as they arrive, with
its own deadline when one is late; ``lockstep``: one tick per step of the sim node
(``sim/lockstep``), on the sim's clock; offered against the sim node only.
``bench/loop_timing.py`` measures them, docs/follow-node.md says why the default won.
QoS: :mod:`ladrc_contract.qos`. The inputs: :mod:`.samples`; the parameters: :mod:`.node_params`.

Safety: zero velocity with ``enable = false`` on stop, fault, shutdown, SIGINT and SIGTERM
(the entry, :func:`ladrc_contract.node_entry.run_node`, keeps the ROS context up until the zero
command is out).
"""

from __future__ import annotations

from array import array
import functools
import gc
import json
import math
import os
import queue
import secrets
import sys
import threading
import time
from typing import Any, NamedTuple

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from ladrc_contract import qos
from ladrc_contract.cdr import CdrPacker
from ladrc_contract.codes import EventKind, FaultCode
from ladrc_contract.events import EventFields
from ladrc_contract.events import encode as encode_event
from ladrc_contract.loop_io import LoopNode
from ladrc_contract.node_entry import NodeRun, StartError, run_node
from ladrc_contract.qos import to_rclpy, wait_acknowledged
from ladrc_contract.realtime import apply_realtime
from ladrc_contract.run_log import RunLog, verdict
from ladrc_contract.schema import Entry, entries, field_problems
from ladrc_contract.services import FOLLOW_SERVICES, command_args, service_class
from ladrc_contract.topics import (
    CNC_MOTION_TOPIC,
    COMMAND_TOPIC,
    DIAGNOSTICS_TOPIC,
    EVENTS_TOPIC,
    FEEDBACK_TOPIC,
    GAP_TOPIC,
    LOCKSTEP_TOPIC,
    PARAMETERS_TOPIC,
    STATUS_TOPIC,
)
from ladrc_msgs.msg import (
    AxisFeedback,
    CapacitiveHeight,
    CncMotion,
    FollowEvent,
    FollowStatus,
    LockStep,
    VelocityCommand,
)
from rcl_interfaces.msg import (
    SetParametersResult,
)
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.parameter import Parameter
from std_msgs.msg import String

from ..analysis.gate import check_gate
from ..control.cap_table import RawToGap, TableError, TableLimits, load_table
from ..control.follow import FollowController, FollowState, PreparedSet, TickInput
from ..control.params import (
    DEFAULT_NODE_NAME,
    ControllerParams,
    ParameterError,
    dump_params,
    params_from_dict,
)
from .gate_process import GateProcess
from .housekeeping import Housekeeping
from .loop_stats import LoopStats
from .loops import run_loop
from .node_params import NodeParams, descriptor, params_file_problem, ros_value
from .samples import SampleInputs
from .topology import TOPOLOGY_PERIOD_S, topology_problems


class _AcceptedSet(NamedTuple):
    """A set the parameter thread accepted, everything built, for the loop to apply at a tick."""

    params: ControllerParams
    prepared: PreparedSet
    text: str  # dump_params(params): the PARAMETERS event and run/parameters
    table: tuple[RawToGap | None] | None  # (the new table,) when the set changes it


def _defaults(packer: CdrPacker) -> list[Any]:
    """Zero values of a packer's leaf fields, of the right Python type each."""
    zero = {'string': '', 'bool': False, 'float32': 0.0, 'float64': 0.0}
    return [zero.get(kind, 0) for _, kind in packer.fields]


class FollowNode(LoopNode):
    """ROS 2 wrapper of :class:`FollowController` (see module docstring)."""

    def __init__(self) -> None:
        # ros2 param: served by the housekeeping thread, not the loop (node/housekeeping.py)
        super().__init__(DEFAULT_NODE_NAME, start_parameter_services=False)
        self._entries = {e.name: e for e in entries(ControllerParams())}
        self.node_params, self.params, table = self._declare_parameters()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        # every set reaching the controller passed the stability gate (start-up above, a change
        # in _on_set_parameters); the controller does not gate (the analysis stays off the loop)
        self.controller = FollowController(self.params)
        # Sets accepted on the housekeeping thread, checked and built there; the loop applies
        # them at its next tick. The node's lock: the loop holds it for a tick, a follow
        # command takes it between two ticks, and a set takes it to queue itself ("not
        # following, so a table may change" in one step against a queued start).
        self._accepted: queue.SimpleQueue[_AcceptedSet] = queue.SimpleQueue()
        self._lock = threading.Lock()
        self.h_s = self.params.h_s
        self.period_ns = int(round(self.h_s * 1e9))
        self.loop_mode = self.node_params.loop
        self.lockstep = self.loop_mode == 'lockstep'
        self.sync_wait_ns = int(round(self.node_params.sync_wait_s * 1e9))
        # t_s and every receive time count from here, on the steady clock (docs, "Time")
        self._t0_ns = time.monotonic_ns()
        self._clock = self.get_clock()  # ROS time for header stamps (use_sim_time applies)
        self.samples = self._create_inputs(table)
        self._create_outputs()
        self.tick_index = 0
        self.sample_seq = 0  # the feedback sample (sync, deadline) or the step (lockstep)
        self.stats = LoopStats(self.period_ns, self.lockstep)
        self.run_log = RunLog(self.h_s)  # faults, holds, time per state: written at exit
        self.deadline_ticks = 0  # sync: ticks run on the own deadline (a sample was late)
        self.tick_exceptions = 0
        self.realtime = 'none'  # what apply_realtime could set (main), for /diagnostics
        # diagnostic_updater's naming: the node's fully qualified name, then the task
        self._diag_name = f'{self.get_fully_qualified_name().lstrip("/")}: follow loop'
        self.create_timer(self.node_params.diagnostics_period_s, self._publish_diagnostics,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._publish_parameters(dump_params(self.params))
        self.housekeeping = Housekeeping(self)  # started by main, after apply_realtime
        self.gate = GateProcess()  # started by main, before apply_realtime
        # who else publishes on the contract topics: checked on the housekeeping thread, a
        # FAULT at the next tick while it lasts (node/topology.py)
        self.topology_problem = ''
        self.housekeeping.add_timer(TOPOLOGY_PERIOD_S, self._check_topology)
        # Pay the first-call costs of the diagnostics path (message types, publisher, numpy)
        # now: measured 11-12 ms on the first call, 0.6-0.9 ms afterwards, and a first call
        # in the loop stalled it long enough to trip a 5 ms drive watchdog.
        self._publish_diagnostics()

    # ---- set-up -----------------------------------------------------------------------
    def _declare_parameters(self) -> tuple[NodeParams, ControllerParams, RawToGap | None]:
        """Declare every parameter; return the node's, the controller's set and its table.

        The whole set, as loaded from the parameter file, must be valid and pass the stability
        gate (here, in this process: the loop is not running yet) to start.
        """
        self._declaring = True
        node_entries = list(entries(NodeParams()))
        try:
            for e in node_entries + list(self._entries.values()):
                self._declare(e)
        except (ParameterException, ValueError, TypeError) as exc:
            raise ParameterError([f'{type(exc).__name__}: {exc}']) from exc
        self._declaring = False
        declared = {e.name for e in node_entries} | set(self._entries)
        unknown = sorted(set(self._parameter_overrides) - declared - {'use_sim_time'})
        if unknown:
            raise ParameterError([f'unknown parameter {name!r} in the parameter file or '
                                  'command line' for name in unknown])
        node_params = NodeParams(**{e.name: self.get_parameter(e.name).value
                                    for e in node_entries})
        reasons = field_problems(node_params)
        params = table = None
        try:
            params = check_gate(self._params_from_ros({}))
            table = self._load_table(params)  # sensor.table_file (docs/calibration.md)
        except ParameterError as exc:
            reasons += exc.reasons
        if reasons:
            raise ParameterError(reasons)
        return node_params, params, table

    def _create_inputs(self, table: RawToGap | None) -> SampleInputs:
        """Create the loop thread's readers (node/loops.py): taken from straight, plain values."""
        control_in = to_rclpy(qos.LOCKSTEP_INPUT if self.lockstep else qos.CONTROL_INPUT)
        np_ = self.node_params
        inputs = SampleInputs(
            self.create_loop_reader(CapacitiveHeight, GAP_TOPIC, control_in),
            self.create_loop_reader(AxisFeedback, FEEDBACK_TOPIC, control_in),
            (self.create_loop_reader(LockStep, LOCKSTEP_TOPIC, control_in)
             if self.lockstep else None),
            clock=self._clock, system_clock=not self.get_parameter('use_sim_time').value,
            t0_ns=self._t0_ns, h_s=self.h_s, stamp_tolerance_s=np_.stamp_tolerance_s,
            sync=self.loop_mode == 'sync', sample_period_tolerance=np_.sample_period_tolerance,
            cnc_reader=self.create_loop_reader(CncMotion, CNC_MOTION_TOPIC, control_in))
        inputs.cap_table = table
        return inputs

    def _create_outputs(self) -> None:
        """Create the publishers, the follow services and the tick's pre-serialized messages."""
        high_rate = to_rclpy(qos.LOCKSTEP_HIGH_RATE if self.lockstep else qos.HIGH_RATE)
        self.pub_cmd = self.create_publisher(VelocityCommand, COMMAND_TOPIC, high_rate)
        self.pub_status = self.create_publisher(FollowStatus, STATUS_TOPIC, high_rate)
        self.pub_events = self.create_publisher(FollowEvent, EVENTS_TOPIC, to_rclpy(qos.EVENTS))
        self.pub_diag = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC,
                                              to_rclpy(qos.DIAGNOSTICS))
        self.pub_run_params = self.create_publisher(String, PARAMETERS_TOPIC,
                                                    to_rclpy(qos.RUN_TEXT))
        for name, (srv_type, service, _) in FOLLOW_SERVICES.items():
            self.create_service(service_class(srv_type), service,
                                functools.partial(self._serve_command, name))
        # The tick publishes pre-serialized CDR (ladrc_contract.cdr): filling rclpy messages
        # field by field cost more than the whole control step. One value list per message,
        # refilled in place each tick. One commander (docs/interfaces.md): this process'
        # identity in every command.
        self._cmd_packer = CdrPacker('ladrc_msgs/msg/VelocityCommand')
        self._cmd_vals = self._cmd_packer.defaults()
        cix = self._cmd_packer.index
        self._cix_answer = cix['sample_seq']
        self._cix_release = cix['release']
        self._cmd_vals[cix['commander']] = self.get_fully_qualified_name()
        self._cmd_vals[cix['session']] = secrets.randbits(63) or 1
        self._st_packer = CdrPacker('ladrc_msgs/msg/FollowStatus')
        self._st_vals = self._st_packer.defaults()
        ix = self._st_packer.index
        # no CNC motion received: its values unknown, no feed override asked
        for name in ('cnc_stamp_s', 'cnc_commanded_feed_mm_s', 'cnc_actual_feed_mm_s',
                     'cnc_segment_left_mm', 'cnc_edge_ahead_mm'):
            self._st_vals[ix[name]] = math.nan
        self._st_vals[ix['feed_override_request']] = 1.0
        self._ix = ix
        self._ix_inputs = [ix[n] for n in (
            't_s', 'gap_seq', 'gap_mm', 'gap_valid', 'gap_status', 'gap_stamp_s', 'encoder_seq',
            'encoder_mm', 'encoder_stamp_s', 'drive_enabled', 'drive_fault', 'velocity_mm_s',
            'period_us', 'compute_us', 'input_age_us', 'overrun', 'sample_seq')]

    # ---- parameters (the housekeeping thread) -------------------------------------------
    def _publish_parameters(self, text: str) -> None:
        self._publish_event(EventFields(EventKind.PARAMETERS, text=text))
        self.pub_run_params.publish(String(data=text))

    def _declare(self, e: Entry) -> None:
        """Declare one parameter; an integer given for a float parameter becomes a float."""
        override = self._parameter_overrides.get(e.name)
        if override is not None:
            value = ros_value(e, override.value)
            if value is not override.value:
                self._parameter_overrides[e.name] = Parameter(e.name, value=value)
        self.declare_parameter(e.name, ros_value(e, e.value), descriptor(e))

    def _params_from_ros(self, changes: dict[str, Any]) -> ControllerParams:
        values = {name: self.get_parameter(name).value for name in self._entries}
        values.update(changes)
        return params_from_dict({k: (tuple(v) if isinstance(v, (list, tuple, array)) else v)
                                 for k, v in values.items()})

    def _on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """Check a set and build it for the loop (the housekeeping thread, never the loop)."""
        if self._declaring:
            return SetParametersResult(successful=True)
        changes = {}
        for p in parameters:
            if p.name not in self._entries:
                return SetParametersResult(successful=False, reason=f'unknown parameter {p.name}')
            changes[p.name] = p.value
        try:
            candidate = self._params_from_ros(changes)
            # the stability gate in its own process: in this one it held the loop
            # (node/gate_process.py)
            reasons = self.gate.reasons(candidate) if candidate.stability.gate else []
            if reasons:
                raise ParameterError(reasons)
            # against the values set so far (queued or applied): the node's parameters
            table_changed = 'sensor.table_file' in changes or (
                candidate.sensor.table_file and candidate.follow.collision_gap_mm
                != self.get_parameter('follow.collision_gap_mm').value)
            table = (self._load_table(candidate),) if table_changed else None
            accepted = _AcceptedSet(candidate, self.controller.prepare(candidate),
                                    dump_params(candidate), table)
        except ParameterError as exc:
            # Rejected: the running values stay.
            return SetParametersResult(successful=False, reason=str(exc))
        except Exception as exc:  # noqa: BLE001 - never let a parameter crash the node
            return SetParametersResult(successful=False,
                                       reason=f'rejected: {type(exc).__name__}: {exc}')
        with self._lock:
            state = self.controller.projected_state  # a start queued this tick counts too
            if table_changed and state not in (FollowState.IDLE, FollowState.FAULT):
                return SetParametersResult(successful=False, reason=(
                    'sensor.table_file: a table changes only while not following (state '
                    f'{state.name}): stop follow first'))
            self._accepted.put(accepted)  # applied at the next tick boundary
        return SetParametersResult(successful=True)

    def _check_topology(self) -> None:
        """Check the publishers around this controller (the housekeeping thread)."""
        try:
            problems = topology_problems(self, COMMAND_TOPIC, [GAP_TOPIC, FEEDBACK_TOPIC])
        except Exception as exc:  # noqa: BLE001 - an unknown topology is a problem too
            problems = [f'the topology check failed: {type(exc).__name__}: {exc}']
        self.topology_problem = '; '.join(problems)

    def _apply_accepted(self) -> None:
        """Apply the sets accepted since the last tick, in order (the loop, at a tick)."""
        last = None
        while True:
            try:
                accepted = self._accepted.get_nowait()
            except queue.Empty:
                break
            last = accepted
            self.params = accepted.params
            if accepted.table is not None:  # never drop a table of an earlier set
                self.samples.cap_table = accepted.table[0]
                if self.samples.last_reading is not None:  # the held one, through the new table
                    self.samples.set_reading(*self.samples.last_reading)
        if last is not None:
            self.controller.set_prepared(last.prepared)
            self._publish_parameters(last.text)

    def _load_table(self, params: ControllerParams) -> RawToGap | None:
        """Return the checked table of ``sensor.table_file`` (None when empty).

        It must reach down to ``follow.collision_gap_mm``: a raw value closer than the table
        then reads as a collision (``cap_table`` module docstring). Raises ParameterError.
        """
        path = params.sensor.table_file
        if not path:
            return None
        try:
            return load_table(path, TableLimits(max_first_gap_mm=params.follow.collision_gap_mm))
        except TableError as exc:
            raise ParameterError([f'sensor.table_file: {r}' for r in exc.reasons]) from None

    # ---- the loop's ticks (node/loops.py) -------------------------------------------------
    def step_ready(self) -> bool:
        """Lock step: a step is waiting and its samples are here (node/samples.py)."""
        return self.samples.step_ready(bool(self.topology_problem))

    def tick_step(self) -> None:
        """Lock step: tick k of step k, at the sim's time k h_s (runner convention)."""
        step, stamp_ns = self.samples.step[0], self.samples.step[5]
        self.samples.step = None
        self.tick_index = step
        self.sample_seq = step
        self.tick(step * self.h_s, stamp_ns)

    def tick_sync(self) -> None:
        """Loop 'sync': tick on the samples received (both new, or the deadline came)."""
        if not self.samples.consume_cycle():
            self.deadline_ticks += 1
        self.tick(fail=self.samples.period_fault)

    def tick(self, t_s: float | None = None, stamp_ns: int | None = None,
             fail: str = '') -> None:
        """One controller tick: inputs -> core -> command and status out.

        ``t_s``: the tick's time (lock step: the sim's; default: the steady clock since
        start); ``stamp_ns``: its header stamp (default: the node clock now); ``fail``: a
        fault of the loop's own to latch first (the sync loop's sample period). Under the
        node's lock: a follow command (housekeeping thread) lands before or after, never
        inside.
        """
        with self._lock:
            if fail and self.controller.state != FollowState.FAULT:
                self.controller.fail(fail, FaultCode.LOOP_TIMING)
            self._tick(t_s, stamp_ns)

    def _tick(self, t_s: float | None, stamp_ns: int | None) -> None:
        start_mono = time.monotonic_ns()
        # header stamps: the node clock (ROS time)
        now_ns = self._clock.now().nanoseconds if stamp_ns is None else stamp_ns
        if not self._accepted.empty():
            self._apply_accepted()
        if self.topology_problem and self.controller.state != FollowState.FAULT:
            self.controller.fail(f'topology: {self.topology_problem}', FaultCode.TOPOLOGY)
        s = self.samples
        if t_s is None:
            t_s = (start_mono - self._t0_ns) * 1e-9
            self.sample_seq = s.enc_seq
        tick = TickInput(t_s, s.gap_mm, s.gap_valid, s.gap_stamp_s, s.enc_mm, s.enc_stamp_s,
                         s.drive_enabled, s.drive_fault, s.gap_status)
        controller = self.controller
        cnc, s.cnc = s.cnc, None  # a new CNC sample, once (the core holds the last one)
        velocity = controller.step(tick, cnc)
        enable = bool(controller.enable)
        velocity = float(velocity) if enable else 0.0
        sec, nsec = divmod(now_ns, 1_000_000_000)
        cmd = self._cmd_vals  # header.stamp.sec, .nanosec, .frame_id, seq, velocity, enable
        cmd[0], cmd[1], cmd[3], cmd[4], cmd[5] = sec, nsec, self.tick_index, velocity, enable
        cmd[self._cix_answer] = self.sample_seq
        self.pub_cmd.publish(self._cmd_packer.pack(cmd))
        compute_ns = time.monotonic_ns() - start_mono
        age_us = (t_s - min(tick.gap_stamp_s, tick.encoder_stamp_s)) * 1e6
        period_us, overrun = self.stats.tick(self.tick_index, start_mono, age_us)
        self._publish_status(tick, sec, nsec, velocity, period_us, compute_ns * 1e-3, age_us,
                             overrun)
        self.tick_index += 1

    def _publish_status(self, tick: TickInput, sec: int, nsec: int, velocity: float,
                        period_us: float, compute_us: float, age_us: float,
                        overrun: bool) -> None:
        """FollowStatus of this tick: the inputs used, the core's internals, the timing."""
        st, ix, s = self._st_vals, self._ix, self.samples
        internals = self.controller.internals()
        for name, value in internals.items():
            st[ix[name]] = value
        t = tick.t_s
        self.run_log.tick(t, internals['state'], internals['fault_reason'], t - tick.gap_stamp_s,
                          t - tick.encoder_stamp_s, internals['substate'],
                          self.controller.fault_code)
        st[0], st[1], st[3] = sec, nsec, self.tick_index
        values = (tick.t_s, s.gap_seq, tick.gap_mm, tick.gap_valid, tick.gap_status,
                  tick.gap_stamp_s, s.enc_seq, tick.encoder_mm, tick.encoder_stamp_s,
                  tick.drive_enabled, tick.drive_fault, velocity, period_us, compute_us,
                  age_us if math.isfinite(age_us) else -1.0, overrun, self.sample_seq)
        for i, value in zip(self._ix_inputs, values, strict=True):
            st[i] = value
        self.pub_status.publish(self._st_packer.pack(st))

    def write_run_summary(self) -> None:
        """Log the run's outcome in one line; write its summary to ``summary_file`` if set."""
        with self._lock:
            summary = self.run_log.summary()
        self.get_logger().info(f'run: {verdict(summary)[1]}')
        path = self.node_params.summary_file
        if path:
            try:
                tmp = f'{path}.part'
                with open(tmp, 'w', encoding='utf-8') as f:
                    json.dump(summary, f)
                os.replace(tmp, path)
            except OSError as exc:
                self.get_logger().error(f'summary_file {path}: {exc.strerror or exc}')

    def on_tick_exception(self, exc: BaseException) -> None:
        """Any exception on the tick path: zero command first, then FAULT, then the log."""
        reason = f'exception in the follow node loop: {type(exc).__name__}: {exc}'
        self.tick_exceptions += 1
        try:
            self.publish_zero(reason, log=self.tick_exceptions == 1)
        finally:
            with self._lock:
                self.controller.fail(reason)

    def publish_zero(self, reason: str, log: bool = True, release: bool = False) -> None:
        """Command zero velocity with the drive enable off (stop, shutdown, Ctrl-C).

        ``release``: the commander's last command (shutdown): the drive may take a new one.
        """
        sec, nsec = divmod(self._clock.now().nanoseconds, 1_000_000_000)
        cmd = self._cmd_vals
        cmd[0], cmd[1], cmd[3], cmd[4], cmd[5] = sec, nsec, self.tick_index, 0.0, False
        cmd[self._cix_answer] = self.sample_seq
        cmd[self._cix_release] = release
        self.pub_cmd.publish(self._cmd_packer.pack(cmd))
        cmd[self._cix_release] = False
        self.tick_index += 1
        if log:
            self.get_logger().info(f'zero velocity commanded: {reason}')

    # ---- follow commands (services, the housekeeping thread) ---------------------------
    def _publish_event(self, fields: EventFields) -> None:
        """Log an applied command or set on follow/events, with the tick it takes effect at."""
        ev = FollowEvent()
        # stamped at the node clock; lock step: at the sim time of the tick it takes effect at
        sec, nsec = divmod(self.tick_index * self.period_ns if self.lockstep
                           else self._clock.now().nanoseconds, 1_000_000_000)
        ev.header.stamp.sec = sec
        ev.header.stamp.nanosec = nsec
        ev.tick = self.tick_index  # takes effect at the start of the next tick
        ev.kind, ev.value_mm, ev.delay_s, ev.velocity_mm_s, ev.accel_mm_s2, ev.flag, ev.text = (
            fields)
        self.pub_events.publish(ev)

    def _serve_command(self, name: str, request, response):
        """Serve a follow command: queue it for the next tick and log it (the events codec)."""
        args = command_args(name, request)
        with self._lock:  # between two ticks; the event names the tick it takes effect at
            accepted, message = self.controller.command(name, **args)
            if accepted:
                self._publish_event(encode_event(name, args))
        response.accepted = bool(accepted)
        response.message = str(message)
        if not accepted:
            self.get_logger().warning(f'{name} rejected: {message}')
        return response

    # ---- diagnostics (the housekeeping thread) -------------------------------------------
    def loop_statistics(self) -> dict[str, float]:
        """Rate, period percentiles, overruns, input age since the last call; sample counts."""
        s = self.samples
        return {
            **self.stats.window(self.tick_index),
            'missed_gap_samples': float(s.missed_gap_samples),
            'stamp_rejects': float(s.stamp_rejects),
            'malformed_samples': float(s.malformed_samples),
            'tick_exceptions': float(self.tick_exceptions),
            **{f'samples_{k}': float(v) for k, v in self.controller.counts.items()},
            'missed_feedback_samples': float(s.missed_feedback_samples),
            'deadline_ticks': float(self.deadline_ticks),
            'sample_period_ms': s.sample_period_s * 1e3,
        }

    def _publish_diagnostics(self) -> None:
        stats = self.loop_statistics()
        ctl = self.controller
        status = DiagnosticStatus(name=self._diag_name,
                                  hardware_id=self.node_params.hardware_id)
        state = getattr(ctl.state, 'name', str(ctl.state))
        if ctl.fault_reason or self.topology_problem:
            status.level = DiagnosticStatus.ERROR
            status.message = f'{state}: {ctl.fault_reason or self.topology_problem}'
        elif stats['rate_hz'] < 0.99 / self.h_s:
            status.level = DiagnosticStatus.WARN
            status.message = f'{state}: loop rate {stats["rate_hz"]:.0f} Hz below target'
        else:
            status.level = DiagnosticStatus.OK
            status.message = state
        table = self.samples.cap_table
        values = {k: f'{v:.6g}' for k, v in stats.items()}
        values.update({'state': state, 'fault_reason': ctl.fault_reason or '',
                       'ticks': str(self.tick_index), 'loop': self.loop_mode,
                       'realtime': self.realtime, 'topology': self.topology_problem or 'ok',
                       'last_stamp_reject': self.samples.last_stamp_reject or 'none',
                       'cap_table': (table.describe() if table is not None
                                     else 'none (gap_mm as published)'),
                       'cap_table_out_of_range': str(table.out_of_range
                                                     if table is not None else 0)})
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [status]
        self.pub_diag.publish(arr)


def _make_node() -> FollowNode:
    try:
        return FollowNode()
    except ParameterError as exc:
        raise StartError(f'invalid parameters: {" | ".join(exc.reasons)}') from None


def _run(node: FollowNode, run: NodeRun) -> int:
    """Start the gate worker, the real-time settings and the housekeeping; run the loop."""
    np_ = node.node_params
    run.defer(node.gate.close)
    node.gate.start()  # its worker process runs at the normal scheduler
    # no SCHED_FIFO in lock step: timing cannot change its result, and two FIFO processes
    # answering each other as fast as they can starve every other process (the recorder)
    applied, warnings = apply_realtime(0 if node.lockstep else np_.thread_priority,
                                       [np_.cpu] if np_.cpu >= 0 else [], np_.lock_memory)
    for text in warnings:
        node.get_logger().warning(text)
    node.realtime = ', '.join(applied) or 'none'
    # after apply_realtime; one below a real-time loop (ladrc_contract.service_thread)
    fifo = any(a.startswith('SCHED_FIFO') for a in applied)
    run.defer(node.housekeeping.close)
    node.housekeeping.start(np_.thread_priority - 1 if fifo else 0)
    node.get_logger().info(f'following loop started ({node.loop_mode}, '
                           f'{1.0 / node.h_s:.0f} Hz)')
    # Everything alive now (node, controller, generated code) leaves the collector's
    # reach: a full collection must not stall the 2 kHz loop.
    gc.collect()
    gc.freeze()
    try:
        run_loop(node, run)
    except ExternalShutdownException:
        run.request_stop('external shutdown')
    run.defer(node.write_run_summary)  # after the zero command, before the threads go
    return 0


def _zero(node: FollowNode, reason: str) -> None:
    """Zero velocity, drive enable off, the last one releasing the commander; lock step: acked."""
    for i in range(3):
        try:
            node.publish_zero(reason, log=i == 0, release=i == 2)
        except Exception:  # noqa: BLE001 - the context may already be gone
            return
    if node.lockstep:
        # the recorder gets the last status and the zero commands before the reliable
        # writers go (ladrc_contract.qos.wait_acknowledged); at most 2 s
        try:
            wait_acknowledged((node.pub_cmd, node.pub_status),
                              min(2.0, node.node_params.lockstep_timeout_s))
        except Exception:  # noqa: BLE001, S110 - the context may already be gone
            pass


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``ros2 run ladrc_follow follow_node --ros-args --params-file FILE``.

    A bad parameter file or value ends the start with one line on stderr and exit code 2.
    """
    return run_node('follow_node', _make_node, _run, args=argv,
                    check_args=params_file_problem, zero=_zero)


if __name__ == '__main__':
    sys.exit(main())
