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
QoS: see :mod:`ladrc_follow.node.qos`.

Safety: zero velocity with ``enable = false`` on stop, fault, shutdown, SIGINT and SIGTERM
(the node installs its own signal handlers so it can still publish the zero command before the
ROS context goes down).
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass
import functools
import gc
import math
import queue
import secrets
import signal
import sys
import threading
import time
from typing import Any, NamedTuple

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from ladrc_contract import qos
from ladrc_contract.cdr import CdrPacker
from ladrc_contract.codes import EventKind
from ladrc_contract.events import EventFields
from ladrc_contract.events import encode as encode_event
from ladrc_contract.loop_io import LoopNode
from ladrc_contract.qos import to_rclpy
from ladrc_contract.realtime import apply_realtime
from ladrc_contract.services import FOLLOW_SERVICES, command_args, service_class
from ladrc_contract.topics import (
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
    FollowEvent,
    FollowStatus,
    LockStep,
    VelocityCommand,
)
import numpy as np
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import String
import yaml

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
from ..control.schema import Entry, entries, field_problems, param
from .gate_process import GateProcess
from .housekeeping import Housekeeping
from .loops import run_loop
from .topology import TOPOLOGY_PERIOD_S, topology_problems

LOOP_MODES = ('sync', 'deadline', 'lockstep')


@dataclass(frozen=True)
class NodeParams:
    """Parameters of the node itself (not of the controller), fixed at start-up."""

    loop: str = param('deadline', '', "tick source: 'sync' (one tick per new sensor sample "
                      "pair, own deadline when one is late), 'deadline' (own 0.5 ms deadline "
                      "loop) or 'lockstep' (one tick per step of the sim node, on its clock; "
                      "the sim node only)",
                      choices=LOOP_MODES, runtime=False)
    sync_wait_s: float = param(0.00025, 's', "loop 'sync': a tick waits for a new sample of "
                               'both inputs at most one period plus this long after the '
                               'previous tick, then runs on its own deadline with what it '
                               'has (docs/follow-node.md)', gt=0.0, le=0.005, runtime=False)
    sample_period_tolerance: float = param(0.25, '1', "loop 'sync': the senders' sample "
                                           'period, measured from their seq over 2 s of '
                                           'receive time, may differ from h_s by this '
                                           'fraction; more is a FAULT (the core is '
                                           'discretised at h_s)', gt=0.0, le=0.9,
                                           runtime=False)
    lockstep_timeout_s: float = param(10.0, 's', "loop 'lockstep': no step from the sim for "
                                      'this long (wall clock) after the first one is a FAULT',
                                      gt=0.0, le=600.0, runtime=False)
    stamp_tolerance_s: float = param(0.01, 's', 'a sample whose sender stamp differs from '
                                     'its receive time by more than this (either way) is '
                                     'invalid: transport delay plus the clock offset of driver '
                                     'and controller must stay below it (docs/follow-node.md)',
                                     gt=0.0, le=1.0, runtime=False)
    diagnostics_period_s: float = param(1.0, 's', 'period of /diagnostics', ge=0.05, le=60.0,
                                        runtime=False)
    thread_priority: int = param(50, '1', 'SCHED_FIFO priority of the loop thread; 0 = the '
                                 'normal scheduler (a refusal is a warning, node/realtime.py)',
                                 ge=0, le=99, runtime=False)
    cpu: int = param(-1, '1', 'pin the process to this CPU; -1 = any', ge=-1, le=1023,
                     runtime=False)
    lock_memory: bool = param(True, '', 'mlockall: no page faults on the tick path',
                              runtime=False)
    hardware_id: str = param('z_axis', '', 'hardware_id of the /diagnostics status (named '
                             'after the node: <namespace/name>: follow loop)', runtime=False)


class _AcceptedSet(NamedTuple):
    """A set the parameter thread accepted, everything built, for the loop to apply at a tick."""

    params: ControllerParams
    prepared: PreparedSet
    text: str  # dump_params(params): the PARAMETERS event and run/parameters
    table: tuple[RawToGap | None] | None  # (the new table,) when the set changes it


_ROS_TYPE = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
             float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING}


