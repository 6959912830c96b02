"""The CiA 402 power drive state machine (FSA) as the master sees it; plain Python, no I/O.

The drive reports its state in the statusword (0x6041) and is commanded by the controlword
(0x6040) (CiA 402-2, "Drive control"). This module names the states, decodes a statusword
(:func:`state_of`), holds the controlword commands, and gives the one controlword that moves
the drive one transition toward a goal (:func:`next_controlword`): a pure function of the state
the drive reported and the state wanted, called once per cycle (SYNC) by the driver.

Why not canopen's ``BaseNode402`` for the cyclic path: its state setter sends a controlword and
then polls the statusword until the state changes, up to 0.8 s per transition; a 2 kHz axis
cannot block its loop that long, and with SYNC-transmitted RPDOs the controlword must be sent in
every cycle anyway (its setter sends it once). Its op-mode setter logs errors instead of raising,
and its ``reset_from_fault`` does not check the fault cleared. So the cyclic path sends
``next_controlword(state_of(statusword), goal)`` in every RPDO and looks at the state the next
TPDO reports: one transition per cycle, never a wait. (Configuration at start, by SDO, may wait:
it is not cyclic.)

Transitions of the standard (numbers as in CiA 402 / IEC 61800-7-201):

====  ===========================================  ==========================================
 #    from -> to                                   command
====  ===========================================  ==========================================
 0    (power on) -> Not ready to switch on         automatic
 1    Not ready -> Switch on disabled              automatic (initialised)
 2    Switch on disabled -> Ready to switch on     shutdown (0x06)
 3    Ready to switch on -> Switched on            switch on (0x07)
 4    Switched on -> Operation enabled             enable operation (0x0F)
 5    Operation enabled -> Switched on             disable operation (0x07)
 6    Switched on -> Ready to switch on            shutdown
 7    Ready to switch on -> Switch on disabled     disable voltage (0x00) or quick stop (0x02)
 8    Operation enabled -> Ready to switch on      shutdown
 9    Operation enabled -> Switch on disabled      disable voltage
 10   Switched on -> Switch on disabled            disable voltage or quick stop
 11   Operation enabled -> Quick stop active       quick stop
 12   Quick stop active -> Switch on disabled      quick stop done (option code 1, 2) or
                                                   disable voltage
 13   any -> Fault reaction active                 a fault
 14   Fault reaction active -> Fault               fault reaction done
 15   Fault -> Switch on disabled                  fault reset (bit 7 rising edge)
 16   Quick stop active -> Operation enabled       enable operation (option code 5..8)
====  ===========================================  ==========================================
"""

from __future__ import annotations

from enum import Enum

CONTROLWORD = 0x6040
STATUSWORD = 0x6041
MODES_OF_OPERATION = 0x6060
MODES_OF_OPERATION_DISPLAY = 0x6061
QUICK_STOP_OPTION_CODE = 0x605A

# modes of operation (0x6060 / 0x6061)
MODE_PROFILE_VELOCITY = 3
MODE_CYCLIC_SYNC_VELOCITY = 9
MODE_NAMES = {MODE_PROFILE_VELOCITY: 'profile velocity',
              MODE_CYCLIC_SYNC_VELOCITY: 'cyclic synchronous velocity'}

# controlword commands (bits 0 switch on, 1 enable voltage, 2 quick stop (active low),
# 3 enable operation, 7 fault reset)
CW_DISABLE_VOLTAGE = 0x00
CW_QUICK_STOP = 0x02
CW_SHUTDOWN = 0x06
CW_SWITCH_ON = 0x07
CW_DISABLE_OPERATION = 0x07
CW_ENABLE_OPERATION = 0x0F
CW_FAULT_RESET = 0x80  # bit 7: a reset happens on its rising edge (0 -> 1)

# statusword bits beyond the state
SW_VOLTAGE_ENABLED = 0x0010
SW_WARNING = 0x0080
SW_REMOTE = 0x0200
SW_TARGET_REACHED = 0x0400
SW_INTERNAL_LIMIT = 0x0800


class State(Enum):
    """The eight states of the power drive state machine."""

    NOT_READY_TO_SWITCH_ON = 'Not ready to switch on'
    SWITCH_ON_DISABLED = 'Switch on disabled'
    READY_TO_SWITCH_ON = 'Ready to switch on'
    SWITCHED_ON = 'Switched on'
    OPERATION_ENABLED = 'Operation enabled'
    QUICK_STOP_ACTIVE = 'Quick stop active'
    FAULT_REACTION_ACTIVE = 'Fault reaction active'
    FAULT = 'Fault'


