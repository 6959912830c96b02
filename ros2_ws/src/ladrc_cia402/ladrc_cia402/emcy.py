"""EMCY messages and the error code (0x603F) of a CiA 402 drive, as one line of text.

An EMCY frame (CiA 301, COB-ID 0x80 + node id) carries 8 bytes: the error code (u16), the
error register (0x1001, u8) and 5 manufacturer-specific bytes. The same error code is in the
drive's 0x603F. The driver names a fault in ``AxisFeedback.fault_reason`` with
:func:`fault_text`, e.g. ``EMCY 0x8611 following error``.
"""

from __future__ import annotations

import struct

EMCY_COB_BASE = 0x80
ERROR_CODE = 0x603F
ERROR_REGISTER = 0x1001
EMCY_STRUCT = struct.Struct('<HB5s')

# error register (0x1001) bits
REG_GENERIC = 0x01
REG_CURRENT = 0x02
REG_VOLTAGE = 0x04
REG_TEMPERATURE = 0x08
REG_COMMUNICATION = 0x10
REG_PROFILE = 0x20
REG_MANUFACTURER = 0x80

# the codes of CiA 301 and CiA 402 a servo drive uses (exact codes first, then the classes)
ERROR_TEXT: dict[int, str] = {
    0x0000: 'no error',
    0x1000: 'generic error',
    0x2300: 'current, device output side',
    0x2310: 'continuous over current',
    0x2320: 'short circuit or earth leakage',
    0x3100: 'mains voltage',
    0x3210: 'DC link over voltage',
    0x3220: 'DC link under voltage',
    0x4210: 'excess temperature device',
    0x4310: 'excess temperature drive',
    0x5000: 'device hardware',
    0x5530: 'data storage (EEPROM) error',
    0x6000: 'device software',
    0x6320: 'parameter error',
    0x7300: 'sensor (resolver, encoder) error',
    0x7305: 'incremental sensor 1 fault',
    0x8110: 'CAN overrun (objects lost)',
    0x8120: 'CAN in error passive mode',
    0x8130: 'life guard or heartbeat error',
    0x8140: 'recovered from bus off',
    0x8141: 'bus off',
    0x8150: 'CAN-ID collision',
    0x8200: 'protocol error',
    0x8210: 'PDO not processed due to length error',
    0x8220: 'PDO length exceeded',
    0x8240: 'unexpected SYNC data length',
    0x8250: 'RPDO timeout',
    0x8400: 'velocity speed controller (deviation)',
    0x8500: 'position controller',
    0x8611: 'following error',
    0x8612: 'reference limit',
    0x9000: 'external error',
    0xFF00: 'manufacturer-specific',
}
ERROR_CLASSES: tuple[tuple[int, int, str], ...] = (  # (code, mask, text): the class of a code
    (0x2000, 0xF000, 'current'),
    (0x3000, 0xF000, 'voltage'),
    (0x4000, 0xF000, 'temperature'),
    (0x5000, 0xFF00, 'device hardware'),
    (0x6000, 0xF000, 'device software'),
    (0x7000, 0xFF00, 'additional modules'),
    (0x8100, 0xFF00, 'communication'),
    (0x8200, 0xFF00, 'protocol error'),
    (0x8000, 0xF000, 'monitoring'),
    (0x9000, 0xFF00, 'external error'),
    (0xFF00, 0xFF00, 'manufacturer-specific'),
)


def error_text(code: int) -> str:
    """Return the text of a code: its own, else its class's, else 'unknown error'."""
    if code in ERROR_TEXT:
        return ERROR_TEXT[code]
    for base, mask, text in ERROR_CLASSES:
        if code & mask == base:
            return text
    return 'unknown error'


def fault_text(code: int, register: int | None = None, manufacturer: bytes = b'') -> str:
    """One line for ``AxisFeedback.fault_reason``: ``EMCY 0x8611 following error`` (+ details).

    The error register is added when it has bits beyond "generic", the manufacturer bytes when
    any is non-zero (as hex: their meaning is the drive's manual's).
    """
    line = f'EMCY 0x{code:04X} {error_text(code)}'
    if register is not None and register & ~REG_GENERIC:
        line += f' (register 0x{register:02X})'
    if any(manufacturer):
        line += f' [manufacturer {manufacturer.hex()}]'
    return line


def pack_emcy(code: int, register: int = 0, manufacturer: bytes = b'') -> bytes:
    """Return the 8 data bytes of an EMCY frame (manufacturer bytes padded or cut to 5)."""
    return EMCY_STRUCT.pack(code, register, bytes(manufacturer[:5]).ljust(5, b'\0'))


def unpack_emcy(data: bytes) -> tuple[int, int, bytes]:
    """Return ``(code, register, manufacturer bytes)`` of an EMCY frame's 8 data bytes."""
    if len(data) != EMCY_STRUCT.size:
        raise ValueError(f'an EMCY frame has 8 data bytes, not {len(data)}')
    return EMCY_STRUCT.unpack(bytes(data))
