"""The live prober of ``ladrc conform``: a driver on the ROS graph, checked against the contract.

:class:`ConformProbe` is one rclpy node (``ladrc_conform``) that

* takes the driver's ``axis/capacitive_height`` and ``axis/feedback`` straight from their DDS
  readers (raw CDR with the middleware's message info: reception time, writer sequence), by
  polling from its own 2 kHz deadline loop, with no executor (a Python executor cannot keep up
  with 2 kHz topics on a 2-core machine: tests/support/rosnodes.py, docs/follow-node.md);
* reads the graph: the driver's publishers and subscription, their types and QoS;
* plays the motion tests of a :class:`~ladrc_tools.commissioning.conformance.Plan` (enable
  false, up then down, one excitation segment of
  :class:`~ladrc_tools.commissioning.excitation.Excitation`, the watchdog) as velocity
  commands at 2 kHz, at a safe height only, bounded in travel and speed, and aborts on any
  surprise with a zero command and ``enable=false``;
* records everything it saw and sent, raw CDR with the reception (or send) time, and writes
  it as a bag with the project's writer (:class:`ladrc_bags.BagWriter`, as the
  recorder node does) once the motion has ended: a writer thread in this process would hold
  the GIL for milliseconds while it compresses a chunk, and a command stream that stalls 5 ms
  trips the drive's watchdog (seen in the first runs: 7.9 ms gaps). A run is ~10 s, a few MB.

``ladrc conform`` itself (start the driver, run this probe, evaluate, write) is
:mod:`.conform_run`.
"""

from __future__ import annotations

from collections import deque
import dataclasses
import gc
import json
import math
from pathlib import Path
import secrets
import time
from typing import Callable

from ladrc_bags import BagError, BagWriter, open_bag
from ladrc_tools.commissioning.conformance import (
    AFTER_RESET,
    COMMAND_TOPIC,
    CONTRACT_TYPES,
    CONTRACT_WRITER,
    DOWN,
    ENABLE,
    EXCITATION,
    FAULT_HOLDS,
    FEEDBACK_TOPIC,
    GAP_TOPIC,
    H_S,
    PASSIVE,
    RESET_CALL,
    RESET_SERVICE,
    SECOND_COMMANDER,
    SILENCE,
    STATUS_OK,
    UP,
    WATCHDOG,
    BagCheck,
    Endpoint,
    FeedbackSamples,
    GapSamples,
    Graph,
    Plan,
    Recording,
    Segment,
    Tolerances,
    compatible,
)
import numpy as np

NODE_NAME = 'ladrc_conform'
PERIOD_NS = int(round(H_S * 1e9))
READER_DEPTH = 10000  # 5 s of a 2 kHz topic: the loop polls far more often than that
SPEED_WINDOW_NS = 10_000_000  # the speed bound is judged over >= 10 ms of encoder travel
SPEED_PERSIST_NS = 2_000_000  # ... in every window for 2 ms (SpeedGuard)
MAX_PLAUSIBLE_GAP_MM = 50.0  # beyond any capacitive height sensor: a reading not in mm
# aborts that a stall of the host causes as well as a driver: the motion tests are repeated
RETRYABLE = ('stale data', 'drive fault during the test')
# the one-commander test (rule one_commander): how long each part lasts
SECOND_COMMANDER_S = 0.02  # 40 upward commands under another name, interleaved with ours
FAULT_HOLDS_S = 0.2  # longer than the sim's self-clearing of a watchdog fault (0.1 s)
RESET_WAIT_S = 1.0  # the reset service's answer
AFTER_RESET_S = 0.2
SECOND_COMMANDER_NAME = '/ladrc_conform_second_commander'
BAG_TOPICS = (GAP_TOPIC, FEEDBACK_TOPIC, COMMAND_TOPIC, '/diagnostics', 'run/scenario')


