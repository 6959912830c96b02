"""The calibration node: the capacitive calibration sweep on the ROS graph (docs/calibration.md).

It drives the axis through the contract's topics, as the follow node does, but only while a
sweep runs: ``calibrate`` (``ladrc_msgs/Calibrate``) starts one and answers at once (accepted,
or the reason: a sweep already running, no samples from the driver, another node commanding
the axis, an existing output folder); the result follows as JSON on ``calibration/result``
(``std_msgs/String``, latched). ``ladrc calibrate`` runs the same node in its own process and
starts the sweep itself.

While a sweep runs, a 2 kHz deadline loop steps the pure
:class:`~ladrc_tools.commissioning.calibration.SweepProcedure` and publishes its velocity
command. Every sensor sample is recorded in its callback, with the feedback samples and, when
a simulator publishes it, ``sim/truth``; afterwards the encoder position of each sensor sample
is interpolated at its stamp (exact when the driver stamps both alike, as the sim node does)
and the table is built, checked and written (:func:`~ladrc_tools.commissioning.calibration_table.
build_table`, :func:`~ladrc_tools.commissioning.calibration_output.write_calibration`).

Lock step (``lockstep: true``, against the sim node in lock step, docs/follow-node.md): the
node ticks once per ``sim/lockstep`` step, on the sim's clock, and answers every step (zero with
``enable`` false while no sweep runs), so a calibration on the sim is deterministic.

Safety (docs/safety.md): the procedure stops at once on contact and aborts on any surprise; an
exception in a tick or a callback, Ctrl-C and SIGTERM publish zero velocity with ``enable``
false first; when a sweep ends the node publishes zero with ``enable`` false and then stops
commanding (the drive's watchdog holds the axis, as when the follow node stops).
"""

from __future__ import annotations

from dataclasses import fields
import gc
import json
import math
from pathlib import Path
import secrets
import sys
import time
from typing import Any, NamedTuple

from ladrc_contract import qos
from ladrc_contract.node_entry import NodeRun, StartError, run_node, stop_signals
from ladrc_contract.qos import to_rclpy
from ladrc_contract.realtime import apply_realtime
from ladrc_follow import sim_time_s
from ladrc_msgs.msg import AxisFeedback, CapacitiveHeight, LockStep, SimTruth, VelocityCommand
from ladrc_msgs.srv import Calibrate
from ladrc_tools.commissioning.calibration import (
    CalibrationError,
    SweepInput,
    SweepMotion,
    SweepProcedure,
)
from ladrc_tools.commissioning.calibration_output import summary, table_meta, write_calibration
from ladrc_tools.commissioning.calibration_table import build_table
import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import String

# every sample of the sweep is wanted (not only the freshest): a deep best-effort reader
RECORD = qos.HIGH_RATE.with_depth(200)
NODE_NAME = 'ladrc_calibrate'


class Run:
    """One sweep: the procedure, the feedback and truth samples, where to write."""

    def __init__(self, motion: SweepMotion, output: Path) -> None:
        self.procedure = SweepProcedure(motion)
        self.output = output
        self.fb_stamp: list[float] = []
        self.fb_pos: list[float] = []
        self.truth: dict[int, float] = {}
        self.zeros_left = 3  # zero commands with enable false after the end
        self.last_tick_ns = 0
        self.periods_ms: list[float] = []  # tick periods while moving (the loop's timing)


