"""Fast CDR serialization of one message type, both ways, for the 2 kHz loop.

rclpy's ``publish(msg)`` converts the Python message field by field (property setters with
type checks, then a C conversion): about 27 µs for a ``FollowStatus`` here, plus ~1 µs per
field set, so a tick spent most of its time filling and publishing messages. ``publish()``
also accepts the serialized bytes (4.5 µs). :class:`CdrPacker` produces those bytes with a few
``struct.pack`` calls whose formats are precomputed from the message definition, including CDR
alignment. The layout comes from the rclpy-generated message classes themselves
(``get_fields_and_field_types()``, in declaration order = CDR order), so the follow node needs
nothing beyond rclpy and the message packages (no rosbags). Byte-identical to rosbags'
serializer (padding zeroed) and data-identical to rclpy's (tests/ros/test_cdr.py).

The other way, :meth:`CdrPacker.unpack` reads the leaf values back from the raw bytes a reader
takes (``take_message(..., raw=True)``): a loop that takes its samples straight from the reader
needs no rclpy message object per sample (rclpy's deserialization builds one field by field).
"""

from __future__ import annotations

import importlib
import re
import struct
from typing import Any, Sequence

PRIMITIVES = {
    'bool': ('?', 1), 'byte': ('B', 1), 'char': ('B', 1), 'octet': ('B', 1), 'int8': ('b', 1),
    'uint8': ('B', 1), 'int16': ('h', 2), 'uint16': ('H', 2), 'int32': ('i', 4),
    'uint32': ('I', 4), 'int64': ('q', 8), 'uint64': ('Q', 8), 'float32': ('f', 4),
    'float64': ('d', 8),
}
"""CDR primitive -> (struct code, size = alignment): the one table of every CDR codec here."""
# The IDL names rclpy's get_fields_and_field_types() uses -> the .msg primitive names above.
_IDL_PRIMITIVES = {
    'boolean': 'bool', 'octet': 'byte', 'char': 'char', 'float': 'float32', 'double': 'float64',
    **{k: k for k in ('int8', 'uint8', 'int16', 'uint16', 'int32', 'uint32', 'int64', 'uint64')},
}
_NESTED = re.compile(r'^([A-Za-z_]\w*)/([A-Za-z_]\w*)$')  # 'builtin_interfaces/Time'
_HEADER = b'\x00\x01\x00\x00'  # CDR, little endian
_U32 = struct.Struct('<I')


def message_class(typename: str) -> type:
    """Return the rclpy message class of ``pkg/msg/Name`` (or ``pkg/Name``)."""
    parts = typename.split('/')
    if len(parts) == 3 and parts[1] == 'msg':
        parts = [parts[0], parts[2]]
    if len(parts) != 2:
        raise ValueError(f'{typename}: not a message type name (pkg/msg/Name)')
    pkg, name = parts
    try:
        return getattr(importlib.import_module(f'{pkg}.msg'), name)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f'{typename}: no such message type ({exc})') from None


def flat_fields(typename: str, prefix: str = '') -> list[tuple[str, str]]:
    """Return ``(dotted name, primitive or 'string')`` of every leaf field, in CDR order.

    Primitives are named as in .msg files (``bool``, ``float64``, ...). Nested messages are
    flattened (``header.stamp.sec``); arrays, sequences, bounded and wide strings are refused.
    """
    out: list[tuple[str, str]] = []
    for name, kind in message_class(typename).get_fields_and_field_types().items():
        if kind in _IDL_PRIMITIVES:
            out.append((f'{prefix}{name}', _IDL_PRIMITIVES[kind]))
        elif kind == 'string':
            out.append((f'{prefix}{name}', 'string'))
        elif kind.startswith('string<'):
            raise ValueError(f'{typename}.{name}: bounded strings are not supported')
        elif (nested := _NESTED.match(kind)) is not None:
            out += flat_fields(f'{nested[1]}/msg/{nested[2]}', f'{prefix}{name}.')
        else:
            raise ValueError(f'{typename}.{name}: {kind} is not supported '
                             '(arrays, sequences, wide strings)')
    return out