class SpeedGuard:
    """The prober's speed bound: the encoder's travel over >= 10 ms of reception time.

    The speed must stay beyond the bound for ``SPEED_PERSIST_NS`` of windows before the run
    aborts: one sample the driver sent late (its process stalled between taking the position
    and sending it, milliseconds on a loaded machine) starts a window with an old position,
    and that one window reads up to (10 ms + stall) / 10 ms x the true speed (10.94 mm/s for
    6 mm/s after an 8 ms stall); the next window starts on the caught-up sample. A runaway axis
    stays beyond the bound and is stopped 2 ms later than on its first window.
    """

    def __init__(self, max_speed_mm_s: float) -> None:
        self.max_speed_mm_s = max_speed_mm_s
        self._window: deque[tuple[int, float]] = deque()
        self._over_ns = -1  # reception time of the first window beyond the bound, -1: none

    def clear(self) -> None:
        """Forget the samples (the motion restarts)."""
        self._window.clear()
        self._over_ns = -1

    def feed(self, recv_ns: int, pos_mm: float) -> str:
        """Take one encoder sample; return why the run must abort ('' = within the bound)."""
        win = self._window
        win.append((recv_ns, pos_mm))
        while len(win) > 2 and recv_ns - win[1][0] >= SPEED_WINDOW_NS:
            win.popleft()
        t0, p0 = win[0]
        if recv_ns - t0 < SPEED_WINDOW_NS:
            return ''
        speed = abs(pos_mm - p0) / ((recv_ns - t0) * 1e-9)
        if speed <= self.max_speed_mm_s:
            self._over_ns = -1
            return ''
        if self._over_ns < 0:
            self._over_ns = recv_ns
        if recv_ns - self._over_ns < SPEED_PERSIST_NS:
            return ''
        return (f'speed beyond the bound: {speed:.2f} mm/s over {(recv_ns - t0) * 1e-6:.0f} ms, '
                f'for {(recv_ns - self._over_ns) * 1e-6:.1f} ms of windows '
                f'(bound {self.max_speed_mm_s:g} mm/s)')


class ConformError(Exception):
    """A run could not be made (bad options, driver would not start); one line."""


def _endpoint(info) -> Endpoint:
    q = info.qos_profile
    node = f'{info.node_namespace.rstrip("/")}/{info.node_name}'
    return Endpoint(node, info.topic_type, getattr(q.reliability, 'name', str(q.reliability)),
                    getattr(q.durability, 'name', str(q.durability)))


