"""The follow states, the transition table, the tick input and the status codes.

The transition table is the machine's whole graph (notes §3.5 ``Follow_OnStep``, completed where
the seed is a fragment: docs/follow-state-machine.md): :meth:`FollowController.enter` refuses
any (from, to) pair that is not in it, and :func:`diagram` draws the docs' diagram from it.
"""

from __future__ import annotations

from enum import IntEnum
from typing import NamedTuple


class FollowState(IntEnum):
    """Follow states; the values are ``ladrc_msgs/FollowStatus`` ``STATE_*``."""

    IDLE = 0
    LOCKING = 1
    PREINTERPOLATE = 2
    PID = 3
    LADRC = 4
    FAULT = 5


IDLE, LOCKING, PREINTERPOLATE, PID, LADRC, FAULT = (int(s) for s in FollowState)
FOLLOWING = (LOCKING, PREINTERPOLATE, PID, LADRC)
"""The states in which a follow is running (``set_target`` and the like are accepted)."""

_S = FollowState
TRANSITIONS: dict[tuple[int, int], str] = {
    (_S.IDLE, _S.IDLE): 'stop_follow',
    (_S.IDLE, _S.LOCKING): 'start_follow',
    (_S.LOCKING, _S.PREINTERPOLATE): 'inputs usable on two ticks (seed Locking_IsFinished)',
    (_S.PREINTERPOLATE, _S.PREINTERPOLATE): 'gradient follow due',
    (_S.PREINTERPOLATE, _S.PID): 'seed hand-over rule, or the plan finished in the window',
    (_S.PID, _S.PREINTERPOLATE): 'target change > retarget_threshold_mm, gradient follow due',
    (_S.PID, _S.LADRC): 'followed, controller ladrc, not machining (or ladrc_while_machining)',
    (_S.LADRC, _S.PREINTERPOLATE): 'target change > retarget_threshold_mm, gradient follow due',
    (_S.LADRC, _S.PID): 'machining starts (ladrc_while_machining false), or controller pid',
    (_S.LOCKING, _S.IDLE): 'stop_follow',
    (_S.PREINTERPOLATE, _S.IDLE): 'stop_follow',
    (_S.PID, _S.IDLE): 'stop_follow',
    (_S.LADRC, _S.IDLE): 'stop_follow',
    (_S.LOCKING, _S.FAULT): 'collision at start, LOCKING timeout',
    (_S.PREINTERPOLATE, _S.FAULT): 'input gate, edge guard, not followed in time, drive',
    (_S.PID, _S.FAULT): 'input gate, edge guard, not followed in time, drive',
    (_S.LADRC, _S.FAULT): 'input gate, edge guard, drive',
    (_S.FAULT, _S.FAULT): 'collision evidence while in FAULT (retract once)',
    (_S.IDLE, _S.FAULT): 'an exception or a non-finite command in the tick',
    (_S.FAULT, _S.IDLE): 'reset_fault (no retract running, drive healthy)',
}
"""(from, to) -> what triggers it. Exceptions and non-finite commands enter FAULT from any
state (:meth:`FollowController.fail`); those from following states are covered above."""


def diagram() -> str:
    """Return the transition table as a Mermaid ``stateDiagram-v2`` (the docs' diagram)."""
    lines = ['stateDiagram-v2', '    [*] --> IDLE']
    for (a, b), why in TRANSITIONS.items():
        lines.append(f'    {FollowState(a).name} --> {FollowState(b).name}: {why}')
    return '\n'.join(lines) + '\n'


class TickInput(NamedTuple):
    """Inputs of one controller tick (the sim runner's ``TickInput`` plus ``gap_status``).

    ``gap_status`` is ``CapacitiveHeight.status`` (``GAP_STATUS_*``); it is the last field
    with a default, so an 8-field tuple (the sim runner's) is accepted too: a status of 0
    with ``gap_valid`` false means "not reported" and the cause is inferred from the reading
    (at or below ``collision_gap_mm``: collision; otherwise out of range / miss-panel).
    """

    t_s: float
    gap_mm: float
    gap_valid: bool
    gap_stamp_s: float
    encoder_mm: float
    encoder_stamp_s: float
    drive_enabled: bool
    drive_fault: bool
    gap_status: int = 0


# ladrc_msgs/CapacitiveHeight STATUS_*
GAP_STATUS_OK = 0
GAP_STATUS_OUT_OF_RANGE = 1
GAP_STATUS_COLLISION = 2
GAP_STATUS_FAULT = 3

# ladrc_msgs/FollowStatus LIMIT_* bits
LIMIT_VELOCITY = 1
LIMIT_ACCELERATION = 2
LIMIT_ESO_STATE = 4
LIMIT_SOFT_Z = 8

# internals() keys = these ladrc_msgs/FollowStatus fields
INTERNALS_KEYS = (
    'state', 'followed', 'machining', 'fault_reason', 'target_gap_mm', 'fused_gap_mm',
    'td_x1_mm', 'td_x2_mm_s', 'eso_z1_mm', 'eso_z2', 'eso_z3', 'u0_mm_s', 'p_term_mm_s',
    'd_term_mm_s', 'disturbance_term_mm_s', 'u_unlimited_mm_s', 'velocity_mm_s',
    'limit_flags',
)

# where this tick's command came from (FollowStatus p/d terms and limit flags follow it)
SOURCE_NONE, SOURCE_INTERP, SOURCE_PID, SOURCE_LADRC = 0, 1, 2, 3
