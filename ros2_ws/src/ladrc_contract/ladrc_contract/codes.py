"""The contract's message codes as enums: one definition, checked against the generated messages.

Each enum's values are the ``ladrc_msgs`` constants of the same name (``FollowStatus.STATE_*``,
``SUB_*``, ``LIMIT_*``, ``CapacitiveHeight.STATUS_*``, ``FollowEvent`` kinds,
``CncMotion.SEGMENT_*``); tests/ros/test_msgs_contract.py compares them with the generated
classes, and tests/test_contract_once.py fails when another module defines a code table. Pure
Python: the control core, the models and the bag tools use them without rclpy.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag


class FollowState(IntEnum):
    """Follow states: ``FollowStatus.STATE_*``."""

    IDLE = 0
    LOCKING = 1
    PREINTERPOLATE = 2
    PID = 3
    LADRC = 4
    FAULT = 5


class SubState(IntEnum):
    """Why a command is held or shaped inside a state: ``FollowStatus.SUB_*``."""

    NONE = 0
    CORNER_LOCK = 1
    VOID_LOCK = 2
    PIERCE = 3
    THC_DELAY = 4
    LIFT = 5
    LEAPFROG = 6
    HOLD = 7
    EDGE_AHEAD = 8
    RETRACT = 9


class LimitFlag(IntFlag):
    """Which limits shaped a tick's command: ``FollowStatus.LIMIT_*`` bits."""

    VELOCITY = 1
    ACCELERATION = 2
    ESO_STATE = 4
    SOFT_Z = 8


class GapStatus(IntEnum):
    """Why a reading is not usable: ``CapacitiveHeight.STATUS_*``."""

    OK = 0
    OUT_OF_RANGE = 1
    COLLISION = 2
    FAULT = 3


class EventKind(IntEnum):
    """What a ``FollowEvent`` records: its ``kind`` constants."""

    START_FOLLOW = 1
    STOP_FOLLOW = 2
    SET_TARGET = 3
    MACHINING = 4
    HEIGHT_COMPENSATION = 5
    GRADIENT_FOLLOW = 6
    RESET_FAULT = 7
    PARAMETERS = 8
    TARGET_WAVE = 9
    PIERCE = 10
    LIFT = 11
    LEAPFROG = 12
    HOLD = 13


class FaultCode(IntEnum):
    """Why the controller entered FAULT, by kind (its ``fault_reason`` says the detail).

    The timing guards (:data:`TIMING_GUARDS`) are the faults a late process can cause: an input
    older than ``follow.stale_timeout_s`` or stamped ahead, the loop's own sample period or
    lock step, and the drive's report of a fault (its command watchdog among them).
    """

    NONE = 0
    STALE_INPUT = 1     # an input older than the stale limit, or stamped in the future
    LOOP_TIMING = 2     # the loop's sample period or lock step out of its limits
    DRIVE = 3           # the drive reports a fault or was disabled while following
    COLLISION = 4       # contact evidence (a retract follows)
    NOT_FOLLOWED = 5    # not followed within the time limit (edge check, approach)
    SENSOR = 6          # the gap reading: not finite, frozen, invalid too long, miss-panel
    ENCODER = 7         # the encoder position not finite
    START = 8           # start_follow could not lock (LOCKING timeout)
    INTERNAL = 9        # an exception or a non-finite command in the tick
    TOPOLOGY = 10       # the graph: a second commander, a missing input publisher


TIMING_GUARDS = frozenset({FaultCode.STALE_INPUT, FaultCode.LOOP_TIMING, FaultCode.DRIVE})
"""Fault codes a stall of the machine can cause (a real fault can cause them too)."""


class Segment(IntEnum):
    """The kind of the CNC's segment: ``CncMotion.SEGMENT_*``."""

    NONE = 0
    RAPID = 1
    CUT = 2
    PIERCE = 3


# the generated message each enum mirrors, and the prefix of its constants
MESSAGE_CONSTANTS: dict[type, tuple[str, str]] = {
    FollowState: ('ladrc_msgs/msg/FollowStatus', 'STATE_'),
    SubState: ('ladrc_msgs/msg/FollowStatus', 'SUB_'),
    LimitFlag: ('ladrc_msgs/msg/FollowStatus', 'LIMIT_'),
    GapStatus: ('ladrc_msgs/msg/CapacitiveHeight', 'STATUS_'),
    EventKind: ('ladrc_msgs/msg/FollowEvent', ''),
    Segment: ('ladrc_msgs/msg/CncMotion', 'SEGMENT_'),
}
