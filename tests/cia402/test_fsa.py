"""The CiA 402 power drive state machine, both sides: the master's and the emulated drive's.

The master's side (``ladrc_cia402.ds402``): statusword -> state for every state, the controlword
commands decoded, ``next_controlword`` reaching each goal one transition per cycle. The drive's
side (``ladrc_sim.cia402.device``): every transition of the standard (0..16) from its state and
command, fault reset only on the rising edge of bit 7, quick stop from Operation enabled braking
the axis model to rest. The two together: the master's controlwords drive the device to
Operation enabled and back.
"""

from __future__ import annotations

from ladrc_cia402 import ds402
from ladrc_cia402.ds402 import Command, Goal, State, command_of, next_controlword, state_of
from ladrc_cia402.units import DriveUnits
from ladrc_sim.cia402.device import Cia402Device
from ladrc_sim.models.axis import Axis, AxisParams
import pytest

S = State


# ---- the master's side ----------------------------------------------------------------------
@pytest.mark.parametrize('statusword, state', [
    (0x0000, S.NOT_READY_TO_SWITCH_ON), (0x0040, S.SWITCH_ON_DISABLED),
    (0x0021, S.READY_TO_SWITCH_ON), (0x0023, S.SWITCHED_ON), (0x0027, S.OPERATION_ENABLED),
    (0x0007, S.QUICK_STOP_ACTIVE), (0x000F, S.FAULT_REACTION_ACTIVE), (0x0008, S.FAULT),
    # the other bits (voltage enabled, warning, remote, target reached) do not matter
    (0x0637, S.OPERATION_ENABLED), (0x0250, S.SWITCH_ON_DISABLED), (0x0218, S.FAULT),
    (0x0031, S.READY_TO_SWITCH_ON), (0x0017, S.QUICK_STOP_ACTIVE),
])
def test_statusword_to_state(statusword, state):
    assert state_of(statusword) is state


def test_a_statusword_of_no_state_is_an_error():
    with pytest.raises(ds402.UnknownStatus):
        state_of(0x0001)  # ready to switch on without quick stop bit nor disabled bit


@pytest.mark.parametrize('cw, command', [
    (0x06, Command.SHUTDOWN), (0x0E, Command.SHUTDOWN), (0x07, Command.SWITCH_ON),
    (0x0F, Command.ENABLE_OPERATION), (0x00, Command.DISABLE_VOLTAGE),
    (0x0D, Command.DISABLE_VOLTAGE), (0x02, Command.QUICK_STOP), (0x0B, Command.QUICK_STOP),
    (0x80, Command.FAULT_RESET), (0x8F, Command.FAULT_RESET),
])
def test_controlword_commands(cw, command):
    assert command_of(cw) is command


def test_next_controlword_toward_each_goal():
    up = Goal.OPERATION_ENABLED
    assert next_controlword(S.SWITCH_ON_DISABLED, up) == 0x06
    assert next_controlword(S.READY_TO_SWITCH_ON, up) == 0x07
    assert next_controlword(S.SWITCHED_ON, up) == 0x0F
    assert next_controlword(S.OPERATION_ENABLED, up) == 0x0F
    assert next_controlword(S.QUICK_STOP_ACTIVE, up) == 0x00
    for s in (S.READY_TO_SWITCH_ON, S.SWITCHED_ON, S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE):
        assert next_controlword(s, Goal.SWITCH_ON_DISABLED) == 0x00
    assert next_controlword(S.OPERATION_ENABLED, Goal.QUICK_STOP) == 0x02
    assert next_controlword(S.QUICK_STOP_ACTIVE, Goal.QUICK_STOP) == 0x02
    assert next_controlword(S.SWITCHED_ON, Goal.QUICK_STOP) == 0x00
    for s in (S.FAULT_REACTION_ACTIVE, S.NOT_READY_TO_SWITCH_ON):
        assert next_controlword(s, up) == 0x00


def test_fault_reset_is_an_edge_and_never_automatic():
    assert next_controlword(S.FAULT, Goal.OPERATION_ENABLED) == 0x00  # no reset asked
    cws = []
    prev = None
    for _ in range(4):
        prev = next_controlword(S.FAULT, Goal.OPERATION_ENABLED, reset_fault=True,
                                previous=prev)
        cws.append(prev)
    assert cws == [0x00, 0x80, 0x00, 0x80]


# ---- the drive's side -------------------------------------------------------------------------
def _device(option: int = 2, h_s: float = 0.0005) -> Cia402Device:
    d = Cia402Device(Axis(AxisParams(), 0.0, h_s), DriveUnits(), quick_stop_option=option)
    d.set_mode(ds402.MODE_CYCLIC_SYNC_VELOCITY)
    d.step(0x00, 0)  # 1: initialised
    assert d.state is S.SWITCH_ON_DISABLED and d.transitions == [1]
    return d


def _to(d: Cia402Device, *cws: int) -> None:
    for cw in cws:
        d.step(cw, 0)


def _case(path: tuple[int, ...], cw: int, number: int, end: State, option: int = 2):
    d = _device(option)
    _to(d, *path)
    d.transitions.clear()
    d.step(cw, 0)
    assert d.transitions == [number], (path, hex(cw))
    assert d.state is end
    assert state_of(d.statusword) is end


ON = (0x06, 0x07, 0x0F)  # shutdown, switch on, enable operation