def descriptor(entry: Entry) -> ParameterDescriptor:
    """Return the ROS descriptor of one declared parameter (type, range, unit, read-only)."""
    s = entry.spec
    unit = f' [{s.unit}]' if s.unit else ''
    seed = f' ({s.seed})' if s.seed else ''
    desc = ParameterDescriptor(name=entry.name, description=f'{s.description}{unit}{seed}',
                               read_only=not s.runtime)
    desc.type = _ROS_TYPE.get(entry.type, ParameterType.PARAMETER_DOUBLE_ARRAY)
    if s.range_text():
        desc.additional_constraints = ('one of ' if s.choices else 'range ') + s.range_text()
    if s.choices or s.lower is None or s.le is None:
        return desc
    if entry.type is int:
        desc.integer_range = [IntegerRange(from_value=int(s.lower), to_value=int(s.le), step=1)]
    elif entry.type is float:
        desc.floating_point_range = [FloatingPointRange(from_value=float(s.lower),
                                                        to_value=float(s.le), step=0.0)]
    return desc


def ros_value(entry: Entry, value: Any) -> Any:
    """Return a value as ROS wants it for this entry: floats for float fields, lists for arrays."""
    if entry.type is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, (tuple, list, array)) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        return [float(v) for v in value]
    return value  # anything else goes to rclpy's type check as it is


def sim_time_s(stamp_ns: int, period_ns: int, h_s: float) -> float:
    """Seconds of a lock-step stamp, exactly as the headless runner counts time (k * h_s).

    The sim's clock advances by whole periods: a stamp of step k (k * period_ns) gives
    ``k * h_s`` bit for bit (the runner's ``np.arange(n) * h_s``); a stamp between two steps
    adds its remainder.
    """
    k, rest_ns = divmod(stamp_ns, period_ns)
    return k * h_s + rest_ns * 1e-9 if rest_ns else k * h_s


def _defaults(packer: CdrPacker) -> list[Any]:
    """Zero values of a packer's leaf fields, of the right Python type each."""
    zero = {'string': '', 'bool': False, 'float32': 0.0, 'float64': 0.0}
    return [zero.get(kind, 0) for _, kind in packer.fields]


