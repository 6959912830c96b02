"""The sim node's side of a cutting job: the job runner's controller is the drive and the wire.

:class:`JobDrive` is what :func:`ladrc_sim.job.runner.run_job` steps when the sim node plays a
job (``-p job:=NAME``), as the :class:`~.drive_bridge.DriveBridge` is what the scenario runner
steps: per tick it sends the CNC's motion sample of the tick on ``cnc/motion`` (when the CNC
cycle has one), has the bridge publish the tick's samples and return the drive's command, and
gives the CNC the controller's answers from ``follow/status`` (the fields the CNC reads are
all in it: docs/interfaces.md, "CNC interface"). The CNC's commands go to the follow services.

Live: the CNC reads the newest status that arrived (a CNC's cycle lags the controller's), and
its commands are sent without waiting (a refusal, when its answer comes, aborts the job, as a
refusal does headless). Lock step: the sim waits for the status answering step k before the CNC
steps k + 1, and each command's answer before the step's samples go out: the headless runner's
order, so a lock-step job equals the headless job bit for bit (tests/ros/test_lockstep.py).
"""

from __future__ import annotations

import math
from typing import Any

from ladrc_contract.cdr import CdrPacker
from ladrc_contract.codes import FollowState
from ladrc_contract.tick import CncInput, TickInput

ANSWERS = ('state', 'substate', 'in_position', 'ready_to_move', 'feed_hold_request',
           'feed_override_request', 'fault_reason', 'target_gap_mm', 'velocity_mm_s')
"""The ``FollowStatus`` fields the CNC and the job runner read (job/cnc.py, job/runner.py)."""

NO_STATUS: dict[str, Any] = {
    'state': int(FollowState.IDLE), 'substate': 0, 'in_position': False, 'ready_to_move': False,
    'feed_hold_request': False, 'feed_override_request': 1.0, 'fault_reason': '',
    'target_gap_mm': math.nan, 'velocity_mm_s': 0.0}
"""The answers before the controller's first status: idle, nothing asked."""


class JobDrive:
    """The job runner's controller in the sim node (module docstring)."""

    def __init__(self, node: Any, bridge: Any) -> None:
        """``node``: the sim node (its CNC publisher, status reader, follow clients)."""
        self.node = node
        self.bridge = bridge
        self.lockstep = bridge.lockstep
        self._status_cdr = CdrPacker('ladrc_msgs/msg/FollowStatus')
        index = self._status_cdr.index
        self._fields = [index[n] for n in ANSWERS]
        self._seq_field = index['sample_seq']
        self.answers: dict[str, Any] = dict(NO_STATUS)
        self._answered = -1  # sample_seq of the newest status taken
        self._x_mm = self._y_mm = math.nan
        self._cnc: CncInput | None = None  # the CNC's newest sample, not sent yet
        self._pending: list[tuple[str, Any]] = []  # live: commands sent, answers not yet seen
        self._refused: list[tuple[str, str]] = []

    # ---- the job runner's hooks ---------------------------------------------------------
    def truth(self, t_s: float, true_gap_mm: float, sheet_mm: float, nozzle_mm: float,
              coverage: float, plate_velocity_mm_s: float, x_mm: float, y_mm: float) -> None:
        """Truth of the coming tick, the nozzle's XY included (``sim/truth``)."""
        self._x_mm, self._y_mm = x_mm, y_mm
        self.bridge.truth(t_s, true_gap_mm, sheet_mm, nozzle_mm, coverage, plate_velocity_mm_s,
                          x_mm, y_mm)

    def quick_stop(self) -> bool:
        """Return True while the drive brakes (watchdog or commander fault)."""
        return self.bridge.quick_stop()

    def step(self, tick: TickInput, cnc: CncInput | None) -> float:
        """Send the CNC's sample, step the drive; lock step: wait for the step's status.

        Live, a cycle the drive catches up silently (its process was late) sends nothing:
        the CNC's newest sample goes out with the next cycle that publishes, and the status
        is read then (a silent cycle must cost as little as it can, or catching up takes
        longer than the controller's stale-input limit allows).
        """
        if cnc is not None:
            self._cnc = cnc
        silent = self.bridge.will_be_silent()
        if self._cnc is not None and not silent:
            self.node.publish_cnc(self._cnc, self._x_mm, self._y_mm)
            self._cnc = None
        velocity = self.bridge.step(tick)
        if self.lockstep:
            step = self.bridge.seq - 1
            self.bridge._await(lambda: self._take_status() >= step,
                               f'no follow/status answering step {step}')
        elif not silent:
            self._take_status()
        return velocity

    def internals(self) -> dict[str, Any]:
        """Return the controller's answers: its newest ``FollowStatus`` (``ANSWERS``)."""
        return self.answers

    def command(self, name: str, **kwargs: Any) -> tuple[bool, str]:
        """Send a CNC command to the follow service; lock step: return its answer."""
        future = self.node.send_follow_command(name, kwargs)
        if not self.lockstep:
            self._pending.append((name, future))
            return True, 'sent'
        self.bridge._await(future.done, f'no answer to the {name} service call')
        result = future.result()
        return (bool(result.accepted), str(result.message)) if result is not None else (
            False, 'no answer')

    def refusals(self) -> list[tuple[str, str]]:
        """Live: return the commands refused since the last call, as (name, message)."""
        if self._pending:
            still = []
            for name, future in self._pending:
                if not future.done():
                    still.append((name, future))
                    continue
                result = future.result()
                if result is None or not result.accepted:
                    self._refused.append((name, result.message if result else 'no answer'))
            self._pending = still
        out, self._refused = self._refused, []
        return out

    # ---- the status reader ----------------------------------------------------------------
    def _take_status(self) -> int:
        """Take the statuses that arrived; keep the newest; return its ``sample_seq``."""
        reader = self.node.status_reader
        while (taken := reader.take()) is not None:
            try:
                values = self._status_cdr.unpack(taken[0])
            except ValueError:
                continue  # not the contract's message: nobody's answer
            self._answered = values[self._seq_field]
            self.answers = dict(zip(ANSWERS, (values[i] for i in self._fields), strict=True))
        return self._answered