@pytest.mark.parametrize('path, cw, number, end', [
    ((), 0x06, 2, S.READY_TO_SWITCH_ON),
    ((0x06,), 0x07, 3, S.SWITCHED_ON),
    ((0x06,), 0x0F, 3, S.SWITCHED_ON),  # switch on + enable operation: 3, then 4
    ((0x06, 0x07), 0x0F, 4, S.OPERATION_ENABLED),
    (ON, 0x07, 5, S.SWITCHED_ON),
    ((0x06, 0x07), 0x06, 6, S.READY_TO_SWITCH_ON),
    ((0x06,), 0x00, 7, S.SWITCH_ON_DISABLED),
    ((0x06,), 0x02, 7, S.SWITCH_ON_DISABLED),
    (ON, 0x06, 8, S.READY_TO_SWITCH_ON),
    (ON, 0x00, 9, S.SWITCH_ON_DISABLED),
    ((0x06, 0x07), 0x00, 10, S.SWITCH_ON_DISABLED),
    ((0x06, 0x07), 0x02, 10, S.SWITCH_ON_DISABLED),
    (ON, 0x02, 11, S.QUICK_STOP_ACTIVE),
    (ON + (0x02,), 0x00, 12, S.SWITCH_ON_DISABLED),
])
def test_every_transition_of_the_standard(path, cw, number, end):
    _case(path, cw, number, end)


def test_transition_16_with_quick_stop_option_6():
    _case(ON + (0x02,), 0x0F, 16, S.OPERATION_ENABLED, option=6)
    d = _device(option=2)  # option 2: no way back but through Switch on disabled
    _to(d, *ON, 0x02)
    d.transitions.clear()
    d.step(0x0F, 0)
    assert 16 not in d.transitions


def test_a_command_of_no_transition_changes_nothing():
    d = _device()
    _to(d, 0x07, 0x0F, 0x02)  # switch on / enable / quick stop from Switch on disabled
    assert d.state is S.SWITCH_ON_DISABLED and d.transitions == [1]


def test_fault_reaction_brakes_then_fault_then_reset_on_the_rising_edge_only():
    d = _device()
    _to(d, *ON)
    for _ in range(100):
        d.step(0x0F, 20_000)  # 20 mm/s up
    assert d.plant.velocity_mm_s > 19.0
    d.fault(0x8611)
    assert [e.code for e in d.events] == [0x8611] and d.error_code == 0x8611
    d.step(0x0F, 20_000)
    assert d.state is S.FAULT_REACTION_ACTIVE and d.transitions[-1] == 13
    n = 0
    while d.state is S.FAULT_REACTION_ACTIVE:
        d.step(0x0F, 20_000)  # the target is ignored: it brakes
        n += 1
        assert n < 1000
    assert d.state is S.FAULT and d.transitions[-1] == 14 and d.plant.velocity_mm_s == 0.0
    assert n == pytest.approx(20.0 / (5000.0 * 0.0005), abs=2)  # a_max braking from 20 mm/s
    d.events.clear()
    d.step(0x00, 0)
    d.step(0x00, 0)
    assert d.state is S.FAULT  # no edge, no reset
    d.step(0x80, 0)
    assert d.state is S.SWITCH_ON_DISABLED and d.transitions[-1] == 15
    assert d.error_code == 0 and [e.code for e in d.events] == [0]  # EMCY error reset
    # bit 7 held: no second edge; a new fault with bit 7 still set needs a new edge
    d.fault(0x8250)
    _to(d, 0x80, 0x80, 0x80, 0x80)
    assert d.state is S.FAULT
    _to(d, 0x00, 0x80)
    assert d.state is S.SWITCH_ON_DISABLED


def test_quick_stop_from_operation_enabled_brakes_the_axis_to_rest():
    d = _device()
    _to(d, *ON)
    for _ in range(200):
        d.step(0x0F, -30_000)
    assert d.plant.velocity_mm_s < -29.0
    d.step(0x02, -30_000)
    assert d.state is S.QUICK_STOP_ACTIVE
    v = [d.plant.velocity_mm_s]
    while d.state is S.QUICK_STOP_ACTIVE:
        d.step(0x02, -30_000)
        v.append(d.plant.velocity_mm_s)
        assert len(v) < 1000
    assert all(b >= a for a, b in zip(v, v[1:], strict=False))  # braking monotonic toward 0
    assert d.state is S.SWITCH_ON_DISABLED and d.plant.velocity_mm_s == 0.0  # option 2: 12


def test_target_velocity_limited_and_only_in_operation_enabled():
    d = _device()
    d.max_velocity_units = 5_000  # 5 mm/s
    _to(d, 0x06, 0x07)
    for _ in range(20):
        d.step(0x07, 50_000)  # switched on: not moving
    assert d.plant.velocity_mm_s == 0.0
    for _ in range(400):
        d.step(0x0F, 50_000)
    assert d.plant.velocity_mm_s == pytest.approx(5.0, rel=1e-3)
    assert d.velocity_units == 5000


# ---- the two together ---------------------------------------------------------------------------
def test_the_master_drives_the_device_up_and_down_one_transition_per_cycle():
    d = _device()
    cws = []
    for goal, end in ((Goal.OPERATION_ENABLED, S.OPERATION_ENABLED),
                      (Goal.QUICK_STOP, S.SWITCH_ON_DISABLED),
                      (Goal.OPERATION_ENABLED, S.OPERATION_ENABLED),
                      (Goal.SWITCH_ON_DISABLED, S.SWITCH_ON_DISABLED)):
        for _ in range(10):
            cw = next_controlword(state_of(d.statusword), goal)
            cws.append(cw)
            d.step(cw, 0)
            if d.state is end:
                break
        assert d.state is end, goal
    # quick stop at rest: 11, then 12 in the next cycle (one transition per cycle)
    assert cws == [0x06, 0x07, 0x0F, 0x02, 0x02, 0x06, 0x07, 0x0F, 0x00]
