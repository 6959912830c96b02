"""The follow states, the transition table, and the codes the machine uses as plain ints.

The transition table is the machine's whole graph (notes §3.5 ``Follow_OnStep``, completed where
the seed is a fragment: docs/follow-state-machine.md): :meth:`FollowController.enter` refuses
any (from, to) pair that is not in it, and :func:`diagram` draws the docs' diagram from it.
"""

from __future__ import annotations

from ladrc_contract.codes import FollowState, GapStatus, LimitFlag
from ladrc_contract.tick import TickInput

__all__ = ['FollowState', 'TickInput']

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
    (_S.PREINTERPOLATE, _S.FAULT): 'input gate, not followed in time, drive',
    (_S.PID, _S.FAULT): 'input gate, not followed in time, drive',
    (_S.LADRC, _S.FAULT): 'input gate, drive',
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


# the contract's codes (ladrc_contract.codes) as plain ints, for the tick path
GAP_STATUS_OK, GAP_STATUS_OUT_OF_RANGE, GAP_STATUS_COLLISION, GAP_STATUS_FAULT = (
    int(c) for c in GapStatus)
LIMIT_VELOCITY, LIMIT_ACCELERATION, LIMIT_ESO_STATE, LIMIT_SOFT_Z = (int(c) for c in LimitFlag)

# internals() keys = these ladrc_msgs/FollowStatus fields
INTERNALS_KEYS = (
    'state', 'followed', 'machining', 'fault_reason', 'target_gap_mm', 'fused_gap_mm',
    'td_x1_mm', 'td_x2_mm_s', 'eso_z1_mm', 'eso_z2', 'eso_z3', 'u0_mm_s', 'p_term_mm_s',
    'd_term_mm_s', 'disturbance_term_mm_s', 'u_unlimited_mm_s', 'velocity_mm_s',
    'limit_flags',
)
# ... followed by these (FollowStatus revision 2): the CNC partner's answers and the CNC values
# the tick used (control/follow/cnc.py); bags from before it lack them
ANSWER_KEYS = (
    'substate', 'hold_reason', 'in_position', 'ready_to_move', 'feed_hold_request',
    'feed_override_request', 'cnc_seq', 'cnc_stamp_s', 'cnc_segment', 'cnc_beam_on',
    'cnc_contour', 'cnc_commanded_feed_mm_s', 'cnc_actual_feed_mm_s', 'cnc_segment_left_mm',
    'cnc_edge_ahead_mm',
)

# where this tick's command came from (FollowStatus p/d terms and limit flags follow it)
SOURCE_NONE, SOURCE_INTERP, SOURCE_PID, SOURCE_LADRC = 0, 1, 2, 3
