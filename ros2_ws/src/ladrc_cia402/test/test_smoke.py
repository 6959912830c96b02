"""colcon test: the CiA 402 master side on its own (no bus, no ROS)."""

from ladrc_cia402 import emcy, mapping
from ladrc_cia402.ds402 import Goal, State, next_controlword, state_of
from ladrc_cia402.units import DriveUnits


def test_statusword_controlword_units_pdo_emcy():
    assert state_of(0x0237) is State.OPERATION_ENABLED
    assert next_controlword(State.SWITCH_ON_DISABLED, Goal.OPERATION_ENABLED) == 0x06
    assert DriveUnits().velocity_command(-2.0009) == -2000
    entries = (mapping.Entry(0x6040, 0, 16, False, 'controlword'),
               mapping.Entry(0x60FF, 0, 32, True, 'target_velocity'))
    data = mapping.pack(entries, (0x0F, -2000))
    assert mapping.unpack(entries, data) == (0x0F, -2000)
    assert emcy.fault_text(0x8611) == 'EMCY 0x8611 following error'