class CdrPacker:
    """Serialize ``typename`` from a flat list of leaf values (see :attr:`fields`)."""

    def __init__(self, typename: str) -> None:
        self.typename = typename
        self.fields = flat_fields(typename)
        self.index = {name: i for i, (name, _) in enumerate(self.fields)}
        # Runs of primitives between strings; for each run, one struct per start offset mod 8.
        self._plan: list[tuple[str, Any]] = []
        run: list[str] = []
        start = 0
        for i, (_, kind) in enumerate(self.fields):
            if kind == 'string':
                if run:
                    self._plan.append(('run', (start, i, self._formats(run))))
                self._plan.append(('string', i))
                run, start = [], i + 1
            else:
                run.append(kind)
        if run:
            self._plan.append(('run', (start, len(self.fields), self._formats(run))))

    @staticmethod
    def _formats(kinds: list[str]) -> list[tuple[struct.Struct, int]]:
        out = []
        for phase in range(8):
            pos, fmt = phase, '<'
            for kind in kinds:
                code, size = PRIMITIVES[kind]
                pad = (-pos) % size
                fmt += 'x' * pad + code
                pos += pad + size
            out.append((struct.Struct(fmt), pos - phase))
        return out

    def pack(self, values: Sequence[Any]) -> bytes:
        """Return the CDR bytes (with the encapsulation header) of the leaf ``values``."""
        parts = [_HEADER]
        pos = 0  # offset after the encapsulation header: CDR aligns relative to it
        for kind, item in self._plan:
            if kind == 'string':
                data = values[item].encode() + b'\x00'
                pad = (-pos) % 4
                parts.append(b'\x00' * pad + struct.pack('<I', len(data)) + data)
                pos += pad + 4 + len(data)
            else:
                lo, hi, formats = item
                fmt, size = formats[pos & 7]
                parts.append(fmt.pack(*values[lo:hi]))
                pos += size
        return b''.join(parts)

    def defaults(self) -> list[Any]:
        """Return zero values of the leaf fields, each of the right Python type."""
        zero = {'string': '', 'bool': False, 'float32': 0.0, 'float64': 0.0}
        return [zero.get(kind, 0) for _, kind in self.fields]

    def unpack(self, data: bytes) -> list[Any]:
        """Return the leaf values of CDR ``data`` (little endian, as :meth:`pack` writes it).

        Raises ``ValueError`` for data that is not such a message (short, another encoding, a
        string without its terminator): a reader never trusts a sender's bytes.
        """
        if data[:4] != _HEADER:
            raise ValueError(f'{self.typename}: not little-endian CDR')
        out: list[Any] = []
        pos = 0  # offset after the encapsulation header
        try:
            for kind, item in self._plan:
                if kind == 'string':
                    pos += (-pos) % 4
                    (n,) = _U32.unpack_from(data, 4 + pos)
                    end = 4 + pos + 4 + n
                    if n < 1 or end > len(data) or data[end - 1] != 0:
                        raise ValueError(f'{self.typename}: malformed string')
                    out.append(data[4 + pos + 4:end - 1].decode())
                    pos += 4 + n
                else:
                    _, _, formats = item
                    fmt, size = formats[pos & 7]
                    out.extend(fmt.unpack_from(data, 4 + pos))
                    pos += size
        except (struct.error, UnicodeDecodeError) as exc:
            raise ValueError(f'{self.typename}: {exc}') from None
        return out


class Outgoing:
    """One outgoing message type of a loop: a value list refilled per message, packed to CDR.

    For messages with a ``std_msgs/Header`` first (its stamp the first two values).
    """

    def __init__(self, typename: str, frame_id: str = '') -> None:
        self.packer = CdrPacker(typename)
        self.values = self.packer.defaults()
        self.index = self.packer.index
        if 'header.frame_id' in self.index:
            self.values[self.index['header.frame_id']] = frame_id

    def pack(self, sec: int, nsec: int, **fields: Any) -> bytes:
        """CDR of the message stamped ``sec.nsec`` with ``fields`` (the rest as last time)."""
        values, index = self.values, self.index
        values[0], values[1] = sec, nsec  # header.stamp
        for name, value in fields.items():
            values[index[name]] = value
        return self.packer.pack(values)
