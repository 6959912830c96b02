"""PDOs as data, the CiA 301 sequence that maps one, and the PDO packing both sides use.

The layout of a drive is not fixed here: :mod:`.device_file` derives it from the device file's
roles and the drive's EDS (or takes the file's explicit one). Data types come from the EDS.

:func:`pack` / :func:`unpack` turn values into the PDO's bytes and back
(little-endian, in mapping order).
"""

from __future__ import annotations

from dataclasses import dataclass
import struct

COB_ID_INVALID = 0x80000000  # bit 31 of a PDO COB-ID: PDO not valid (disabled)
RPDO_COMM, RPDO_MAP = 0x1400, 0x1600
TPDO_COMM, TPDO_MAP = 0x1800, 0x1A00
SYNC_COB_ID = 0x080
_FORMATS = {(8, False): 'B', (8, True): 'b', (16, False): 'H', (16, True): 'h',
            (32, False): 'I', (32, True): 'i'}


@dataclass(frozen=True)
class Entry:
    """One mapped object: index, subindex, size in bits, signed or not, a name."""

    index: int
    subindex: int
    bits: int
    signed: bool
    name: str

    @property
    def word(self) -> int:
        """The mapping entry as written to 0x16xx / 0x1Axx: index << 16 | sub << 8 | bits."""
        return self.index << 16 | self.subindex << 8 | self.bits


@dataclass(frozen=True)
class Pdo:
    """One PDO: direction, number (1..4), COB-ID base, transmission type, entries."""

    kind: str  # 'rpdo' (master -> drive) or 'tpdo' (drive -> master)
    number: int
    cob_base: int
    transmission_type: int
    entries: tuple[Entry, ...]
    event_timer_ms: int = 0  # RPDO: the drive's deadline; TPDO: 0 (sent on SYNC only)

    def __post_init__(self) -> None:
        if self.kind not in ('rpdo', 'tpdo'):
            raise ValueError(f'kind {self.kind!r}: rpdo or tpdo')
        if not 1 <= self.number <= 4:
            raise ValueError(f'PDO number {self.number}: 1..4 (the predefined set)')
        if size(self.entries) > 8:
            raise ValueError(f'{self.kind.upper()}{self.number}: {size(self.entries)} bytes, '
                             'a CAN PDO carries at most 8')

    def cob_id(self, node_id: int) -> int:
        """Return this PDO's COB-ID for ``node_id``."""
        return self.cob_base + node_id

    @property
    def comm_index(self) -> int:
        """0x1400 / 0x1800 + number - 1."""
        return (RPDO_COMM if self.kind == 'rpdo' else TPDO_COMM) + self.number - 1

    @property
    def map_index(self) -> int:
        """0x1600 / 0x1A00 + number - 1."""
        return (RPDO_MAP if self.kind == 'rpdo' else TPDO_MAP) + self.number - 1


def size(entries: tuple[Entry, ...]) -> int:
    """Bytes of a PDO with these entries (each a whole number of bytes)."""
    bits = sum(e.bits for e in entries)
    if bits % 8 or any((e.bits, e.signed) not in _FORMATS for e in entries):
        raise ValueError('PDO entries of 8, 16 or 32 bits only')
    return bits // 8


def struct_of(entries: tuple[Entry, ...]) -> struct.Struct:
    """Return the little-endian struct of a PDO's data in mapping order."""
    return struct.Struct('<' + ''.join(_FORMATS[(e.bits, e.signed)] for e in entries))


def pack(entries: tuple[Entry, ...], values: tuple[int, ...]) -> bytes:
    """Pack ``values`` (one int per entry; struct.error if out of range) into PDO data."""
    return struct_of(entries).pack(*values)


def unpack(entries: tuple[Entry, ...], data: bytes) -> tuple[int, ...]:
    """Unpack a PDO's data; ValueError for a frame of another length (CiA: 0x8210)."""
    st = struct_of(entries)
    if len(data) != st.size:
        raise ValueError(f'PDO of {len(data)} bytes, the mapping has {st.size}')
    return st.unpack(bytes(data))


def decode_entry(word: int) -> tuple[int, int, int]:
    """``(index, subindex, bits)`` of a mapping entry as read from 0x16xx / 0x1Axx."""
    return word >> 16, (word >> 8) & 0xFF, word & 0xFF