# (mask, value) of the statusword per state (bits 0-3 ready/switched on/op enabled/fault,
# 5 quick stop (active low), 6 switch on disabled)
STATUS_PATTERNS: dict[State, tuple[int, int]] = {
    State.NOT_READY_TO_SWITCH_ON: (0x4F, 0x00),
    State.SWITCH_ON_DISABLED: (0x4F, 0x40),
    State.READY_TO_SWITCH_ON: (0x6F, 0x21),
    State.SWITCHED_ON: (0x6F, 0x23),
    State.OPERATION_ENABLED: (0x6F, 0x27),
    State.QUICK_STOP_ACTIVE: (0x6F, 0x07),
    State.FAULT_REACTION_ACTIVE: (0x4F, 0x0F),
    State.FAULT: (0x4F, 0x08),
}


class UnknownStatus(ValueError):
    """A statusword that matches no state of the standard (a broken drive or frame)."""


def state_of(statusword: int) -> State:
    """Return the state a statusword reports; raise :class:`UnknownStatus` for none."""
    for state, (mask, value) in STATUS_PATTERNS.items():
        if statusword & mask == value:
            return state
    raise UnknownStatus(f'statusword 0x{statusword:04X} is no CiA 402 state')


def statusword_bits(state: State) -> int:
    """Return the state bits of a statusword in ``state`` (what a drive sets; others 0)."""
    return STATUS_PATTERNS[state][1]


class Goal(Enum):
    """Where the master wants the drive: running, at rest without power, or braking."""

    OPERATION_ENABLED = 'operation enabled'
    SWITCH_ON_DISABLED = 'switch on disabled'
    QUICK_STOP = 'quick stop'


def next_controlword(state: State, goal: Goal, reset_fault: bool = False,
                     previous: int | None = None) -> int:
    """Return the controlword that moves the drive one transition from ``state`` to ``goal``.

    Pure and non-blocking: called once per cycle with the state the drive last reported; the
    drive makes (at most) one transition per cycle, the next call sees the new state.

    * toward Operation enabled: 2 (shutdown), 3 (switch on), 4 (enable operation); from Quick
      stop active it disables voltage (12) and starts again: transition 16 depends on the
      drive's quick stop option code, 12 does not;
    * toward Switch on disabled: disable voltage (7, 9, 10, 12);
    * quick stop: from Operation enabled the quick stop command (11), kept while it brakes;
      from the other powered states disable voltage (the axis is not moving under power);
    * in Fault: the fault reset needs a rising edge of bit 7. With ``reset_fault`` the
      controlword is 0x80 if the ``previous`` controlword sent lacked bit 7 and 0x00 otherwise,
      so successive calls give 0x00, 0x80, 0x00, 0x80 ... (one edge every second cycle) until
      the drive leaves Fault. Without ``reset_fault`` a faulted drive gets 0x00: a reset is
      the operator's decision, never automatic;
    * Fault reaction active, Not ready to switch on: 0x00 (nothing is accepted; wait).
    """
    if state is State.FAULT:
        if reset_fault and previous is not None and not previous & CW_FAULT_RESET:
            return CW_FAULT_RESET
        return CW_DISABLE_VOLTAGE
    if state in (State.FAULT_REACTION_ACTIVE, State.NOT_READY_TO_SWITCH_ON):
        return CW_DISABLE_VOLTAGE
    if goal is Goal.SWITCH_ON_DISABLED:
        return CW_DISABLE_VOLTAGE
    if goal is Goal.QUICK_STOP:
        if state in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE):
            return CW_QUICK_STOP
        return CW_DISABLE_VOLTAGE
    # toward Operation enabled
    return {
        State.SWITCH_ON_DISABLED: CW_SHUTDOWN,
        State.READY_TO_SWITCH_ON: CW_SWITCH_ON,
        State.SWITCHED_ON: CW_ENABLE_OPERATION,
        State.OPERATION_ENABLED: CW_ENABLE_OPERATION,
        State.QUICK_STOP_ACTIVE: CW_DISABLE_VOLTAGE,
    }[state]


class Command(Enum):
    """A controlword decoded as the drive reads it (bits 7, 3, 2, 1, 0)."""

    SHUTDOWN = 'shutdown'
    SWITCH_ON = 'switch on'
    ENABLE_OPERATION = 'enable operation'  # also "switch on + enable operation"
    DISABLE_VOLTAGE = 'disable voltage'
    QUICK_STOP = 'quick stop'
    FAULT_RESET = 'fault reset'  # bit 7 set (the edge is the drive's to detect)


def command_of(controlword: int) -> Command:
    """Decode a controlword into the device-control command (CiA 402 table, x = any bit).

    Disable voltage (0xxx xx0x) and quick stop (0xxx x01x) win over the rest; 0xxx 0111 is
    switch on (= disable operation from Operation enabled), 0xxx 1111 enable operation and
    0xxx x110 shutdown.
    """
    cw = controlword
    if cw & CW_FAULT_RESET:
        return Command.FAULT_RESET
    if not cw & 0x02:
        return Command.DISABLE_VOLTAGE
    if not cw & 0x04:
        return Command.QUICK_STOP
    if not cw & 0x01:
        return Command.SHUTDOWN
    if cw & 0x08:
        return Command.ENABLE_OPERATION
    return Command.SWITCH_ON