class FollowNode(LoopNode):
    """ROS 2 wrapper of :class:`FollowController` (see module docstring)."""

    def __init__(self) -> None:
        # ros2 param: served by the housekeeping thread, not the loop (node/housekeeping.py)
        super().__init__(DEFAULT_NODE_NAME, start_parameter_services=False)
        self._declaring = True
        self._entries = {e.name: e for e in entries(ControllerParams())}
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
        self.node_params = NodeParams(**{e.name: self.get_parameter(e.name).value
                                         for e in node_entries})
        reasons = field_problems(self.node_params)
        # The whole set, as loaded from the parameter file, must be valid to start.
        # sensor.table_file: the raw -> gap table (docs/calibration.md), None = gap_mm as sent
        self.cap_table: RawToGap | None = None
        self._last_sample: tuple[float, float, bool, int, bool] | None = None
        try:
            # the start-up set passes the stability gate here, in this process (the loop is
            # not running yet); a change at run time in the gate's process (gate_process.py)
            self.params = check_gate(self._params_from_ros({}))
            self.cap_table = self._load_table(self.params)
        except ParameterError as exc:
            reasons += exc.reasons
        if reasons:
            raise ParameterError(reasons)
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

        # Latest samples (zero-order hold), as plain values.
        # Freshness is judged from the controller's own receive time on the steady clock,
        # never from the sender's stamp alone (safety issue); t_s counts from here.
        self._t0_ns = time.monotonic_ns()
        self._clock = self.get_clock()  # ROS time for header stamps (use_sim_time applies)
        # diagnostic_updater's naming: the node's fully qualified name, then the task
        self._diag_name = f'{self.get_fully_qualified_name().lstrip("/")}: follow loop'
        self._stamp_tol_ns = int(self.node_params.stamp_tolerance_s * 1e9)
        # a sender stamp is judged against the reception time on the node clock: the
        # middleware's reception stamp (system clock) unless the node runs on /clock
        self._system_clock = not self.get_parameter('use_sim_time').value
        self.stamp_rejects = 0
        self.last_stamp_reject = ''  # the newest rejected stamp, for /diagnostics
        self.malformed_samples = 0  # samples whose bytes are not the contract's message
        self.tick_exceptions = 0
        self.realtime = 'none'  # what apply_realtime could set (main), for /diagnostics
        self.gap_seq = 0
        self.gap_mm = math.nan
        self.gap_valid = False
        self.gap_status = CapacitiveHeight.STATUS_FAULT
        self.gap_stamp_s = -math.inf
        self.enc_seq = 0
        self.enc_mm = math.nan
        self.enc_stamp_s = -math.inf
        self.drive_enabled = False
        self.drive_fault = False
        self._gap_last_seq = -1
        self._enc_last_seq = -1
        self.missed_gap_samples = 0
        self.missed_feedback_samples = 0
        # loop 'sync': a sample of each input for the coming tick's cycle has arrived. Each tick
        # consumes one cycle of each input (the seq it waits for next), also a tick on the own
        # deadline: a sample that comes after its cycle was ticked without it is held for the
        # next tick and starts none of its own (two ticks within one period would integrate
        # the core's h_s twice).
        self.new_gap = False
        self.new_feedback = False
        self._gap_expect = 0
        self._fb_expect = 0
        self.sync_wait_ns = int(round(self.node_params.sync_wait_s * 1e9))
        self.deadline_ticks = 0  # sync: ticks run on the own deadline (a sample was late)
        self._rate_window: tuple[int, int] | None = None  # (first seq, its receive ns)
        self.sample_period_s = math.nan  # measured from the feedback seq (loop 'sync')
        self._period_fault = ''
        # loop 'lockstep': the step being waited for, and when the last one came (wall clock)
        self.lockstep = self.loop_mode == 'lockstep'
        self._step: tuple[int, int, bool, int, bool, int] | None = None
        self._step_wall_ns = 0
        # One commander (docs/interfaces.md): this process' identity in every command.
        self.commander = self.get_fully_qualified_name()
        self.session = secrets.randbits(63) or 1
        self.sample_seq = 0  # the feedback sample (sync, deadline, timer) or step (lockstep)

        control_in = to_rclpy(qos.LOCKSTEP_INPUT if self.lockstep else qos.CONTROL_INPUT)
        high_rate = to_rclpy(qos.LOCKSTEP_HIGH_RATE if self.lockstep else qos.HIGH_RATE)
        # the loop thread's readers (node/loops.py): taken from straight, parsed to plain values
        self.gap_reader = self.create_loop_reader(CapacitiveHeight, GAP_TOPIC, control_in)
        self.fb_reader = self.create_loop_reader(AxisFeedback, FEEDBACK_TOPIC, control_in)
        self.step_reader = (self.create_loop_reader(LockStep, LOCKSTEP_TOPIC, control_in)
                            if self.lockstep else None)
        self._gap_cdr = CdrPacker('ladrc_msgs/msg/CapacitiveHeight')
        self._fb_cdr = CdrPacker('ladrc_msgs/msg/AxisFeedback')
        self._step_cdr = CdrPacker('ladrc_msgs/msg/LockStep')
        gi, fi = self._gap_cdr.index, self._fb_cdr.index
        self._gap_fields = [gi[n] for n in ('header.stamp.sec', 'header.stamp.nanosec', 'seq',
                                            'gap_mm', 'raw_hz', 'valid', 'status')]
        self._fb_fields = [fi[n] for n in ('header.stamp.sec', 'header.stamp.nanosec', 'seq',
                                           'position_mm', 'drive_enabled', 'drive_fault')]
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
        # refilled in place each tick.
        self._cmd_packer = CdrPacker('ladrc_msgs/msg/VelocityCommand')
        self._cmd_vals = _defaults(self._cmd_packer)
        cix = self._cmd_packer.index
        self._cix_answer = cix['sample_seq']
        self._cix_release = cix['release']
        self._cmd_vals[cix['commander']] = self.commander
        self._cmd_vals[cix['session']] = self.session
        self._st_packer = CdrPacker('ladrc_msgs/msg/FollowStatus')
        self._st_vals = _defaults(self._st_packer)
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
        self.tick_index = 0
        # Loop statistics (ring of periods for the 1 Hz percentiles).
        self._ring = np.zeros(4096)
        self._last_start_ns = 0
        self.overruns = 0
        self._age_max_us = 0.0
        self._ticks_at_diag = 0
        self._diag_t_ns = time.monotonic_ns()
        self.create_timer(self.node_params.diagnostics_period_s,
                          self._publish_diagnostics,
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

    def _publish_parameters(self, text: str) -> None:
        self._publish_event(EventFields(EventKind.PARAMETERS, text=text))
        self.pub_run_params.publish(String(data=text))

    # ---- parameters -------------------------------------------------------------------
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
        except ParameterError as exc:
            # Rejected: the running values stay.
            return SetParametersResult(successful=False, reason=str(exc))
        except Exception as exc:  # noqa: BLE001 - never let a parameter crash the node
            return SetParametersResult(successful=False,
                                       reason=f'rejected: {type(exc).__name__}: {exc}')
        # against the values set so far (queued or applied): the node's parameters
        table_changed = 'sensor.table_file' in changes or (
            candidate.sensor.table_file and candidate.follow.collision_gap_mm
            != self.get_parameter('follow.collision_gap_mm').value)
        table = None
        try:
            if table_changed:
                table = (self._load_table(candidate),)
            accepted = _AcceptedSet(candidate, self.controller.prepare(candidate),
                                    dump_params(candidate), table)
        except ParameterError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        except Exception as exc:  # noqa: BLE001
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
                self.cap_table = accepted.table[0]
                if self._last_sample is not None:  # the held sample, through the new table
                    self._set_gap(*self._last_sample)
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

    # ---- inputs (the loop thread) --------------------------------------------------------
    def take_samples(self) -> None:
        """Take what waits in the readers (oldest first) into the latest-sample values."""
        for reader, on in ((self.gap_reader, self._on_gap), (self.fb_reader, self._on_feedback),
                           (self.step_reader, self._on_step)):
            if reader is None:
                continue
            while (taken := reader.take()) is not None:
                on(*taken)

    def _parse(self, packer: CdrPacker, data: bytes) -> list[Any] | None:
        """Leaf values of a sample's CDR; None (counted) when the bytes are not the message."""
        try:
            return packer.unpack(data)
        except ValueError:
            self.malformed_samples += 1
            return None

    def _receive(self, topic: str, stamp_ns: int, received_ns: int) -> tuple[float, bool]:
        """Return the receive time (s since start, steady clock) and the stamp's plausibility.

        Plausible: the sender's stamp is within ``stamp_tolerance_s`` of the node clock at
        reception (ROS time: the middleware's reception stamp on the system clock, or /clock
        with ``use_sim_time``; not in the future, not delayed or skewed by more than that).
        The receive time is that reception, on the steady clock: a loop that takes the sample
        late does not make it look older than it is, nor fresher.

        Lock step: the sample time is the sender's stamp on the sim's clock
        (:func:`sim_time_s`); its age is judged by the core at the step's tick.
        """
        if self.lockstep:
            return sim_time_s(stamp_ns, self.period_ns, self.h_s), True
        mono = time.monotonic_ns()
        if self._system_clock:
            # how long ago it arrived (a clock step in between counts as now)
            ago_ns = min(max(time.time_ns() - received_ns, 0), 1_000_000_000)
            reference_ns = received_ns
        else:
            ago_ns, reference_ns = 0, self._clock.now().nanoseconds
        skew_ns = stamp_ns - reference_ns
        ok = -self._stamp_tol_ns <= skew_ns <= self._stamp_tol_ns
        if not ok:
            self.stamp_rejects += 1
            self.last_stamp_reject = (
                f'{topic} stamp {skew_ns * 1e-6:+.3f} ms from its reception on the node clock '
                f'(tolerance {self._stamp_tol_ns * 1e-6:g} ms)')
        return (mono - ago_ns - self._t0_ns) * 1e-9, ok

    def _on_gap(self, data: bytes, received_ns: int) -> None:
        values = self._parse(self._gap_cdr, data)
        if values is None:
            return
        sec, nsec, seq, gap_mm, raw_hz, valid, status = (values[i] for i in self._gap_fields)
        if self._gap_last_seq >= 0 and seq > self._gap_last_seq + 1:
            self.missed_gap_samples += seq - self._gap_last_seq - 1
        self._gap_last_seq = seq
        self.gap_seq = seq
        if seq >= self._gap_expect or seq + 64 < self._gap_expect:  # (a restarted sender)
            self.new_gap = True
        self.gap_stamp_s, stamp_ok = self._receive(GAP_TOPIC, sec * 1_000_000_000 + nsec,
                                                   received_ns)
        self._last_sample = (gap_mm, raw_hz, valid, status, stamp_ok)
        self._set_gap(*self._last_sample)

    def _set_gap(self, gap_mm: float, raw_hz: float, valid: bool, status: int,
                 stamp_ok: bool) -> None:
        table = self.cap_table
        if table is None:
            self.gap_mm = gap_mm
            self.gap_valid = valid and stamp_ok
            self.gap_status = status if stamp_ok else CapacitiveHeight.STATUS_FAULT
        else:
            # the controller converts raw -> gap (docs/calibration.md); outside the table:
            # invalid, never extrapolated
            gap, ok, st = table.convert(raw_hz, valid, status)
            self.gap_mm = gap
            self.gap_valid = ok and stamp_ok
            self.gap_status = st if stamp_ok else CapacitiveHeight.STATUS_FAULT

    def _on_feedback(self, data: bytes, received_ns: int) -> None:
        values = self._parse(self._fb_cdr, data)
        if values is None:
            return
        sec, nsec, seq, position_mm, enabled, fault = (values[i] for i in self._fb_fields)
        if self._enc_last_seq >= 0 and seq > self._enc_last_seq + 1:
            self.missed_feedback_samples += seq - self._enc_last_seq - 1
        self._enc_last_seq = seq
        self.enc_seq = seq
        if seq >= self._fb_expect or seq + 64 < self._fb_expect:  # (a restarted sender)
            self.new_feedback = True
        if self.loop_mode == 'sync':
            self._check_sample_period(seq)
        self.enc_stamp_s, stamp_ok = self._receive(FEEDBACK_TOPIC, sec * 1_000_000_000 + nsec,
                                                   received_ns)
        self.enc_mm = position_mm if stamp_ok else math.nan  # not finite: a fault
        self.drive_enabled = enabled
        self.drive_fault = fault

    def _check_sample_period(self, seq: int) -> None:
        """Loop 'sync': the feedback's sample period (seq over receive time, 2 s) against h_s.

        The core is discretised at h_s: ticks on samples of another period would integrate the
        observer and the reference at the wrong rate. Counted from the sender's seq over this
        node's own receive clock, so neither the sender's stamps nor one late sample decide.
        """
        now = time.monotonic_ns()
        if self._rate_window is None or seq <= self._rate_window[0]:
            self._rate_window = (seq, now)
            return
        seq0, t0 = self._rate_window
        if now - t0 < 2_000_000_000:
            return
        self._rate_window = (seq, now)
        self.sample_period_s = (now - t0) * 1e-9 / (seq - seq0)
        deviation = self.sample_period_s / self.h_s - 1.0
        if abs(deviation) <= self.node_params.sample_period_tolerance:
            self._period_fault = ''  # back within tolerance: a reset clears the fault
        elif not self._period_fault:
            self._period_fault = (
                f'sample period {self.sample_period_s * 1e3:.3f} ms of axis/feedback differs '
                f'from the controller period h_s {self.h_s * 1e3:g} ms by {deviation:+.0%} '
                f'(tolerance {self.node_params.sample_period_tolerance:.0%}): the core is '
                'discretised at h_s')

    def _on_step(self, data: bytes, received_ns: int) -> None:
        """Lock step: the sim published step ``step``; tick once its samples are here."""
        values = self._parse(self._step_cdr, data)
        if values is None:
            return
        sec, nsec, _frame, step, gap_seq, gap_fresh, enc_seq, enc_fresh = values
        self._step = (step, gap_seq, gap_fresh, enc_seq, enc_fresh, sec * 1_000_000_000 + nsec)
        self._step_wall_ns = time.monotonic_ns()

    def step_ready(self) -> bool:
        """Lock step: a step is waiting and the samples it names have arrived.

        With a topology problem (another publisher may have superseded a sample) the step is
        answered without them: the tick faults and commands zero.
        """
        s = self._step
        return s is not None and (bool(self.topology_problem) or (
            (not s[2] or self._gap_last_seq == s[1]) and (not s[4] or self._enc_last_seq == s[3])))

    def tick_step(self) -> None:
        """Lock step: tick k of step k, at the sim's time k h_s (runner convention)."""
        step, stamp_ns = self._step[0], self._step[5]
        self._step = None
        self.tick_index = step
        self.sample_seq = step
        self.tick(step * self.h_s, stamp_ns)

    def tick_sync(self) -> None:
        """Loop 'sync': tick on the samples received (both new, or the deadline came)."""
        if not (self.new_gap and self.new_feedback):
            self.deadline_ticks += 1
        self._gap_expect = self.gap_seq + 1 if self.new_gap else self._gap_expect + 1
        self._fb_expect = self.enc_seq + 1 if self.new_feedback else self._fb_expect + 1
        self.new_gap = self.new_feedback = False
        self.tick(fail=self._period_fault)

    # ---- the tick ---------------------------------------------------------------------
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
                self.controller.fail(fail)
            self._tick(t_s, stamp_ns)

    def _tick(self, t_s: float | None, stamp_ns: int | None) -> None:
        start_mono = time.monotonic_ns()
        # header stamps: the node clock (ROS time)
        now_ns = self._clock.now().nanoseconds if stamp_ns is None else stamp_ns
        if not self._accepted.empty():
            self._apply_accepted()
        if self.topology_problem and self.controller.state != FollowState.FAULT:
            self.controller.fail(f'topology: {self.topology_problem}')
        if t_s is None:
            t_s = (start_mono - self._t0_ns) * 1e-9
            self.sample_seq = self.enc_seq
        gap_stamp_s, enc_stamp_s = self.gap_stamp_s, self.enc_stamp_s
        tick = TickInput(t_s, self.gap_mm, self.gap_valid, gap_stamp_s, self.enc_mm,
                         enc_stamp_s, self.drive_enabled, self.drive_fault, self.gap_status)
        controller = self.controller
        velocity = controller.step(tick)
        enable = bool(controller.enable)
        velocity = float(velocity) if enable else 0.0

        sec, nsec = divmod(now_ns, 1_000_000_000)
        cmd = self._cmd_vals  # header.stamp.sec, .nanosec, .frame_id, seq, velocity, enable
        cmd[0], cmd[1], cmd[3], cmd[4], cmd[5] = sec, nsec, self.tick_index, velocity, enable
        cmd[self._cix_answer] = self.sample_seq
        self.pub_cmd.publish(self._cmd_packer.pack(cmd))
        compute_ns = time.monotonic_ns() - start_mono

        period_ns = start_mono - self._last_start_ns if self._last_start_ns else self.period_ns
        self._last_start_ns = start_mono
        self._ring[self.tick_index & 4095] = period_ns * 1e-3
        overrun = period_ns > 2 * self.period_ns and not self.lockstep
        if overrun:
            self.overruns += 1
        age_us = (t_s - min(gap_stamp_s, enc_stamp_s)) * 1e6
        if age_us > self._age_max_us:
            self._age_max_us = age_us

        st = self._st_vals
        ix = self._ix
        for name, value in controller.internals().items():
            st[ix[name]] = value
        st[0], st[1], st[3] = sec, nsec, self.tick_index
        values = (t_s, self.gap_seq, self.gap_mm, self.gap_valid, self.gap_status, gap_stamp_s,
                  self.enc_seq, self.enc_mm, enc_stamp_s, self.drive_enabled, self.drive_fault,
                  velocity, period_ns * 1e-3, compute_ns * 1e-3,
                  age_us if math.isfinite(age_us) else -1.0, overrun, self.sample_seq)
        for i, value in zip(self._ix_inputs, values, strict=True):
            st[i] = value
        self.pub_status.publish(self._st_packer.pack(st))
        self.tick_index += 1

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

    # ---- diagnostics ------------------------------------------------------------------
    def loop_statistics(self) -> dict[str, float]:
        """Rate, period percentiles, overruns, input age since the last call."""
        now = time.monotonic_ns()
        elapsed = (now - self._diag_t_ns) * 1e-9
        ticks = self.tick_index - self._ticks_at_diag
        self._diag_t_ns, self._ticks_at_diag = now, self.tick_index
        n = min(ticks, 4096, self.tick_index)
        idx = (np.arange(self.tick_index - n, self.tick_index) & 4095) if n else []
        periods = self._ring[idx] if n else np.zeros(1)
        age, self._age_max_us = self._age_max_us, 0.0
        return {
            'rate_hz': ticks / elapsed if elapsed > 0 else 0.0,
            'period_p50_us': float(np.percentile(periods, 50)),
            'period_p99_us': float(np.percentile(periods, 99)),
            'period_max_us': float(periods.max()),
            'overruns': float(self.overruns),
            'input_age_max_us': age,
            'missed_gap_samples': float(self.missed_gap_samples),
            'stamp_rejects': float(self.stamp_rejects),
            'malformed_samples': float(self.malformed_samples),
            'tick_exceptions': float(self.tick_exceptions),
            **{f'samples_{k}': float(v) for k, v in self.controller.counts.items()},
            'missed_feedback_samples': float(self.missed_feedback_samples),
            'deadline_ticks': float(self.deadline_ticks),
            'sample_period_ms': self.sample_period_s * 1e3,
        }

    def _publish_diagnostics(self) -> None:
        stats = self.loop_statistics()
        ctl = self.controller
        status = DiagnosticStatus()
        status.name = self._diag_name
        status.hardware_id = self.node_params.hardware_id
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
        values = {k: f'{v:.6g}' for k, v in stats.items()}
        values.update({'state': state, 'fault_reason': ctl.fault_reason or '',
                       'ticks': str(self.tick_index), 'loop': self.loop_mode,
                       'realtime': self.realtime, 'topology': self.topology_problem or 'ok',
                       'last_stamp_reject': self.last_stamp_reject or 'none',
                       'cap_table': (self.cap_table.describe() if self.cap_table is not None
                                     else 'none (gap_mm as published)'),
                       'cap_table_out_of_range': str(self.cap_table.out_of_range
                                                     if self.cap_table is not None else 0)})
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [status]
        self.pub_diag.publish(arr)


def params_file_problem(args: list[str]) -> str:
    """Return why a ``--params-file`` of the command line cannot be read ('' when all can).

    rcl would refuse a malformed file with a log line of its own and an exception; reading the
    files first gives the user one line that names the file.
    """
    for flag, path in zip(args, args[1:], strict=False):
        if flag != '--params-file':
            continue
        try:
            with open(path, encoding='utf-8') as f:
                yaml.safe_load(f)
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
            return f'parameter file {path}: ' + ' '.join(str(exc).split())
    return ''


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``ros2 run ladrc_follow follow_node --ros-args --params-file FILE``.

    A bad parameter file or value ends the start with one line on stderr and exit code 2.
    """
    problem = params_file_problem(sys.argv if argv is None else argv)
    if problem:
        print(f'follow_node: {problem}', file=sys.stderr)
        return 2
    try:
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # noqa: BLE001 - e.g. rcl cannot parse the parameter file
        text = ' '.join(str(exc).split())
        print(f'follow_node: cannot start: {type(exc).__name__}: {text}', file=sys.stderr)
        return 2
    running = [True]
    stop_reason = ['shutdown']

    def _stop(signum, _frame):
        running[0] = False
        stop_reason[0] = signal.Signals(signum).name

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    node = None
    try:
        try:
            node = FollowNode()
        except ParameterError as exc:
            print(f'follow_node: invalid parameters: {" | ".join(exc.reasons)}',
                  file=sys.stderr)
            return 2
        np_ = node.node_params
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
        node.housekeeping.start(np_.thread_priority - 1 if fifo else 0)
        node.get_logger().info(f'following loop started ({node.loop_mode}, '
                               f'{1.0 / node.h_s:.0f} Hz)')
        # Everything alive now (node, controller, generated code) leaves the collector's
        # reach: a full collection must not stall the 2 kHz loop.
        gc.collect()
        gc.freeze()
        try:
            run_loop(node, running)
        except ExternalShutdownException:
            stop_reason[0] = 'external shutdown'
        finally:
            # Zero velocity before anything goes down, however the loop ended.
            for i in range(3):
                try:
                    node.publish_zero(stop_reason[0], log=i == 0, release=i == 2)
                except Exception:  # noqa: BLE001 - the context may already be gone
                    break
        return 0
    finally:
        if node is not None:
            node.housekeeping.close()
            node.gate.close()
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
