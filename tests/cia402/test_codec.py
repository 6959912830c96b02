"""The drive's integer units, the EMCY text, the PDO packing and the SDO mapping sequence."""

from __future__ import annotations

import math

from ladrc_cia402 import emcy, mapping
from ladrc_cia402.units import INT32_MAX, INT32_MIN, AnalogScale, DriveUnits
import pytest


# ---- units --------------------------------------------------------------------------------------
def test_commands_round_toward_zero_never_bigger():
    u = DriveUnits(1000.0, 1000.0)
    assert u.velocity_command(2.0) == 2000
    assert u.velocity_command(1.9999) == 1999
    assert u.velocity_command(-1.9999) == -1999  # downward: not -2000 (not faster down)
    assert u.velocity_command(-0.0004) == 0
    assert u.velocity_command(math.nan) == 0
    assert u.velocity_command(math.inf) == INT32_MAX
    assert u.velocity_command(-1e12) == INT32_MIN
    for x in (-123.4567, -0.3, -5e-4, 0.29, 7.0007, 199.9999):
        c = u.velocity_command(x)
        assert abs(c) <= abs(x) * 1000.0 and abs(x * 1000.0 - c) < 1.0
        assert u.position_command(x) == int(x * 1000.0)


def test_readings_both_ways():
    u = DriveUnits.from_velocity_factor(increments_per_mm=4096 / 5.0,
                                        increments_per_s_per_unit=4096 / 600.0)  # 0.1 rpm
    # 5 mm per revolution of 4096 increments: 1 rev/s = 5 mm/s = 600 units of 0.1 rpm
    assert u.velocity_mm_s(600) == pytest.approx(5.0)
    assert u.velocity_command(5.0) in (599, 600)
    assert u.position_mm(4096) == pytest.approx(5.0)
    assert u.position_increments(5.0) == 4096
    assert u.velocity_units(-5.0) == -600
    with pytest.raises(ValueError):
        DriveUnits(0.0, 1.0)
    with pytest.raises(ValueError):
        DriveUnits(1.0, math.nan)


def test_analog_scale():
    a = AnalogScale(1000.0)
    assert a.counts(1.2345) == 1234 or a.counts(1.2345) == 1235
    assert a.mm(a.counts(2.0)) == (2.0, True)
    assert a.counts(3.0, valid=False) == a.invalid
    mm, valid = a.mm(a.invalid)
    assert math.isnan(mm) and not valid
    assert a.counts(1e9) == 0x7FFE  # saturates below the invalid mark


# ---- EMCY --------------------------------------------------------------------------------
@pytest.mark.parametrize('code, text', [
    (0x8611, 'EMCY 0x8611 following error'),
    (0x8250, 'EMCY 0x8250 RPDO timeout'),
    (0x8130, 'EMCY 0x8130 life guard or heartbeat error'),
    (0x2310, 'EMCY 0x2310 continuous over current'),
    (0x3210, 'EMCY 0x3210 DC link over voltage'),
    (0x3220, 'EMCY 0x3220 DC link under voltage'),
    (0x4210, 'EMCY 0x4210 excess temperature device'),
    (0x8210, 'EMCY 0x8210 PDO not processed due to length error'),
    (0x8110, 'EMCY 0x8110 CAN overrun (objects lost)'),
    (0x8140, 'EMCY 0x8140 recovered from bus off'),
    (0x8200, 'EMCY 0x8200 protocol error'),
    (0x1000, 'EMCY 0x1000 generic error'),
    (0x2399, 'EMCY 0x2399 current'),  # unknown code: its class
    (0x4321, 'EMCY 0x4321 temperature'),
    (0x0123, 'EMCY 0x0123 unknown error'),
])
def test_emcy_text(code, text):
    assert emcy.fault_text(code) == text


def test_emcy_text_details_and_frame_round_trip():
    assert emcy.fault_text(0x8250, 0x11) == 'EMCY 0x8250 RPDO timeout (register 0x11)'
    assert emcy.fault_text(0x8250, 0x01) == 'EMCY 0x8250 RPDO timeout'
    assert emcy.fault_text(0x8200, 0x11, b'2MSTR') == \
        'EMCY 0x8200 protocol error (register 0x11) [manufacturer 324d535452]'
    frame = emcy.pack_emcy(0x8611, 0x21, b'\x01\x02')
    assert len(frame) == 8
    assert emcy.unpack_emcy(frame) == (0x8611, 0x21, b'\x01\x02\x00\x00\x00')
    with pytest.raises(ValueError):
        emcy.unpack_emcy(frame[:7])


# ---- PDOs --------------------------------------------------------------------------------
CONTROLWORD = mapping.Entry(0x6040, 0, 16, False, 'controlword')
TARGET_VELOCITY = mapping.Entry(0x60FF, 0, 32, True, 'target_velocity')
STATUSWORD = mapping.Entry(0x6041, 0, 16, False, 'statusword')
POSITION_ACTUAL = mapping.Entry(0x6064, 0, 32, True, 'position_actual')
VELOCITY_ACTUAL = mapping.Entry(0x606C, 0, 32, True, 'velocity_actual')
GAP = mapping.Entry(0x6401, 1, 16, True, 'gap')
RPDO1 = mapping.Pdo('rpdo', 1, 0x200, 1, (CONTROLWORD, TARGET_VELOCITY))
TPDO1 = mapping.Pdo('tpdo', 1, 0x180, 1, (STATUSWORD, POSITION_ACTUAL))
TPDO2 = mapping.Pdo('tpdo', 2, 0x280, 1, (VELOCITY_ACTUAL, GAP))


@pytest.mark.parametrize('pdo, values', [
    (RPDO1, (0x000F, -2000)),
    (RPDO1, (0xFFFF, INT32_MAX)),
    (TPDO1, (0x0637, INT32_MIN)),
    (TPDO2, (-1, -0x8000)),
    (TPDO2, (123456, 0x7FFF)),
])
def test_pdo_pack_round_trip(pdo, values):
    data = mapping.pack(pdo.entries, values)
    assert len(data) == mapping.size(pdo.entries) <= 8
    assert mapping.unpack(pdo.entries, data) == values


def test_pdo_layout_is_little_endian_in_mapping_order():
    assert mapping.pack(RPDO1.entries, (0x000F, -2)) == bytes.fromhex('0f00feffffff')
    with pytest.raises(ValueError):
        mapping.unpack(RPDO1.entries, bytes(5))  # a frame of the wrong length
    with pytest.raises(ValueError):  # 10 bytes: no CAN PDO
        mapping.Pdo('tpdo', 3, 0x380, 1, (STATUSWORD, POSITION_ACTUAL, VELOCITY_ACTUAL))
    assert mapping.decode_entry(0x64010110) == (0x6401, 1, 16)