class CalibrateNode(Node):
    """Calibration sweeps on request (module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        for f in fields(SweepMotion):
            self.declare_parameter(f.name, float(f.default))
        self.declare_parameter('output_root', 'calibration')
        self.declare_parameter('truth_topic', 'sim/truth')
        self.declare_parameter('source', 'driver')
        self.declare_parameter('thread_priority', 50)
        self.declare_parameter('lock_memory', True)
        self.lockstep = bool(self.declare_parameter('lockstep', False).value)
        self.motion = SweepMotion(**{f.name: float(self.get_parameter(f.name).value)
                                     for f in fields(SweepMotion)})
        reasons = self.motion.problems()
        if reasons:
            raise ValueError('; '.join(reasons))
        self.h_s = 0.0005
        self.period_ns = int(round(self.h_s * 1e9))
        self._t0_ns = time.monotonic_ns()
        self._stamp0_ns: int | None = None
        self.run: Run | None = None
        self.last_result: dict[str, Any] | None = None
        # latest inputs (zero-order hold), receive times on the steady clock since start
        self.raw_hz = math.nan
        self.gap_mm = math.nan
        self.valid = False
        self.status = CapacitiveHeight.STATUS_FAULT
        self.gap_t = -math.inf
        self.pos_mm = math.nan
        self.enc_t = -math.inf
        self.drive_enabled = False
        self.drive_fault = False
        self.drive_reason = ''
        self.cmd_seq = 0
        self._gap_seq = -1  # the newest sample seen of each stream (repeats are not fresh)
        self._fb_seq = -1
        # lock step: the step waiting for its samples, the step being ticked (its time)
        self.step: tuple[int, int, bool, int, bool] | None = None
        self.step_k = 0
        record = to_rclpy(qos.LOCKSTEP_HIGH_RATE.with_depth(200) if self.lockstep else RECORD)
        if self.lockstep:
            self.create_subscription(LockStep, 'sim/lockstep', self._on_step,
                                     to_rclpy(qos.LOCKSTEP_INPUT))
        self.create_subscription(CapacitiveHeight, 'axis/capacitive_height', self._on_gap,
                                 record)
        self.create_subscription(AxisFeedback, 'axis/feedback', self._on_feedback, record)
        truth_topic = self.get_parameter('truth_topic').value
        if truth_topic:
            self.create_subscription(SimTruth, truth_topic, self._on_truth, record)
        self.pub_cmd = self.create_publisher(
            VelocityCommand, 'axis/velocity_command',
            to_rclpy(qos.LOCKSTEP_HIGH_RATE if self.lockstep else qos.HIGH_RATE))
        self.pub_result = self.create_publisher(String, 'calibration/result',
                                                to_rclpy(qos.RUN_TEXT))
        self.create_service(Calibrate, 'calibrate', self._srv_calibrate)
        self._cmd = VelocityCommand()
        self._cmd.header.frame_id = 'z_axis'
        self._cmd.commander = self.get_fully_qualified_name()
        self._cmd.session = secrets.randbits(63) or 1

    # ---- inputs ------------------------------------------------------------------------
    def _now_s(self) -> float:
        if self.lockstep:  # the sim's time of the step being ticked
            return self.step_k * self.h_s
        return (time.monotonic_ns() - self._t0_ns) * 1e-9

    def _sample_s(self, stamp) -> float:
        """Return a sample's time: now (steady clock); lock step: its stamp (the sim's)."""
        if self.lockstep:
            return sim_time_s(stamp.sec * 1_000_000_000 + stamp.nanosec, self.period_ns,
                              self.h_s)
        return self._now_s()

    def _on_step(self, msg: LockStep) -> None:
        self.step = (msg.step, msg.gap_seq, msg.gap_fresh, msg.encoder_seq, msg.encoder_fresh)

    def step_ready(self) -> bool:
        """Lock step: a step is waiting and the samples it names have arrived."""
        s = self.step
        return s is not None and (not s[2] or self._gap_seq >= s[1]) and (
            not s[4] or self._fb_seq >= s[3])

    def _stamp_s(self, stamp) -> float:
        ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        if self._stamp0_ns is None:
            self._stamp0_ns = ns
        return (ns - self._stamp0_ns) * 1e-9

    def _on_gap(self, msg: CapacitiveHeight) -> None:
        t = self._sample_s(msg.header.stamp)
        if msg.seq <= self._gap_seq:
            return  # a repeated or older sample is not fresh data (a driver re-sending)
        self._gap_seq = msg.seq
        self.raw_hz, self.gap_mm = msg.raw_hz, msg.gap_mm
        self.valid, self.status, self.gap_t = msg.valid, msg.status, t
        run = self.run
        if run is not None and not run.procedure.finished:
            run.procedure.on_sample(t, self._stamp_s(msg.header.stamp), msg.seq, msg.raw_hz,
                                    msg.gap_mm, msg.valid, msg.status, self.pos_mm)

    def _on_feedback(self, msg: AxisFeedback) -> None:
        if msg.seq <= self._fb_seq:
            return  # a repeated or older sample is not fresh data
        self._fb_seq = msg.seq
        self.pos_mm, self.enc_t = msg.position_mm, self._sample_s(msg.header.stamp)
        self.drive_enabled, self.drive_fault = msg.drive_enabled, msg.drive_fault
        self.drive_reason = msg.fault_reason
        run = self.run
        if run is not None and not run.procedure.finished:
            run.fb_stamp.append(self._stamp_s(msg.header.stamp))
            run.fb_pos.append(msg.position_mm)

    def _on_truth(self, msg: SimTruth) -> None:
        run = self.run
        if run is not None and not run.procedure.finished:
            run.truth[msg.seq] = msg.true_gap_mm

    # ---- starting a sweep --------------------------------------------------------------
    def start(self, output_dir: str = '') -> tuple[bool, str]:
        """Start a sweep writing to ``output_dir``; return ``(accepted, message)``."""
        if self.run is not None:
            return False, 'a calibration sweep is running already'
        out = Path(output_dir or Path(self.get_parameter('output_root').value)
                   / time.strftime('calibration-%Y%m%d-%H%M%S'))
        if out.exists():
            return False, f'{out} exists already: outputs are never overwritten'
        if out.parent.exists() and not out.parent.is_dir():
            return False, f'{out.parent} is not a folder'
        writers = self.count_publishers('axis/velocity_command')
        if writers > 1:
            return False, (f'another node commands the axis ({writers - 1} other publisher(s) on '
                           'axis/velocity_command): stop the follow node first')
        t = self._now_s()
        limit = max(0.1, 10.0 * self.motion.stale_timeout_s)
        if not (t - self.gap_t <= limit and t - self.enc_t <= limit):
            return False, ('no recent samples from the driver on axis/capacitive_height and '
                           'axis/feedback')
        self.run = Run(self.motion, out)
        self.last_result = None
        # The sweep stores ~10^5 small tuples: the cyclic collector's full passes over them
        # stalled the 2 kHz loop for up to 0.3 s (measured); they hold no cycles, so it is
        # off until the sweep ends (finish).
        gc.collect()
        gc.disable()
        self.get_logger().info(f'calibration sweep started: descent '
                               f'{self.motion.descent_mm_s:g} mm/s, writing {out}')
        return True, f'calibration sweep started; result on calibration/result, folder {out}'

    def _srv_calibrate(self, request, response):
        response.accepted, response.message = self.start(request.output_dir)
        if not response.accepted:
            self.get_logger().warning(f'calibrate rejected: {response.message}')
        return response

    @property
    def active(self) -> bool:
        """Whether a sweep is running (its motion, or its processing still to come)."""
        return self.run is not None

    # ---- the tick ----------------------------------------------------------------------
    def publish_command(self, velocity_mm_s: float, enable: bool, release: bool = False
                        ) -> None:
        """Publish one velocity command (zero when not enabled; ``release``: the last one)."""
        sec, nsec = divmod(self.get_clock().now().nanoseconds, 1_000_000_000)
        c = self._cmd
        c.header.stamp.sec, c.header.stamp.nanosec = sec, nsec
        c.seq = self.cmd_seq
        c.sample_seq = self.step_k if self.lockstep else max(self._fb_seq, 0)
        c.velocity_mm_s = float(velocity_mm_s) if enable else 0.0
        c.enable = bool(enable)
        c.release = bool(release)
        self.pub_cmd.publish(c)
        self.cmd_seq += 1

    def tick(self) -> bool:
        """One tick of a running sweep; return True when its motion has just ended."""
        run = self.run
        if run is None:
            return False
        p = run.procedure
        now = time.monotonic_ns()
        if run.last_tick_ns and not p.finished:
            run.periods_ms.append((now - run.last_tick_ns) * 1e-6)
        run.last_tick_ns = now
        if p.finished:
            if run.zeros_left > 0:
                run.zeros_left -= 1
                self.publish_command(0.0, False)
                return run.zeros_left == 0
            return False
        v, enable = p.step(SweepInput(self._now_s(), self.raw_hz, self.gap_mm, self.valid,
                                      self.status, self.gap_t, self.pos_mm, self.enc_t,
                                      self.drive_enabled, self.drive_fault,
                                      self.drive_reason))
        self.publish_command(v, enable)
        return False

    def fail(self, reason: str) -> None:
        """Zero command with enable false first, then abort the sweep (exceptions, signals)."""
        try:
            self.publish_command(0.0, False)
        finally:
            if self.run is not None:
                self.run.procedure.abort(reason)

    # ---- the result --------------------------------------------------------------------
    def finish(self) -> dict[str, Any]:
        """Build, check and write the table of the ended sweep; publish and return the result."""
        run, self.run = self.run, None
        gc.enable()
        if run is None:
            return {}
        p = run.procedure
        result: dict[str, Any] = {'ok': False, 'output': None}
        try:
            if not p.succeeded:
                raise CalibrationError(p.reason or 'the sweep did not finish')
            self._pair(run)
            cal = build_table(p.record, meta=table_meta(
                self.motion, p.record, str(self.get_parameter('source').value)))
            out = write_calibration(cal, run.output)
            name = 'cap_table.yaml' if not cal.problems else 'cap_table.rejected.yaml'
            result = {'ok': not cal.problems, 'output': str(out),
                      'table_file': str(out / name) if not cal.problems else None,
                      **summary(cal)}
        except (CalibrationError, FileExistsError, OSError) as exc:
            result['reason'] = ' '.join(str(exc).split())
        except Exception as exc:  # noqa: BLE001 - the node keeps running
            result['reason'] = f'processing failed: {type(exc).__name__}: {exc}'
        if run.periods_ms:
            per = np.asarray(run.periods_ms)
            result['tick_period_p99_ms'] = float(np.percentile(per, 99))
            result['tick_period_max_ms'] = float(per.max())
        self.last_result = result
        self.pub_result.publish(String(data=json.dumps(result)))
        if result['ok']:
            self.get_logger().info(f'calibration written: {result["output"]}, grade '
                                   f'{result["grade"]}')
        else:
            self.get_logger().warning('calibration failed: '
                                      + (result.get('reason') or '; '.join(
                                          result.get('problems') or [])))
        return result

    @staticmethod
    def _pair(run: Run) -> None:
        """Set the encoder position and truth of each sensor sample from stamps and seq."""
        rec = run.procedure.record
        if not rec.rows:
            return
        fs = np.asarray(run.fb_stamp)
        fp = np.asarray(run.fb_pos)
        order = np.argsort(fs, kind='stable')
        fs, fp = fs[order], fp[order]
        rows = []
        contact = math.nan
        for row in rec.rows:
            t, stamp, seq, raw, gap, valid, status, pos, phase, _ = row
            if len(fs) >= 2 and fs[0] <= stamp <= fs[-1]:
                pos = float(np.interp(stamp, fs, fp))
            rows.append((t, stamp, seq, raw, gap, valid, status, pos, phase,
                         run.truth.get(int(seq), math.nan)))
            if int(seq) == rec.contact_seq and contact != contact:
                contact = pos
        rec.rows = rows
        if rec.contact_kind == 'collision status' and contact == contact:
            rec.contact_position_mm = contact


def run_loop(node: CalibrateNode, executor, run: NodeRun, until_done: bool = False
             ) -> None:
    """Serve callbacks; tick at 2 kHz while a sweep runs; process it when its motion ends."""
    if node.lockstep:
        run_lockstep(node, executor, run, until_done)
        return
    period = node.period_ns
    mono = time.monotonic_ns
    next_ns = mono()
    while not run.stop_requested:
        if not node.active:
            if until_done and node.last_result is not None:
                return
            executor.spin_once(timeout_sec=0.02)
            next_ns = mono()
            continue
        remaining = next_ns - mono()
        if remaining > 0:
            try:
                executor.spin_once(timeout_sec=remaining * 1e-9)
            except Exception as exc:  # noqa: BLE001 - a callback failed: stop the axis
                node.fail(f'callback failed: {type(exc).__name__}: {exc}')
            continue
        try:
            ended = node.tick()
        except Exception as exc:  # noqa: BLE001 - zero command first, then abort
            node.fail(f'tick failed: {type(exc).__name__}: {exc}')
            ended = False
        next_ns += period
        if mono() - next_ns > period:
            next_ns = mono() + period
        if ended:
            node.finish()
            if until_done:
                return


def run_lockstep(node: CalibrateNode, executor, run: NodeRun, until_done: bool) -> None:
    """Lock step: one tick per step of the sim; every step answered (zero when idle)."""
    while not run.stop_requested:
        if not node.step_ready():
            try:
                executor.spin_once(timeout_sec=0.05)
            except Exception as exc:  # noqa: BLE001 - a callback failed: stop the axis
                node.fail(f'callback failed: {type(exc).__name__}: {exc}')
            continue
        node.step_k = node.step[0]
        node.step = None
        answered = node.cmd_seq
        ended = False
        try:
            ended = node.tick()
        except Exception as exc:  # noqa: BLE001 - zero command first, then abort
            node.fail(f'tick failed: {type(exc).__name__}: {exc}')
        if node.cmd_seq == answered:  # no sweep moving: the step still gets its answer
            node.publish_command(0.0, False)
        if ended:
            node.finish()
        if until_done and node.last_result is not None:
            return


def stop_commanding(node: CalibrateNode, reason: str) -> None:
    """Abort a running sweep and leave the axis with zero velocity, enable false."""
    if node.active:
        node.fail(reason)
        gc.enable()
    if node.cmd_seq:
        for i in range(3):
            try:
                node.publish_command(0.0, False, release=i == 2)
            except Exception:  # noqa: BLE001 - the context may be gone
                break


class SimOptions(NamedTuple):
    """``ladrc calibrate --sim``: the simulated axis the sweep runs on."""

    start_gap_mm: float = 5.0
    noise_mm: float = 0.005
    watchdog_s: float = 0.05
    raw_only: bool = False
    drive: str = ''  # 'cia402': the emulated CiA 402 drive and its driver node (cia402_stack)


def _start_sim(sim: SimOptions, motion: dict[str, float], lockstep: bool
               ) -> tuple[Any, Any]:
    """Start the sim node on a DDS domain of its own; return ``(process, its temp folder)``."""
    import os
    import subprocess
    import tempfile

    from ladrc_tools.commissioning.calibration import sim_scenario
    import yaml

    from .bringup import MIDDLEWARE_KEYS, executable_path, isolated_env

    os.environ.update({k: v for k, v in isolated_env().items() if k in MIDDLEWARE_KEYS})
    os.environ.pop('ROS_LOCALHOST_ONLY', None)
    tmp = tempfile.TemporaryDirectory(prefix='ladrc-calibrate-')
    scenario = Path(tmp.name) / 'calibrate_sensor.yaml'
    scenario.write_text(yaml.safe_dump(sim_scenario(
        sim.start_gap_mm, SweepMotion(**motion), noise_std_mm=sim.noise_mm)))
    log = open(Path(tmp.name) / 'sim.log', 'wb')  # noqa: SIM115
    if sim.drive == 'cia402':
        # the CiA 402 path (docs/cia402.md): the raw value is the analog input's count
        cmd = [executable_path('ladrc_bringup', 'cia402_stack'), '--scenario', str(scenario),
               '--watchdog-timeout-s', repr(sim.watchdog_s), '--logs',
               str(Path(tmp.name) / 'cia402'), '--raw-only']
        cmd += ['--lockstep'] if lockstep else ['--period-s', '0.001']
    else:
        cmd = [executable_path('ladrc_sim', 'sim_node'), '--ros-args', '-p',
               f'scenario:={scenario}', '-p', 'wait_for_controller_s:=0.0', '-p',
               f'watchdog_timeout_s:={sim.watchdog_s}', '-p',
               f'raw_only:={str(sim.raw_only).lower()}']
        cmd += ['-p', 'lockstep:=true', '-p', 'realtime:=false'] if lockstep else []
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=dict(os.environ),
                            start_new_session=True)
    log.close()
    return proc, tmp


def _start_sweep(node: CalibrateNode, executor, run: NodeRun, output: str,
                 wait_s: float) -> None:
    """Wait for the driver's samples (at most ``wait_s``) and start the sweep, or raise."""
    deadline = time.monotonic() + wait_s
    accepted, message = False, f'no samples from the driver within {wait_s:g} s'
    while not run.stop_requested and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
        if node.lockstep and node.step_ready():
            # lock step: the sim (and a driver waiting for its controller) moves on only when
            # each step is answered; zero, enable false, until the sweep starts
            node.step_k = node.step[0]
            node.step = None
            node.publish_command(0.0, False)
            continue
        # samples of both inputs, and a drive that is enabled (a CiA 402 drive powers up in
        # its first cycles, docs/cia402.md): a drive faulted or disabled for the whole wait is
        # refused by start() with its reason
        ready = node.drive_enabled or time.monotonic() > deadline - 1.0
        if node.gap_t > -math.inf and node.enc_t > -math.inf and ready:
            accepted, message = node.start(output)
            if accepted or 'no recent samples' not in message:
                break
    if run.stop_requested:
        raise KeyboardInterrupt
    if not accepted:
        raise CalibrationError(message)


