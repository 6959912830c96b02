"""Fast CDR of fixed-layout messages, many at once: numpy columns -> serialized rows.

What the headless bag writer (:mod:`.run_bag`) uses to write a whole run's topics without a
Python message object per tick; byte-identical to rosbags' serializer.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from .columns import CDR_PRIMITIVES as _BASE
from .errors import BagError
from .typestore import ladrc_typestore

# ---- fast serialization of fixed-layout rows ------------------------------------------------
_ENCAP = 4  # CDR encapsulation header (little endian, 0x0001); alignment counts from its end


class RowPacker:
    """Serialize many messages of one type at once with numpy (strings empty or given).

    The CDR layout of a message whose strings are all empty, or each one the same text in every
    row (``strings``: flattened field -> text), is fixed, so a structured numpy array with the
    CDR offsets *is* the serialized messages. Built from the typestore's field definitions and
    checked once against ``serialize_cdr`` (raises if rosbags disagrees).
    """

    def __init__(self, msgtype: str, typestore: Any = None,
                 strings: Mapping[str, str] | None = None) -> None:
        self.store = typestore or ladrc_typestore()
        self.msgtype = msgtype
        self.texts = {k: v.encode('utf-8') for k, v in (strings or {}).items()}
        names: list[str] = []
        formats: list[str] = []
        offsets: list[int] = []
        self.strings: list[str] = []
        end = self._layout(msgtype, '', 0, names, formats, offsets)
        self.fields = [n for n in names if not n.startswith('~')]
        self._order = [n[5:] if n.startswith('~len.') else n for n in names
                       if not n.startswith('~str.')]
        self.dtype = np.dtype({'names': ['~encap'] + names, 'formats': ['<u4'] + formats,
                               'offsets': [0] + [o + _ENCAP for o in offsets],
                               'itemsize': end + _ENCAP})
        probe = self.pack(1, {})
        ref = bytes(self.store.serialize_cdr(self._default(msgtype), msgtype))
        if probe[0] != ref:
            raise BagError(f'fixed CDR layout of {msgtype} disagrees with rosbags')

    def _layout(self, msgtype: str, prefix: str, off: int, names: list, formats: list,
                offsets: list) -> int:
        for fname, (kind, arg) in self.store.fielddefs[msgtype][1]:
            key = f'{prefix}{fname}'
            if kind.name == 'NAME':
                off = self._layout(arg, f'{key}.', off, names, formats, offsets)
            elif kind.name == 'BASE' and arg[0] == 'string':
                off += -off % 4
                names.append(f'~len.{key}')
                formats.append('<u4')
                offsets.append(off)
                self.strings.append(key)
                text = self.texts.get(key, b'')
                if text:
                    names.append(f'~str.{key}')
                    formats.append(f'S{len(text)}')
                    offsets.append(off + 4)
                off += 5 + len(text)  # uint32 length, the text, then the terminating NUL
            elif kind.name == 'BASE' and arg[0] in _BASE:
                fmt = _BASE[arg[0]]
                size = np.dtype(fmt).itemsize
                off += -off % size
                names.append(key)
                formats.append(fmt)
                offsets.append(off)
                off += size
            else:
                raise BagError(f'{msgtype}.{fname}: arrays have no fixed layout')
        return off

    def _default(self, msgtype: str, prefix: str = '') -> Any:
        kwargs = {}
        for fname, (kind, arg) in self.store.fielddefs[msgtype][1]:
            if kind.name == 'NAME':
                kwargs[fname] = self._default(arg, f'{prefix}{fname}.')
            elif arg[0] == 'string':
                kwargs[fname] = self.texts.get(f'{prefix}{fname}', b'').decode('utf-8')
            elif arg[0] == 'bool':
                kwargs[fname] = False
            elif arg[0].startswith('float'):
                kwargs[fname] = 0.0
            else:
                kwargs[fname] = 0
        return self.store.types[msgtype](**kwargs)

    def pack(self, n: int, columns: Mapping[str, Any]) -> list[bytes]:
        """Return ``n`` serialized messages; ``columns`` maps flattened field -> value/array.

        Fields not given are zero; ``header.stamp`` may be given as ``stamp_s`` (float s).
        """
        arr = np.zeros(n, dtype=self.dtype)
        arr['~encap'] = 0x00000100  # bytes 00 01 00 00: CDR little endian
        for key in self.strings:
            text = self.texts.get(key, b'')
            arr[f'~len.{key}'] = len(text) + 1
            if text:
                arr[f'~str.{key}'] = text
        cols = dict(columns)
        if 'stamp_s' in cols:
            sec, nsec = stamp_parts(np.asarray(cols.pop('stamp_s'), dtype=float))
            cols.setdefault('header.stamp.sec', sec)
            cols.setdefault('header.stamp.nanosec', nsec)
        for key, value in cols.items():
            if key not in self.dtype.names:
                raise BagError(f'{self.msgtype} has no field {key!r}')
            arr[key] = value
        buf = arr.tobytes()
        size = self.dtype.itemsize
        return [buf[i:i + size] for i in range(0, n * size, size)]


def stamp_parts(t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split seconds into ``builtin_interfaces/Time`` (sec, nanosec) arrays."""
    ns = np.round(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)
    return ns // 1_000_000_000, ns % 1_000_000_000
