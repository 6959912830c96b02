"""The sim node's drive: the runner's controller that is a drive on the ROS graph.

:class:`DriveBridge` is what the headless runner steps in the sim node: at each 0.5 ms deadline
it takes the velocity commands that arrived (straight from the reader, raw), applies the one
commander rule (:mod:`ladrc_contract.commander_lock`) and the drive watchdog (no command for
``watchdog_timeout_s`` -> quick stop and a drive fault with a readable reason), has the node
publish the tick's samples, and returns the latest command (one tick of transport delay, as on a
fieldbus). Lock step (``lockstep``): it publishes step k and waits for the command answering k
(docs/follow-node.md, "Lock step").
"""

from __future__ import annotations

from collections import Counter
import gc
import math
import threading
import time
from typing import Any, NamedTuple

from ladrc_contract.commander_lock import CommanderLock, Identity
from ladrc_contract.loop_io import SampleWait

from ..headless.scenario import (
    DRIVE_FAULT_REASON,
)

WIND_DOWN_TICKS = 20
"""Steps the controller runs stopped, its inputs still live, before a run's samples end."""
WIND_DOWN_LIMIT_S = 2.0
"""Wall time the controller has to answer the run's closing ``stop_follow``."""


class _Command(NamedTuple):
    """The fields of a ``VelocityCommand`` the drive uses."""

    seq: int
    velocity_mm_s: float
    enable: bool
    sample_seq: int
    commander: str
    session: int
    release: bool


COMMAND_FIELDS = _Command._fields


class StopSimulation(Exception):
    """Raised inside the runner's loop to end the run early (Ctrl-C)."""


class LockstepAbort(Exception):
    """Lock step: the controller did not answer within ``lockstep_timeout_s`` (one line)."""


