"""The CNC's link to the height controller on the ROS graph: its answers in, its commands out.

The simulated CNC (:mod:`ladrc_sim.job.cnc`) reads the controller's answers (the
``FollowStatus`` fields it needs: docs/interfaces.md, "CNC interface") and sends its commands to
the follow services. :class:`FollowLink` is that over DDS, for whichever node plays the CNC (the
sim node's :mod:`.job_drive`, or the CNC node): the newest status taken straight from the reader
(raw CDR), the commands sent without waiting live (a refusal, when its answer comes, is
returned by :meth:`refusals` and aborts the job) or awaited in lock step (the answer before the
step goes on, the headless runner's order).
"""

from __future__ import annotations

import math
from typing import Any, Callable

from ladrc_contract.cdr import CdrPacker
from ladrc_contract.codes import FollowState

ANSWERS = ('state', 'substate', 'in_position', 'ready_to_move', 'feed_hold_request',
           'feed_override_request', 'fault_reason', 'target_gap_mm', 'velocity_mm_s')
"""The ``FollowStatus`` fields the CNC and the job runner read (job/cnc.py, job/runner.py)."""

NO_STATUS: dict[str, Any] = {
    'state': int(FollowState.IDLE), 'substate': 0, 'in_position': False, 'ready_to_move': False,
    'feed_hold_request': False, 'feed_override_request': 1.0, 'fault_reason': '',
    'target_gap_mm': math.nan, 'velocity_mm_s': 0.0}
"""The answers before the controller's first status: idle, nothing asked."""


class FollowLink:
    """The controller's answers (``answers``) and the CNC's commands, for a node playing a CNC.

    ``node``: its ``status_reader`` (a loop reader of ``follow/status``) and
    ``send_follow_command(name, args)`` (returns the service call's future); ``wait(condition,
    what)``: waits until ``condition()`` in lock step (aborts with ``what`` past its timeout).
    """

    def __init__(self, node: Any, lockstep: bool,
                 wait: Callable[[Callable[[], bool], str], None]) -> None:
        self.node = node
        self.lockstep = lockstep
        self.wait = wait
        self._status_cdr = CdrPacker('ladrc_msgs/msg/FollowStatus')
        index = self._status_cdr.index
        self._fields = [index[n] for n in ANSWERS]
        self._seq_field = index['sample_seq']
        self._gap_seq_field = index['gap_seq']
        self.answers: dict[str, Any] = dict(NO_STATUS)
        self.answered = -1  # sample_seq of the newest status taken
        self.gap_seq = 0  # gap_seq of the newest status (0: the controller has no sample yet)
        self._pending: list[tuple[str, Any]] = []  # live: commands sent, answers not yet seen
        self._refused: list[tuple[str, str]] = []

    def take_status(self) -> int:
        """Take the statuses that arrived; keep the newest; return its ``sample_seq``."""
        reader = self.node.status_reader
        while (taken := reader.take()) is not None:
            try:
                values = self._status_cdr.unpack(taken[0])
            except ValueError:
                continue  # not the contract's message: nobody's answer
            self.answered = values[self._seq_field]
            self.gap_seq = values[self._gap_seq_field]
            self.answers = dict(zip(ANSWERS, (values[i] for i in self._fields), strict=True))
        return self.answered

    def await_status(self, step: int) -> None:
        """Lock step: wait for the status answering ``step``."""
        self.wait(lambda: self.take_status() >= step, f'no follow/status answering step {step}')

    def command(self, name: str, **kwargs: Any) -> tuple[bool, str]:
        """Send a CNC command to the follow service; lock step: return its answer."""
        future = self.node.send_follow_command(name, kwargs)
        if not self.lockstep:
            self._pending.append((name, future))
            return True, 'sent'
        self.wait(future.done, f'no answer to the {name} service call')
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