def run_calibration(output: str, motion: dict[str, float], sim: SimOptions | None = None,
                    wait_s: float = 10.0, lockstep: bool = False) -> dict[str, Any]:
    """Run one sweep in this process (``ladrc calibrate``); return the result.

    With ``sim``: the sim node is started on a DDS domain of its own (random id, localhost
    discovery) and ended by its PID afterwards. Raises :class:`CalibrationError` (one line)
    when the sweep cannot start or ends without a table, KeyboardInterrupt on Ctrl-C.
    """
    from rclpy.experimental import EventsExecutor

    from .bringup import interrupt_process

    values = {**motion}
    reasons = SweepMotion(**values).problems()
    if reasons:
        raise CalibrationError('; '.join(reasons))
    sim_proc, tmp = _start_sim(sim, values, lockstep) if sim is not None else (None, None)
    try:
        with stop_signals() as run:
            context = rclpy.Context()
            rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
            node = None
            try:
                # sim/truth: only a simulator publishes it (the error against the true gap)
                overrides = {**values, 'truth_topic': 'sim/truth',
                             'source': 'sim' if sim else 'driver', 'lockstep': lockstep}
                node = CalibrateNode(context=context, parameter_overrides=[
                    Parameter(k, value=v) for k, v in overrides.items()])
                executor = EventsExecutor(context=context)
                executor.add_node(node)
                apply_realtime(0 if lockstep
                               else int(node.get_parameter('thread_priority').value), [],
                               bool(node.get_parameter('lock_memory').value))
                _start_sweep(node, executor, run, output, wait_s)
                run_loop(node, executor, run, until_done=True)
                if run.stop_requested:
                    stop_commanding(node, 'interrupted')
                    raise KeyboardInterrupt
                result = node.last_result or {}
                if not result.get('output'):
                    raise CalibrationError(result.get('reason') or 'the sweep did not finish')
                executor.shutdown()
                return result
            finally:
                if node is not None:
                    stop_commanding(node, 'calibration ended')
                    node.destroy_node()
                rclpy.try_shutdown(context=context)
    finally:
        if sim_proc is not None:
            interrupt_process(sim_proc, 10.0)
        if tmp is not None:
            tmp.cleanup()

def _make_node() -> CalibrateNode:
    try:
        return CalibrateNode()
    except ValueError as exc:
        raise StartError(f'invalid parameters: {exc}') from None


def _run(node: CalibrateNode, run: NodeRun) -> int:
    """Serve sweep requests until a stop is requested; 0."""
    from rclpy.experimental import EventsExecutor

    executor = EventsExecutor(context=node.context)
    executor.add_node(node)
    run.defer(executor.shutdown)
    # lock step: no SCHED_FIFO (ladrc_follow's follow_node._run says why)
    _, warnings = apply_realtime(0 if node.lockstep
                                 else int(node.get_parameter('thread_priority').value), [],
                                 bool(node.get_parameter('lock_memory').value))
    for text in warnings:
        node.get_logger().warning(text)
    run_loop(node, executor, run)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``ros2 run ladrc_bringup calibrate_node [--ros-args -p descent_mm_s:=0.5]``.

    Every path ends with the sweep aborted and zero velocity, enable false (its zero hook).
    """
    return run_node('calibrate_node', _make_node, _run, args=argv,
                    zero=lambda node, _reason: stop_commanding(node, 'calibration node stopped'))


if __name__ == '__main__':
    sys.exit(main())