class DriveBridge:
    """The runner's controller: publishes samples, returns received commands, paces real time."""

    def __init__(self, node: Any, realtime: bool = True) -> None:
        """``node``: the sim node (its readers, publishers, clients, logger)."""
        self.node = node
        self.realtime = realtime
        # the commander lock and the held command: the loop thread takes commands, the
        # service thread resets the drive
        self.mutex = threading.Lock()
        # woken by a command, or (a job in lock step) by the controller's status or the CNC's
        # samples and steps (a separate CNC)
        others = (getattr(node, name, None) for name in ('status_reader', 'cnc_reader',
                                                         'cnc_step_reader', 'cnc_job_reader'))
        self._wait = SampleWait(node.context, tuple(
            r for r in (node.cmd_reader, *others) if r is not None))
        self.running = True
        h = node.h_s
        self.period_ns = int(round(h * 1e9))
        self.t_start_ns = 0
        self.cmd_velocity = 0.0
        self.cmd_enable = False
        self.cmd_seq = -1
        self.cmd_count = 0
        self.last_cmd_ns = 0
        self.watchdog_ticks = max(1, int(round(node.watchdog_timeout_s / h)))
        self.ticks_since_cmd = 0
        self.recover_ns = int(node.watchdog_recover_s * 1e9)
        self.fault_reason = ''
        self.watchdog_trips = 0
        self._resumed_ns = 0
        self.seq = 0
        self.truth_seq = 0  # sim/truth messages published (the step, but for silent cycles)
        self.truth_values = (math.nan,) * 8
        self.late_ticks = 0
        self._prev_enc = math.nan
        self._prev_t = math.nan
        self.periods_us: list[float] = []
        self._last_tick_ns = 0
        # samples published so far (seq of the next one), the step counter
        self.gap_seq = 0
        self.enc_seq = 0
        self.lockstep = node.lockstep
        self.lockstep_timeout_ns = int(node.lockstep_timeout_s * 1e9)
        self._answer: tuple[float, bool] | None = None  # lock step: the command answering seq
        self.lock = CommanderLock()
        self.malformed_commands = 0
        self.cmd_source: Identity = ('', 0)  # whose command is held
        self.cycles_by_commander: Counter = Counter()  # drive cycles executed, per source
        self.last_tick = None  # the runner's latest tick (wind_down holds the world at it)
        self.wind_down_problem = ''  # why the wind-down did not end with an answer

    # ---- the runner's hooks -------------------------------------------------------------
    def truth(self, t_s: float, true_gap_mm: float, sheet_mm: float, nozzle_mm: float,
              coverage: float, plate_velocity_mm_s: float, x_mm: float = math.nan,
              y_mm: float = math.nan) -> None:
        """Truth of the coming tick (called by the runner before ``step``; XY: a job's)."""
        self.truth_values = (true_gap_mm, sheet_mm, nozzle_mm, coverage, plate_velocity_mm_s,
                             t_s, x_mm, y_mm)

    def command(self, name: str, **kwargs: Any) -> None:
        """Send a scenario follow command to the controller's service.

        Live: asynchronously. Lock step: the answer is awaited, so the command takes effect at
        the tick of this step, as in the headless runner.
        """
        future = self.node.send_follow_command(name, kwargs)
        if self.lockstep:
            self._await(future.done, f'no answer to the {name} service call')

    def _await(self, condition, what: str) -> None:
        """Lock step: wait until ``condition()``; abort after the wall-clock wait.

        The service thread serves the call's answer; the commands that arrive meanwhile are
        taken here (the answer to the step is one of them).
        """
        limit = time.monotonic_ns() + self.lockstep_timeout_ns
        while True:
            self.take_commands()
            if condition():
                return
            if not self.running:
                raise StopSimulation()
            now = time.monotonic_ns()
            if now > limit:
                raise LockstepAbort(f'lock step aborted at step {self.seq}: {what} within '
                                    f'{self.lockstep_timeout_ns * 1e-9:g} s (wall clock)')
            self._wait.wait(min(limit - now, 2_000_000))

    def take_commands(self) -> None:
        """Take the velocity commands that arrived, oldest first (the loop thread)."""
        reader = self.node.cmd_reader
        while (taken := reader.take()) is not None:
            self.on_command(*taken)

    def _start(self) -> int:
        now = time.monotonic_ns()
        if self.t_start_ns == 0:
            # The runner has allocated its per-run series: move everything alive now out of
            # the collector's reach, so a full collection cannot stall the 2 kHz loop.
            gc.collect()
            gc.freeze()
            now = time.monotonic_ns()
            self.t_start_ns = now
        return now

    def wind_down(self, ticks: int = WIND_DOWN_TICKS, limit_s: float = WIND_DOWN_LIMIT_S
                  ) -> None:
        """End a run with the controller stopped before its inputs stop.

        Calls ``stop_follow`` and keeps stepping with the world and the axis held at the
        runner's last tick (fresh samples, stamped on), until the call is answered and
        ``ticks`` more steps went out, so the controller commands zero while it still has
        inputs. Lock step: the answer comes before the first held step. Called by the runner
        right after its last tick; ``wind_down_problem`` says why the controller did not
        answer within ``limit_s`` of wall time ('' when it did).
        """
        tick = self.last_tick
        if tick is None:
            return
        future = self.node.send_follow_command('stop_follow', {})
        if self.lockstep:
            self._await(future.done, 'no answer to the stop_follow service call')
        end_ns = time.monotonic_ns() + int(limit_s * 1e9)
        after = 0
        while after < ticks:
            t = self.seq * self.node.h_s
            self.step(tick._replace(t_s=t, gap_stamp_s=t, encoder_stamp_s=t))
            self.last_tick = tick
            if future.done():
                after += 1
            elif time.monotonic_ns() > end_ns:
                self.wind_down_problem = (f'the controller did not answer stop_follow within '
                                          f'{limit_s:g} s')
                return

    def step_lockstep(self, tick) -> float:
        """Lock step: publish step k, wait for the command answering k, return it."""
        now = self._start()
        if self.realtime:  # paced: never faster than real time
            deadline = self.t_start_ns + self.seq * self.period_ns
            while now < deadline:
                time.sleep((deadline - now) * 1e-9)
                now = time.monotonic_ns()
        if not self.running:
            raise StopSimulation()
        if self._last_tick_ns:
            self.periods_us.append((now - self._last_tick_ns) * 1e-3)
        self._last_tick_ns = now
        self._answer = None
        fault, reason = self._drive_fault(tick)
        self.node.publish_samples(self.seq, tick, fault, reason, self.truth_values,
                                  stamp_ns=self.seq * self.period_ns)
        self._await(lambda: self._answer is not None,
                    f'no velocity command answering step {self.seq}')
        velocity, enable = self._answer
        self.seq += 1
        if fault or not tick.drive_enabled or not enable:
            return 0.0
        self.cycles_by_commander[self.cmd_source] += 1
        return velocity

    def _drive_fault(self, tick) -> tuple[bool, str]:
        """Return the drive's fault now: the commander lock's, the watchdog's or the scenario's."""
        reason = self.lock.fault_reason or self.fault_reason or (
            DRIVE_FAULT_REASON if tick.drive_fault else '')
        return bool(reason), reason

    def will_be_silent(self) -> bool:
        """Live: the coming cycle is late by more than one, so it is caught up silently."""
        if self.lockstep or not self.realtime or self.t_start_ns == 0:
            return False
        due_ns = self.t_start_ns + self.seq * self.period_ns
        return time.monotonic_ns() - due_ns > self.period_ns

    def step(self, tick) -> float:
        """Wait for this tick's deadline, publish its samples, return the latest command."""
        self.last_tick = tick
        if self.lockstep:
            return self.step_lockstep(tick)
        node = self.node
        now = self._start()
        deadline = self.t_start_ns + self.seq * self.period_ns
        if self.realtime and now < deadline:
            while now < deadline:
                time.sleep((deadline - now) * 1e-9)
                now = time.monotonic_ns()
        elif self.realtime and now - deadline > self.period_ns:
            # Late by more than a cycle (this process was descheduled): the missed cycles run
            # silently, back to back, so the simulated axis keeps wall time (it moved on at the
            # held command meanwhile; the conformance kit measures its speed against the
            # clock). Silent: nothing published (each topic's seq counts what it publishes),
            # not counted by the watchdog (no command could arrive in them: the simulator's
            # own stall must not trip it).
            return self._silent_cycle(tick)
        if not self.running:
            raise StopSimulation()
        self.take_commands()  # what arrived until this cycle
        if self._last_tick_ns:
            self.periods_us.append((now - self._last_tick_ns) * 1e-3)
        self._last_tick_ns = now

        # Drive watchdog, armed by the first command. It counts the drive's own cycles without
        # a new command (as a fieldbus drive does), so a stall of this process is not taken
        # for a silent controller.
        fault = bool(tick.drive_fault)
        reason = DRIVE_FAULT_REASON if fault else ''
        if self.last_cmd_ns:
            self.ticks_since_cmd += 1
            if self.ticks_since_cmd > self.watchdog_ticks:
                tripped = not self.fault_reason
                self.fault_reason = (f'no velocity command for {self.ticks_since_cmd} cycles '
                                     f'(watchdog {self.watchdog_ticks} cycles = '
                                     f'{self.watchdog_ticks * self.period_ns * 1e-6:g} ms): '
                                     'axis stopped')
                if tripped:
                    self.watchdog_trips += 1
                    node.get_logger().warning(f'watchdog: {self.fault_reason} (late ticks so '
                                              f'far: {self.late_ticks})')
                self._resumed_ns = 0
            elif self.fault_reason:
                if not self._resumed_ns:
                    self._resumed_ns = now
                elif now - self._resumed_ns > self.recover_ns:
                    self.fault_reason = ''
        fault, reason = self._drive_fault(tick)
        node.publish_samples(self.seq, tick, fault, reason, self.truth_values)
        self.seq += 1
        if fault or not tick.drive_enabled or not self.cmd_enable:
            return 0.0
        self.cycles_by_commander[self.cmd_source] += 1
        return self.cmd_velocity

    def _silent_cycle(self, tick) -> float:
        """Catch up a missed cycle: the plant steps on the held command, nothing published."""
        if not self.running:
            raise StopSimulation()
        self.late_ticks += 1
        self.take_commands()
        # The watchdog by the cycle's own time (not its count: a stall of this process must not
        # trip it): commands that came during the stall were taken just now; a controller that
        # went silent before it stops the axis when the drive would have.
        due_ns = self.t_start_ns + self.seq * self.period_ns
        if (self.last_cmd_ns and not self.fault_reason
                and due_ns - self.last_cmd_ns > self.watchdog_ticks * self.period_ns):
            self.fault_reason = (f'no velocity command for '
                                 f'{(due_ns - self.last_cmd_ns) * 1e-6:.1f} ms (watchdog '
                                 f'{self.watchdog_ticks * self.period_ns * 1e-6:g} ms, '
                                 'cycles caught up after a stall of the simulator): axis stopped')
            self.watchdog_trips += 1
            self._resumed_ns = 0
            self.node.get_logger().warning(f'watchdog: {self.fault_reason}')
        fault, _ = self._drive_fault(tick)
        self.seq += 1
        if fault or not tick.drive_enabled or not self.cmd_enable:
            return 0.0
        self.cycles_by_commander[self.cmd_source] += 1
        return self.cmd_velocity

    def quick_stop(self) -> bool:
        """Return True while the watchdog or the commander lock faults the drive (a_max brake)."""
        return bool(self.fault_reason or self.lock.fault_reason)

    def on_command(self, data: bytes, _received_ns: int) -> None:
        """One velocity command taken from the reader: keep the latest (zero-order hold).

        Lock step: the command answering the step being waited for is its answer. A command
        the commander lock refuses is not executed (module docstring); bytes that are not a
        ``VelocityCommand`` are nobody's command (counted, not executed).
        """
        try:
            msg = _Command(*(self.node.cmd_cdr.unpack(data)[i]
                             for i in self.node.cmd_fields))
        except ValueError:
            self.malformed_commands += 1
            return
        with self.mutex:
            self._command(msg)

    def _command(self, msg: _Command) -> None:
        faulted = bool(self.lock.fault_reason)
        if not self.lock.admit(msg.commander, msg.session, msg.release):
            if not faulted:  # the first foreign command: hold zero from now on
                self.cmd_velocity, self.cmd_enable = 0.0, False
                self.node.get_logger().error(
                    f'drive fault at cycle {self.seq} (next feedback seq {self.enc_seq}): '
                    f'{self.lock.fault_reason}')
            if (self.lockstep and self.lock.owner == (msg.commander, msg.session)
                    and msg.sample_seq == self.seq and self._answer is None):
                self._answer = (0.0, False)  # the step goes on, the drive faulted: at rest
            return
        self.cmd_source = (msg.commander, msg.session)
        if self.lockstep and msg.sample_seq == self.seq and self._answer is None:
            self._answer = (msg.velocity_mm_s, msg.enable)
        self.cmd_velocity = msg.velocity_mm_s
        self.cmd_enable = msg.enable
        self.cmd_seq = msg.seq
        self.cmd_count += 1
        self.last_cmd_ns = time.monotonic_ns()
        self.ticks_since_cmd = 0