class ConformProbe:
    """The prober node: graph, samples, motion tests, bag (see the module docstring)."""

    def __init__(self, context, plan: Plan, tolerances: Tolerances, bag_path: Path,
                 log: Callable[[str], None] = print) -> None:
        from ladrc_contract import qos
        from ladrc_contract.qos import to_rclpy
        from ladrc_msgs.msg import AxisFeedback, CapacitiveHeight, VelocityCommand
        import rclpy

        self.plan, self.tol, self.log = plan, tolerances, log
        self._qos = qos
        self.node = rclpy.create_node(NODE_NAME, context=context)
        self._clock = self.node.get_clock()
        # Best-effort readers match any writer (docs/conformance.md, "QoS"); depth is not part
        # of matching, so a deep history still receives what a keep-last-1 reader would.
        reader = to_rclpy(qos.HIGH_RATE.with_depth(READER_DEPTH))
        self._types = {GAP_TOPIC: CapacitiveHeight, FEEDBACK_TOPIC: AxisFeedback}
        self._subs = {t: self.node.create_subscription(c, t, lambda _m: None, reader, raw=True)
                      for t, c in self._types.items()}
        from diagnostic_msgs.msg import DiagnosticArray
        from std_msgs.msg import String

        self._extra_subs = {
            '/diagnostics': self.node.create_subscription(
                DiagnosticArray, '/diagnostics', lambda _m: None,
                to_rclpy(qos.DIAGNOSTICS.with_depth(100)), raw=True),
            'run/scenario': self.node.create_subscription(
                String, 'run/scenario', lambda _m: None, to_rclpy(qos.RUN_TEXT), raw=True)}
        self._VelocityCommand = VelocityCommand
        self._cmd = VelocityCommand()
        self._cmd.header.frame_id = 'conform'
        # one commander (docs/interfaces.md): the prober commands the axis under its own identity
        # and releases it with its last command (a handover, docs/conformance.md)
        self._cmd.commander = self.node.get_fully_qualified_name()
        self._cmd.session = secrets.randbits(63) or 1
        # the second commander of the one-commander test: another writer, another name
        self._second = VelocityCommand()
        self._second.header.frame_id = 'conform'
        self._second.commander = SECOND_COMMANDER_NAME
        self._second.session = secrets.randbits(63) or 1
        self.second_send: list[int] = []
        self.reset_answer = ''
        from ladrc_msgs.srv import ResetFault
        from rclpy.executors import SingleThreadedExecutor

        # the reset client on a node of its own, spun by its own executor: the prober's node
        # has no executor (its readers are taken from directly, see the module docstring)
        self._ResetFault = ResetFault
        self._reset_node = rclpy.create_node(NODE_NAME + '_reset', context=context)
        self._reset_client = self._reset_node.create_client(ResetFault, RESET_SERVICE)
        self._reset_executor = SingleThreadedExecutor(context=context)
        self._reset_executor.add_node(self._reset_node)
        self._pub = None
        self._pub2 = None
        self.command_qos = ''
        self.bag_path = Path(bag_path)
        self._bag_items: list[tuple[str, bytes, int]] = []  # (topic, CDR, bag time ns)
        self.enqueued = {('/' + t.lstrip('/')): 0 for t in BAG_TOPICS}
        # what was received, one list per field (scalars only: nothing for the collector)
        self.g = {k: [] for k in ('recv', 'stamp', 'seq', 'pub', 'gap', 'valid', 'status')}
        self.f = {k: [] for k in ('recv', 'stamp', 'seq', 'pub', 'pos', 'vel', 'enabled',
                                  'fault', 'reason')}
        self.c = {k: [] for k in ('send', 'vel', 'enable')}
        self.segments: list[Segment] = []
        self.graph = Graph()
        self._excitation: np.ndarray | None = None  # the profile, computed before the motion
        self.aborted = ''
        self.not_run = ''
        self.notes: list[str] = []
        self._deadline = 0
        self._cmd_seq = 0
        self._gap_cursor = 0
        self._fb_cursor = 0
        self._pos0 = math.nan
        self._speed = SpeedGuard(plan.max_speed_mm_s)
        self._fault_expected = False
        self._alive: Callable[[], bool] = lambda: True
        self._ticks = 0

    # ---- receiving -------------------------------------------------------------------------
    def _enqueue(self, topic: str, data: bytes, stamp_ns: int) -> None:
        self._bag_items.append((topic, data, stamp_ns))

    def poll(self) -> None:
        """Take every sample waiting in the readers into the lists and the bag queue."""
        from rclpy.serialization import deserialize_message

        if SIGNALLED:
            raise KeyboardInterrupt(SIGNALLED.pop())  # once; the clean-up polls on
        enqueue = self._enqueue
        for topic, sub in self._subs.items():
            cls = self._types[topic]
            gap = topic == GAP_TOPIC
            d = self.g if gap else self.f
            with sub.handle:
                while (taken := sub.handle.take_message(sub.msg_type, True)) is not None:
                    data, info = taken
                    recv = int(info.get('received_timestamp') or time.time_ns())
                    msg = deserialize_message(data, cls)
                    d['recv'].append(recv)
                    d['stamp'].append(msg.header.stamp.sec * 1_000_000_000
                                      + msg.header.stamp.nanosec)
                    d['seq'].append(int(msg.seq))
                    d['pub'].append(int(info.get('publication_sequence_number') or 0))
                    if gap:
                        d['gap'].append(msg.gap_mm)
                        d['valid'].append(msg.valid)
                        d['status'].append(msg.status)
                    else:
                        d['pos'].append(msg.position_mm)
                        d['vel'].append(msg.velocity_mm_s)
                        d['enabled'].append(msg.drive_enabled)
                        d['fault'].append(msg.drive_fault)
                        d['reason'].append(msg.fault_reason)
                    enqueue(topic, data, recv)
                    self.enqueued['/' + topic] += 1
        for topic, sub in self._extra_subs.items():
            with sub.handle:
                while (taken := sub.handle.take_message(sub.msg_type, True)) is not None:
                    data, info = taken
                    enqueue(topic, data, int(info.get('received_timestamp') or time.time_ns()))
                    self.enqueued['/' + topic.lstrip('/')] += 1

    def _wait(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.poll()
            time.sleep(0.005)

    # ---- the graph ----------------------------------------------------------------------------
    def read_graph(self) -> Graph:
        """Return the driver's endpoints on the three contract topics (this node left out)."""
        me = f'/{NODE_NAME}'
        g = Graph()
        for topic in (GAP_TOPIC, FEEDBACK_TOPIC, COMMAND_TOPIC):
            name = '/' + topic
            g.publishers[topic] = [e for e in map(
                _endpoint, self.node.get_publishers_info_by_topic(name)) if e.node != me]
            g.subscriptions[topic] = [e for e in map(
                _endpoint, self.node.get_subscriptions_info_by_topic(name)) if e.node != me]
        return g

    def discover(self, timeout_s: float, alive: Callable[[], bool]) -> bool:
        """Wait for the driver's endpoints and a first sample of each topic; keep the graph."""
        self._alive = alive
        deadline = time.monotonic() + timeout_s
        ready = False
        while time.monotonic() < deadline and alive():
            self.poll()
            g = self.read_graph()
            ready = (bool(g.publishers[GAP_TOPIC]) and bool(g.publishers[FEEDBACK_TOPIC])
                     and bool(g.subscriptions[COMMAND_TOPIC]) and bool(self.g['recv'])
                     and bool(self.f['recv']))
            if ready:
                break
            time.sleep(0.02)
        if ready:
            self._wait_steady(min(5.0, max(0.5, deadline - time.monotonic())))
        self._wait(0.2)  # the graph settles (a second endpoint shows up late)
        self.graph = self.read_graph()
        return ready

    def _wait_steady(self, timeout_s: float) -> bool:
        """Wait until both topics have arrived steadily for 0.1 s (no gap over 20 ms).

        Right after matching, the middleware delivers a stale backlog and then pauses
        (seen: 333 ms); the passive window starts after that.
        """
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            self.poll()
            steady = True
            for d in (self.g, self.f):
                recv = d['recv'][-200:]
                if len(recv) < 200 or time.time_ns() - recv[-1] > 20_000_000:
                    steady = False
                    break
                gaps = np.diff(np.asarray(recv))
                steady = steady and recv[-1] - recv[0] <= 200_000_000 and gaps.max() < 2e7
            if steady:
                return True
            time.sleep(0.01)
        return False

    # ---- commanding -------------------------------------------------------------------------
    def _make_publisher(self) -> str:
        """Create the command publisher: the contract's QoS, or what the driver's input needs."""
        from ladrc_contract.qos import to_rclpy

        subs = self.graph.subscriptions.get(COMMAND_TOPIC, [])
        bad = [e for e in subs if not compatible(CONTRACT_WRITER, e)[0]]
        profile = to_rclpy(self._qos.HIGH_RATE)
        self.command_qos = 'BEST_EFFORT, VOLATILE (the contract)'
        if bad:
            # Measure the other rules anyway: a RELIABLE writer matches both kinds of reader.
            durable = any(e.durability == 'TRANSIENT_LOCAL' for e in bad)
            # reliable (transient local if the reader is): the events' or the lock step's
            profile = to_rclpy(self._qos.EVENTS if durable
                               else self._qos.LOCKSTEP_HIGH_RATE.with_depth(100))
            self.command_qos = ('RELIABLE' + (', TRANSIENT_LOCAL' if durable else '')
                                + ": the driver's command input does not take the contract's "
                                'best-effort commands (qos_command_input); the motion tests '
                                'ran with a writer it accepts')
            self.notes.append(f'commands sent {self.command_qos}')
        self._pub = self.node.create_publisher(self._VelocityCommand, COMMAND_TOPIC, profile)
        self._pub2 = self.node.create_publisher(self._VelocityCommand, COMMAND_TOPIC, profile)
        end = time.monotonic() + 5.0
        while self._pub.get_subscription_count() == 0 and time.monotonic() < end:
            self._wait(0.02)
        if self._pub.get_subscription_count() == 0:
            return "the driver's command subscription never matched the prober's publisher"
        self._wait(0.3)  # the driver's side of the match
        return ''

    def _now_ns(self) -> int:
        return self._clock.now().nanoseconds

    def _send(self, velocity_mm_s: float, enable: bool) -> None:
        from rclpy.serialization import serialize_message

        vmax = self.plan.max_speed_mm_s
        v = float(min(vmax, max(-vmax, velocity_mm_s)))  # never more than the bound
        now = self._now_ns()
        m = self._cmd
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(now, 1_000_000_000)
        m.seq = self._cmd_seq
        m.velocity_mm_s = v
        m.enable = bool(enable)
        data = serialize_message(m)
        self._pub.publish(data)
        self._cmd_seq += 1
        self.c['send'].append(now)
        self.c['vel'].append(v)
        self.c['enable'].append(bool(enable))
        self._enqueue(COMMAND_TOPIC, data, now)
        self.enqueued['/' + COMMAND_TOPIC] += 1

    def _send_second(self, velocity_mm_s: float) -> None:
        """Send one command of the second commander (its own writer and name)."""
        from rclpy.serialization import serialize_message

        vmax = self.plan.max_speed_mm_s
        now = self._now_ns()
        m = self._second
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(now, 1_000_000_000)
        m.seq = len(self.second_send)
        m.velocity_mm_s = float(min(vmax, max(-vmax, velocity_mm_s)))
        m.enable = True
        data = serialize_message(m)
        self._pub2.publish(data)
        self.second_send.append(now)
        self._enqueue(COMMAND_TOPIC, data, now)
        self.enqueued['/' + COMMAND_TOPIC] += 1

    def _tick(self) -> None:
        """Wait for the next 0.5 ms deadline (skip ahead when late), then take the samples."""
        self._deadline += PERIOD_NS
        now = time.monotonic_ns()
        if self._deadline > now:
            time.sleep((self._deadline - now) * 1e-9)
        elif now - self._deadline > PERIOD_NS:
            self._deadline = now
        self.poll()
        self._ticks += 1

    def stop_commands(self, seconds: float = 0.05, release: bool = False) -> None:
        """Send zero with enable=false for ``seconds`` (every exit path ends here).

        ``release``: the last one releases the axis (the prober's last command).
        """
        if self._pub is None:
            return
        try:
            self._stop_commands(seconds)
        finally:
            if release:
                self._cmd.release = True
                self._send(0.0, False)
                self._cmd.release = False

    def _stop_commands(self, seconds: float) -> None:
        self._deadline = time.monotonic_ns()
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self._send(0.0, False)  # first: reading samples must not keep the zero from going
            try:
                self._tick()
            except Exception:  # noqa: BLE001 - a broken sample cannot stop the stop
                time.sleep(H_S)

    # ---- the safety checks ----------------------------------------------------------------
    def _check(self) -> str:
        """Return the surprise in the samples since the last check ('' = none)."""
        p = self.plan
        now = time.time_ns()
        stale_ns = int(p.stale_s * 1e9)
        for name, d in (('gap reading', self.g), ('feedback', self.f)):
            if now - d['recv'][-1] > stale_ns:
                return (f'stale data: no {name} for {(now - d["recv"][-1]) * 1e-6:.0f} ms '
                        f'(bound {p.stale_s * 1e3:g} ms)')
            # a driver that re-sends its last sample (acquisition hung) is stale too: the
            # sender's stamp must advance within the bound
            n_recent = min(len(d['stamp']), int(p.stale_s / H_S) + 2)
            if n_recent >= int(p.stale_s / H_S) + 2 and d['stamp'][-1] == d['stamp'][-n_recent]:
                return (f'stale data: the {name} stamp has not advanced for {n_recent} samples '
                        '(a driver re-sending its last sample?)')
        g = self.g
        for i in range(self._gap_cursor, len(g['recv'])):
            gap, status = g['gap'][i], g['status'][i]
            if not (g['valid'][i] and status == STATUS_OK and math.isfinite(gap)):
                return f'gap reading invalid (valid={g["valid"][i]}, status {status}, {gap} mm)'
            if gap < p.min_gap_mm:
                return f'gap {gap:.3f} mm below the minimum {p.min_gap_mm:g} mm'
        self._gap_cursor = len(g['recv'])
        f = self.f
        speed = self._speed
        for i in range(self._fb_cursor, len(f['recv'])):
            pos, recv = f['pos'][i], f['recv'][i]
            if not math.isfinite(pos) or abs(pos - self._pos0) > p.max_travel_mm:
                return (f'travel beyond the bound: encoder {pos - self._pos0:+.3f} mm from the '
                        f'start (bound ±{p.max_travel_mm:g} mm)')
            why = speed.feed(recv, pos)
            if why:
                return why
            if f['fault'][i] and not self._fault_expected:
                return f'drive fault during the test: {f["reason"][i] or "no reason given"}'
        self._fb_cursor = len(f['recv'])
        if self._ticks % 200 == 0 and not self._alive():
            return 'the driver process exited'
        return ''

    def _abort(self, reason: str) -> bool:
        self.aborted = reason
        self.log(f'conform: ABORT: {reason}: zero command, enable=false')
        self._fault_expected = True
        start = self._now_ns()
        self.stop_commands(self.plan.abort_hold_s)
        self.segments.append(Segment('abort hold', start, self._now_ns(), 0.0, False))
        return False

    def _command(self, name: str, velocity: np.ndarray, enable: bool, nominal: float) -> bool:
        """Play one commanded segment (one value per tick); False if it was aborted."""
        start = 0
        for v in velocity.tolist():
            self._tick()
            problem = self._check()
            if problem:
                self.segments.append(Segment(f'{name} (aborted)', start or self._now_ns(),
                                             self._now_ns(), nominal, enable))
                return self._abort(problem)
            self._send(v, enable)
            start = start or self.c['send'][-1]
        self.segments.append(Segment(name, start, self.c['send'][-1], nominal, enable))
        return True

    def _constant(self, name: str, seconds: float, v: float, enable: bool) -> bool:
        return self._command(name, np.full(max(1, int(round(seconds / H_S))), v), enable, v)

    def _silence(self) -> bool:
        """Send nothing for ``watch_s`` (the watchdog's test); the bounds stay checked."""
        start = self.c['send'][-1]
        self._fault_expected = True
        n = max(1, int(round(self.plan.watch_s / H_S)))
        problem = ''
        for _ in range(n):
            self._tick()
            problem = self._check()
            if problem:
                break
        self.segments.append(Segment(SILENCE, start, self._now_ns(), 0.0, False, False))
        if not problem:
            f = self.f
            recv = np.asarray(f['recv'])
            tail = recv >= recv[-1] - 20_000_000
            moved = float(np.ptp(np.asarray(f['pos'])[tail]))
            if moved > self.tol.rest_mm:
                problem = (f'the axis still moves {self.plan.watch_s * 1e3:g} ms after the '
                           f'commands stopped ({moved * 1e3:.3g} µm in 20 ms): no watchdog?')
        return self._abort(problem) if problem else True

    # ---- the run ----------------------------------------------------------------------------
    def _precondition(self) -> str:
        """Return why the motion tests must not start ('' = they may)."""
        p = self.plan
        g = self.graph
        if not g.subscriptions.get(COMMAND_TOPIC):
            return f'nobody subscribes {COMMAND_TOPIC}'
        if g.publishers.get(COMMAND_TOPIC):
            return (f'another node publishes {COMMAND_TOPIC} '
                    f'({", ".join(e.node for e in g.publishers[COMMAND_TOPIC])})')
        if not self.g['recv'] or not self.f['recv']:
            return 'no samples received'
        now = time.time_ns()
        for name, d in (('gap reading', self.g), ('feedback', self.f)):
            if now - d['recv'][-1] > int(p.stale_s * 1e9):
                return f'stale {name}: the last one is {(now - d["recv"][-1]) * 1e-6:.0f} ms old'
        f = self.f
        if f['fault'][-1]:
            return f'the drive reports a fault: {f["reason"][-1] or "no reason given"}'
        if not f['enabled'][-1]:
            return 'the drive is not enabled'
        gap, valid, status = self.g['gap'][-1], self.g['valid'][-1], self.g['status'][-1]
        if not (valid and status == STATUS_OK and math.isfinite(gap)):
            return f'the gap reading is invalid (status {status})'
        if gap > MAX_PLAUSIBLE_GAP_MM:
            return (f"gap reading {gap:.4g}: beyond any capacitive sensor's range "
                    f'({MAX_PLAUSIBLE_GAP_MM:g} mm): not in mm (µm?); nothing is moved')
        if gap - p.max_travel_mm < p.min_gap_mm:
            return (f'gap {gap:.3f} mm: travel down to the bound ({p.max_travel_mm:g} mm) could '
                    f'end below the minimum {p.min_gap_mm:g} mm; raise the axis or lower '
                    '--max-travel-mm')
        if not math.isfinite(f['pos'][-1]):
            return 'the encoder position is not finite'
        return ''

    def run(self) -> None:
        """Passive window, then (at a safe height only) the motion tests in order."""
        p = self.plan
        t0 = self._now_ns()
        self._wait(p.passive_s)
        self.segments.append(Segment(PASSIVE, t0, self._now_ns(), commanded=False))
        self.not_run = self._precondition()
        if not self.not_run:
            self.not_run = self._make_publisher()
        if not self.not_run:  # the publisher may have taken seconds: look again
            self.graph = self.read_graph()
            self.not_run = self._precondition()
        self._excitation = (p.excitation.velocity_mm_s(H_S) if p.excitation is not None
                            else None)  # computed before the 2 kHz stream starts
        if self.not_run:
            self.log(f'conform: motion tests not run: {self.not_run}')
            return
        self._pos0 = self.f['pos'][-1]
        self.notes.append(f'start: gap {self.g["gap"][-1]:.4g} mm, encoder {self._pos0:.4g} mm')
        self._gap_cursor, self._fb_cursor = len(self.g['recv']), len(self.f['recv'])
        gc.collect()
        gc.freeze()
        gc.disable()  # a full collection must not stall the 2 kHz loop
        self._deadline = time.monotonic_ns()
        try:
            for attempt in range(1 + p.retries):
                if attempt:
                    why = self._retry(attempt)
                    if why:
                        self.notes.append(f'motion tests not repeated: {why}')
                        break
                if self._motion() or not self.aborted.startswith(RETRYABLE):
                    break
        finally:
            gc.enable()
            gc.unfreeze()

    def _motion(self) -> bool:
        """Play the motion tests in order; False if one was aborted."""
        p = self.plan
        v, settle = p.test_speed_mm_s, p.settle_s
        ok = (self._constant(ENABLE, p.enable_s, v, False)
              and self._constant('settle', settle, 0.0, True)
              and self._constant(UP, p.half_s, v, True)
              and self._constant(DOWN, p.half_s, -v, True)
              and self._constant('settle', settle, 0.0, True))
        if ok and self._excitation is not None:
            ex = p.excitation
            ok = (self._command(EXCITATION, self._excitation, True, ex.amplitude_mm_s)
                  and self._constant('settle', settle, 0.0, True))
        return (ok and self._one_commander()
                and self._constant(WATCHDOG, p.watchdog_run_s, v, True) and self._silence())

    def _one_commander(self) -> bool:
        """Play the one-commander test (rule ``one_commander``); False if it was aborted.

        The prober keeps commanding zero (enabled) throughout; the second commander's
        commands go upward (away from the sheet) at the test speed, so a drive that executes
        them moves where the travel bound still holds.
        """
        v = self.plan.test_speed_mm_s
        self._fault_expected = True
        start = 0
        for _ in range(max(1, int(round(SECOND_COMMANDER_S / H_S)))):
            self._tick()
            problem = self._check()
            if problem:
                return self._abort(problem)
            self._send(0.0, True)
            self._send_second(v)
            start = start or self.c['send'][-1]
        self.segments.append(Segment(SECOND_COMMANDER, start, self.second_send[-1], 0.0, True))
        if not self._constant(FAULT_HOLDS, FAULT_HOLDS_S, 0.0, True):
            return False
        start = self._now_ns()
        future = None
        if self._reset_client.service_is_ready():
            future = self._reset_client.call_async(self._ResetFault.Request())
        end = time.monotonic() + RESET_WAIT_S
        while future is not None and not future.done() and time.monotonic() < end:
            self._tick()
            problem = self._check()
            if problem:
                return self._abort(problem)
            self._send(0.0, True)
            self._reset_executor.spin_once(timeout_sec=0.0)
        if future is None:
            self.reset_answer = f'no {RESET_SERVICE} service'
        elif not future.done():
            self.reset_answer = f'no answer within {RESET_WAIT_S:g} s'
        else:
            r = future.result()
            self.reset_answer = f'{"accepted" if r.accepted else "refused"}: {r.message}'
        self.segments.append(Segment(RESET_CALL, start, self._now_ns(), 0.0, True))
        if not self._constant(AFTER_RESET, AFTER_RESET_S, 0.0, True):
            return False
        self._fault_expected = False
        f = self.f
        if f['fault'][-1]:
            return self._abort(f'the drive is still faulted after the reset '
                               f'({self.reset_answer}): {f["reason"][-1] or "no reason"}')
        return True

    def _retry(self, attempt: int) -> str:
        """Prepare another attempt after a timing abort; return why not ('' = go)."""
        self.notes.append(f'attempt {attempt} aborted: {self.aborted}; the motion tests were '
                          'repeated (a stall of the host looks the same)')
        self.segments = [s if s.name == PASSIVE or '(' in s.name else
                         dataclasses.replace(s, name=f'{s.name} (attempt {attempt})')
                         for s in self.segments]
        # zero, enable=false while the drive recovers (the sim clears its watchdog fault
        # after 0.1 s of commands); faults are expected here
        self._fault_expected = True
        self._constant(f'hold (attempt {attempt})', 0.3, 0.0, False)
        self._gap_cursor, self._fb_cursor = len(self.g['recv']), len(self.f['recv'])
        self._speed.clear()
        why = self._precondition()
        if why:
            return why
        offset = self.f['pos'][-1] - self._pos0
        # back from anywhere inside the travel bound: the return is bounded as every motion
        # test is (a defect that moved the axis during the enable test, then a stall of the
        # host, used to leave seven rules "not run")
        if abs(offset) > self.plan.max_travel_mm:
            return (f'the axis is {offset:+.3f} mm from its start (outside the travel bound)')
        self.aborted = ''
        self._fault_expected = False
        if abs(offset) > self.tol.rest_mm:
            # back to the start (a height checked safe), at the test speed, bounds as always
            v = self.plan.test_speed_mm_s
            n = max(1, int(round(abs(offset) / v / H_S)))
            back = -math.copysign(v, offset)
            if not (self._command(f'return (attempt {attempt})', np.full(n, back), True, back)
                    and self._constant(f'settle (attempt {attempt})', self.plan.settle_s, 0.0,
                                       True)):
                return f'the return to the start was aborted: {self.aborted}'
        return ''

    # ---- the result ---------------------------------------------------------------------------
    def finish(self) -> Recording:
        """Close the bag, read it back, and return everything as a :class:`Recording`."""
        self.poll()
        check = BagCheck(self.bag_path.name, False,
                         expected={t: n for t, n in self.enqueued.items()})
        try:
            self._write_bag()
            with open_bag(self.bag_path) as bag:
                check.counts = {t: bag.count(t) for t in self.enqueued}
                check.readable = True
        except (BagError, OSError) as exc:
            check.error = ' '.join(str(exc).split())
        g, f, c = self.g, self.f, self.c
        gap = GapSamples(recv_ns=g['recv'], stamp_ns=g['stamp'], seq=g['seq'], pub_seq=g['pub'],
                         gap_mm=g['gap'], valid=g['valid'], status=g['status'])
        fb = FeedbackSamples(recv_ns=f['recv'], stamp_ns=f['stamp'], seq=f['seq'],
                             pub_seq=f['pub'], position_mm=f['pos'], velocity_mm_s=f['vel'],
                             drive_enabled=f['enabled'], drive_fault=f['fault'],
                             fault_reason=f['reason'])
        return Recording(self.graph, gap, fb, c['send'], c['vel'], c['enable'], self.segments,
                         self.plan, self.aborted, self.not_run, self.notes, check,
                         commander=self._cmd.commander, second_commander=self._second.commander,
                         second_send_ns=self.second_send, reset_answer=self.reset_answer)

    def _write_bag(self) -> None:
        """Write what was seen and sent, in time order, as a rosbag2 bag (mcap)."""
        self._bag_items.sort(key=lambda item: item[2])
        custom = {'ladrc.source': 'conform',
                  'ladrc.conform.segments': json.dumps(
                      [[s.name, s.start_ns, s.end_ns] for s in self.segments])}
        with BagWriter(self.bag_path, custom_data=custom) as writer:
            for topic in BAG_TOPICS:
                writer.add_topic(topic)
            for topic, data, stamp_ns in self._bag_items:
                writer.write_raw(topic, stamp_ns, data)

    def destroy(self) -> None:
        """Destroy the nodes."""
        self._reset_executor.shutdown(timeout_sec=0.0)
        self._reset_node.destroy_node()
        self.node.destroy_node()


SIGNALLED: list[str] = []
"""A SIGINT/SIGTERM received, raised as KeyboardInterrupt at the probe's next poll."""


__all__ = ['ConformError', 'ConformProbe', 'CONTRACT_TYPES']
