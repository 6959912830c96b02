"""The follow controller (notes §3.5 ``Follow_OnStep``): a state machine driving PID / LADRC.

One concern per module:

* :mod:`.states`: the states, the transition table (and the docs' diagram drawn from it), the
  tick input, the status codes;
* :mod:`.input_gate`: what of a tick's inputs may reach the law, as a verdict with its reason;
* :mod:`.limiter`: the output limiter every command passes (v, a·h, soft Z, gradient caps);
* :mod:`.commands`: the follow commands, one validator and one apply function each;
* :mod:`.machine`: :class:`FollowController`, one tick function per state, every transition
  through ``enter``.
"""

from ..follow_params import FollowParams
from .commands import COMMANDS, MAX_DELAY_S, MIN_GRADIENT
from .machine import FollowController, PreparedSet
from .states import (
    ANSWER_KEYS,
    GAP_STATUS_COLLISION,
    GAP_STATUS_FAULT,
    GAP_STATUS_OK,
    GAP_STATUS_OUT_OF_RANGE,
    INTERNALS_KEYS,
    LIMIT_ACCELERATION,
    LIMIT_ESO_STATE,
    LIMIT_SOFT_Z,
    LIMIT_VELOCITY,
    TRANSITIONS,
    FollowState,
    TickInput,
)

__all__ = [
    'FollowState', 'FollowParams', 'FollowController', 'PreparedSet', 'TickInput',
    'GAP_STATUS_OK', 'GAP_STATUS_OUT_OF_RANGE', 'GAP_STATUS_COLLISION', 'GAP_STATUS_FAULT',
    'LIMIT_VELOCITY', 'LIMIT_ACCELERATION', 'LIMIT_ESO_STATE', 'LIMIT_SOFT_Z',
    'INTERNALS_KEYS', 'ANSWER_KEYS', 'COMMANDS', 'MAX_DELAY_S', 'MIN_GRADIENT', 'TRANSITIONS',
]
