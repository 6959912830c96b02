"""The emulated drive's CiA 402 device: its power state machine over the simulator's axis.

Plain Python, no bus: :meth:`Cia402Device.step` is one drive period (one SYNC). It takes the
controlword and target velocity the drive holds in its dictionary at that SYNC, makes at most
one transition of the standard's state machine (table in ``ladrc_cia402.ds402``), advances the
axis one period and leaves the statusword and actual values to be sent in the TPDOs.

* CSV (0x6060 = 9) and profile velocity (3): in Operation enabled the target velocity (velocity
  units -> mm/s by the drive's :class:`~ladrc_cia402.units.DriveUnits`) is applied for the
  period, clipped to ``max_velocity_units`` (the drive's limit; the axis model then applies its
  own velocity and acceleration limits). Profile velocity is treated as CSV here (the model's
  acceleration limit is the profile); a real drive ramps at 0x6083.
* Quick stop active and Fault reaction active: the axis brakes to standstill (the model's
  disabled-drive braking at its acceleration limit); at standstill Quick stop active goes to
  Switch on disabled (option codes 1, 2; 5, 6 stay and allow transition 16) and Fault reaction
  active to Fault. The other states: axis not powered (the model brakes it too: a holding
  brake).
* Faults (:meth:`fault`): from any state to Fault reaction active (13) at the next period, the
  EMCY queued in :attr:`events` for the emulator to send; fault reset (15) on the rising edge
  of controlword bit 7 in Fault (the EMCY "error reset", code 0, queued).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

from ladrc_cia402 import (
    CW_FAULT_RESET,
    MODE_CYCLIC_SYNC_VELOCITY,
    MODE_PROFILE_VELOCITY,
    REG_GENERIC,
    SW_REMOTE,
    SW_VOLTAGE_ENABLED,
    Command,
    DriveUnits,
    State,
    command_of,
    statusword_bits,
)

SUPPORTED_MODES = (MODE_PROFILE_VELOCITY, MODE_CYCLIC_SYNC_VELOCITY)
POWERED = (State.READY_TO_SWITCH_ON, State.SWITCHED_ON, State.OPERATION_ENABLED,
           State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE)

# (state, command) -> (next state, the standard's number); 12 at rest, 13-16: see step()
TRANSITIONS: dict[tuple[State, Command], tuple[State, int]] = {
    (State.SWITCH_ON_DISABLED, Command.SHUTDOWN): (State.READY_TO_SWITCH_ON, 2),
    (State.READY_TO_SWITCH_ON, Command.SWITCH_ON): (State.SWITCHED_ON, 3),
    # "switch on + enable operation" from Ready to switch on: 3 now, 4 next period
    (State.READY_TO_SWITCH_ON, Command.ENABLE_OPERATION): (State.SWITCHED_ON, 3),
    (State.SWITCHED_ON, Command.ENABLE_OPERATION): (State.OPERATION_ENABLED, 4),
    (State.OPERATION_ENABLED, Command.SWITCH_ON): (State.SWITCHED_ON, 5),
    (State.SWITCHED_ON, Command.SHUTDOWN): (State.READY_TO_SWITCH_ON, 6),
    (State.READY_TO_SWITCH_ON, Command.DISABLE_VOLTAGE): (State.SWITCH_ON_DISABLED, 7),
    (State.READY_TO_SWITCH_ON, Command.QUICK_STOP): (State.SWITCH_ON_DISABLED, 7),
    (State.OPERATION_ENABLED, Command.SHUTDOWN): (State.READY_TO_SWITCH_ON, 8),
    (State.OPERATION_ENABLED, Command.DISABLE_VOLTAGE): (State.SWITCH_ON_DISABLED, 9),
    (State.SWITCHED_ON, Command.DISABLE_VOLTAGE): (State.SWITCH_ON_DISABLED, 10),
    (State.SWITCHED_ON, Command.QUICK_STOP): (State.SWITCH_ON_DISABLED, 10),
    (State.OPERATION_ENABLED, Command.QUICK_STOP): (State.QUICK_STOP_ACTIVE, 11),
    (State.QUICK_STOP_ACTIVE, Command.DISABLE_VOLTAGE): (State.SWITCH_ON_DISABLED, 12),
}


class Plant(Protocol):
    """The axis as the device drives it (``ladrc_sim.models.axis.Axis``)."""

    position_mm: float
    velocity_mm_s: float

    def step(self, cmd_mm_s: float, enabled: bool = True, fault: bool = False
             ) -> tuple[float, float]:
        """One period; ``(position_mm, velocity_mm_s)`` after it."""


@dataclass
class Emcy:
    """An EMCY to send: error code, error register, manufacturer bytes (5)."""

    code: int
    register: int = REG_GENERIC
    manufacturer: bytes = b''


@dataclass
class Cia402Device:
    """One CiA 402 drive over a plant; :meth:`step` once per SYNC."""

    plant: Plant
    units: DriveUnits = field(default_factory=DriveUnits)
    max_velocity_units: int = 200_000  # 200 mm/s at the default units
    quick_stop_option: int = 2
    state: State = State.NOT_READY_TO_SWITCH_ON
    mode: int = 0
    error_code: int = 0
    events: list[Emcy] = field(default_factory=list)
    transitions: list[int] = field(default_factory=list)  # the standard's numbers, in order
    _controlword: int = 0  # the last one applied (for the bit-7 edge)
    _fault: Emcy | None = None  # raised, not yet entered
    _before: State = State.NOT_READY_TO_SWITCH_ON  # the state when the period began

    # ---- configuration (by SDO) -------------------------------------------------------
    def set_mode(self, mode: int) -> None:
        """0x6060; ValueError for a mode this drive has not (the SDO server aborts)."""
        if mode not in SUPPORTED_MODES and mode != 0:
            raise ValueError(f'mode of operation {mode} not supported (3, 9)')
        self.mode = mode

    @property
    def mode_display(self) -> int:
        """0x6061: the mode in effect."""
        return self.mode

    # ---- faults -----------------------------------------------------------------------
    def fault(self, code: int, register: int = REG_GENERIC, manufacturer: bytes = b'') -> None:
        """Raise a fault: EMCY now, Fault reaction active at the next period (13).

        A fault raised while one is being handled (Fault reaction active, Fault) keeps the
        first error code; its EMCY is still sent.
        """
        emcy = Emcy(code, register | REG_GENERIC, manufacturer)
        self.events.append(emcy)
        if self.state not in (State.FAULT_REACTION_ACTIVE, State.FAULT) and self._fault is None:
            self._fault = emcy
            self.error_code = code

    @property
    def faulted(self) -> bool:
        """In Fault reaction active or Fault, or a fault raised and about to enter it."""
        return self._fault is not None or self.state in (State.FAULT_REACTION_ACTIVE,
                                                          State.FAULT)

    # ---- one period ---------------------------------------------------------------------
    def step(self, controlword: int, target_velocity: int) -> None:
        """One drive period over the device's own plant: :meth:`command`, the axis, :meth:`settle`.

        A braking state (Quick stop active, Fault reaction active) entered in this period ends
        at the earliest in the next one, at standstill: one transition per period.
        """
        cmd = self.command(controlword, target_velocity)
        # quick stop, fault reaction, not powered, no mode: brake to a stop
        self.plant.step(0.0 if cmd is None else cmd, enabled=cmd is not None)
        self.settle(self.plant.velocity_mm_s == 0.0)

    def command(self, controlword: int, target_velocity: int) -> float | None:
        """Run the period's state machine (one transition at most); return the velocity (mm/s).

        ``None``: the axis is not driven by the target this period (not in Operation enabled,
        or no velocity mode): it brakes at its deceleration limit. In Operation enabled the
        target (velocity units) is clipped to ``max_velocity_units`` and converted to mm/s.
        Whoever moves the axis (the plant here, the headless runner in the emulator) calls
        :meth:`settle` with the axis at rest or not once the period is applied.
        """
        self._before = self.state
        self._transition(controlword)
        self._controlword = controlword
        if self.state is State.OPERATION_ENABLED and self.mode in SUPPORTED_MODES:
            lim = self.max_velocity_units
            t = lim if target_velocity > lim else (-lim if target_velocity < -lim
                                                   else target_velocity)
            return self.units.velocity_mm_s(t)
        return None

    def settle(self, at_rest: bool) -> None:
        """End a braking state at standstill (12, 14), if no transition was made this period."""
        s = self.state
        if s is not self._before or not at_rest:
            return
        if s is State.QUICK_STOP_ACTIVE and self.quick_stop_option in (0, 1, 2, 3, 4):
            self._go(State.SWITCH_ON_DISABLED, 12)
        elif s is State.FAULT_REACTION_ACTIVE:
            self._go(State.FAULT, 14)

    def _go(self, state: State, number: int) -> None:
        self.state = state
        self.transitions.append(number)

    def _transition(self, cw: int) -> None:
        s = self.state
        if self._fault is not None:
            self._fault = None
            self._go(State.FAULT_REACTION_ACTIVE, 13)
            return
        if s is State.NOT_READY_TO_SWITCH_ON:
            self._go(State.SWITCH_ON_DISABLED, 1)  # initialised
            return
        if s is State.FAULT_REACTION_ACTIVE:
            return  # nothing is accepted until the reaction is done
        if s is State.FAULT:
            if cw & CW_FAULT_RESET and not self._controlword & CW_FAULT_RESET:
                self.error_code = 0
                self.events.append(Emcy(0, 0))  # EMCY "error reset / no error"
                self._go(State.SWITCH_ON_DISABLED, 15)
            return
        c = command_of(cw & ~CW_FAULT_RESET)  # bit 7 outside Fault: no meaning
        if s is State.QUICK_STOP_ACTIVE and c is Command.ENABLE_OPERATION \
                and self.quick_stop_option in (5, 6, 7, 8):
            self._go(State.OPERATION_ENABLED, 16)
            return
        nxt = TRANSITIONS.get((s, c))
        if nxt is not None:
            self._go(*nxt)

    # ---- what the TPDOs carry -----------------------------------------------------------
    @property
    def statusword(self) -> int:
        """0x6041: the state's bits, voltage enabled when powered, remote."""
        sw = statusword_bits(self.state) | SW_REMOTE
        if self.state in POWERED:
            sw |= SW_VOLTAGE_ENABLED
        return sw

    @property
    def position_increments(self) -> int:
        """0x6064 of the plant's true position (the encoder: nearest increment)."""
        return self.units.position_increments(self.plant.position_mm)

    @property
    def velocity_units(self) -> int:
        """0x606C."""
        return self.units.velocity_units(self.plant.velocity_mm_s)
