"""Fill any ROS message (rclpy or rosbags) with distinctive non-default values per field."""

from __future__ import annotations

import math

NUMERIC = {
    'float': 1.25, 'double': -2.5e-3, 'float32': 1.25, 'float64': -2.5e-3,
    'int8': -7, 'uint8': 7, 'int16': -300, 'uint16': 300, 'int32': -70000, 'uint32': 70000,
    'int64': -(2**40), 'uint64': 2**40 + 3, 'octet': 9, 'byte': 9, 'char': 65,
}


def fill_rclpy(msg, salt: int = 0):
    """Set every field of an rclpy message to a value derived from its name and ``salt``."""
    for name, typ in msg.get_fields_and_field_types().items():
        current = getattr(msg, name)
        if typ == 'boolean':
            setattr(msg, name, (len(name) + salt) % 2 == 0 or name.startswith('valid'))
        elif typ == 'string':
            setattr(msg, name, f'{name}-{salt}-é')
        elif typ in NUMERIC:
            base = NUMERIC[typ]
            if isinstance(base, float):
                value = base * (1 + len(name)) + salt * math.pi
            else:
                value = base + (len(name) + salt if base >= 0 else -(len(name) + salt))
            setattr(msg, name, value)
        elif hasattr(current, 'get_fields_and_field_types'):
            fill_rclpy(current, salt + len(name))
        else:
            raise TypeError(f'unhandled field type {typ} of {name}')
    return msg


def to_plain(msg) -> dict:
    """Return the rclpy message as nested plain values (for equality checks)."""
    out = {}
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        out[name] = to_plain(value) if hasattr(value, 'get_fields_and_field_types') else value
    return out


def to_rosbags(msg, store, typename: str):
    """Build the rosbags dataclass of ``typename`` holding the rclpy message's values."""
    cls = store.types[typename]
    fields = store.fielddefs[typename][1]
    kwargs = {}
    for fname, desc in fields:
        value = getattr(msg, fname)
        if hasattr(value, 'get_fields_and_field_types'):
            kwargs[fname] = to_rosbags(value, store, desc[1])  # (Nodetype.NAME, typename)
        else:
            kwargs[fname] = value
    return cls(**kwargs)


_SIZES = {'bool': 1, 'byte': 1, 'char': 1, 'int8': 1, 'uint8': 1, 'int16': 2, 'uint16': 2,
          'int32': 4, 'uint32': 4, 'float32': 4, 'int64': 8, 'uint64': 8, 'float64': 8}


def cdr_padding(store, typename: str, msg) -> set[int]:
    """Return the byte offsets of CDR alignment padding in the serialization of ``msg``.

    Fast-CDR (rclpy) leaves padding bytes uninitialised, so two correct serializers agree on
    every byte except these. Offsets count from the start of the buffer (4-byte header first).
    """
    pad: set[int] = set()
    pos = 4  # after the encapsulation header; alignment is relative to here

    def align(size: int) -> None:
        nonlocal pos
        while (pos - 4) % size:
            pad.add(pos)
            pos += 1

    def walk(tname: str, value) -> None:
        nonlocal pos
        for fname, (node, detail) in store.fielddefs[tname][1]:
            field = getattr(value, fname)
            if node.name == 'NAME':
                walk(detail, field)
            elif detail[0] == 'string':
                align(4)
                pos += 4 + len(field.encode()) + 1
            else:
                size = _SIZES[detail[0]]
                align(size)
                pos += size

    walk(typename, msg)
    return pad
