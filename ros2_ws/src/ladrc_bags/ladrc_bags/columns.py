"""CDR of many messages of one type into numpy columns at once, strings included (no rclpy).

A 2 kHz topic is 7.2 million messages an hour; one Python call per message (rosbags'
``deserialize_cdr``, about 8 us for a ``FollowStatus``) is a minute per hour per topic. Here the
messages of a batch lie in one flat byte buffer, each at its start offset, and the decoder walks
the type's fields once for the whole batch with a vector of cursors, one per message (OMG CDR 1,
little endian; what rosbags and rclpy write):

* a primitive of size *s* is aligned to *s* relative to the end of the 4-byte encapsulation
  header, read at every cursor with one numpy gather, and the cursors move on by *s*;
* a string is a ``uint32`` length *L* (the text's bytes plus the terminating NUL), aligned to 4,
  then the *L* bytes: the cursors move on by ``4 + L``, each by its own *L*, so every field after
  a string sits at a per-message offset computed from the lengths before it.

A string column's texts are decoded once per distinct text (nonempty texts of one length are
compared as fixed-size byte rows by ``np.unique``): a command topic names the same commander
in every message, a status topic says "" or one of a few reasons. Arrays and sequences (the
diagnostics' status list) have no such decoder (:class:`NoColumns`); their topics are read
message by message.
"""

from __future__ import annotations

from typing import Any, Iterable

from ladrc_contract.cdr import PRIMITIVES
import numpy as np

from .errors import BagError

CDR_PRIMITIVES = {name: np.dtype('<' + code).str for name, (code, _) in PRIMITIVES.items()}
"""CDR primitive -> numpy format (little endian), from ``ladrc_contract.cdr.PRIMITIVES``."""

ENCAPSULATION_BYTES = 4
"""The CDR encapsulation header; alignment counts from its end."""

STRING = 'string'


class NoColumns(BagError):
    """The message type has no column decoder (it holds an array or a sequence)."""


def gather(buf: np.ndarray | bytes, dtype: np.dtype | str, offsets: np.ndarray) -> np.ndarray:
    """Return the items of ``dtype`` that start at each byte offset of ``buf`` (one gather).

    Raises ``IndexError`` when an item would reach past the end of ``buf``.
    """
    dt = np.dtype(dtype)
    nbytes = len(buf) if isinstance(buf, (bytes, bytearray, memoryview)) else buf.nbytes
    every_byte = np.ndarray(shape=(max(nbytes - dt.itemsize + 1, 0),), dtype=dt,
                            buffer=buf, strides=(1,))
    return every_byte[offsets]


def fields_of(msgtype: str, typestore: Any, prefix: str = '') -> list[tuple[str, str]]:
    """Return the leaf fields of ``msgtype`` in CDR order: ``(flattened name, kind)``.

    ``kind`` is a numpy format or :data:`STRING`; nested messages are flattened with dots
    (``header.stamp.sec``). :class:`NoColumns` for an array or a sequence.
    """
    out: list[tuple[str, str]] = []
    for fname, (kind, arg) in typestore.fielddefs[msgtype][1]:
        key = f'{prefix}{fname}'
        if kind.name == 'NAME':
            out += fields_of(arg, typestore, f'{key}.')
        elif kind.name == 'BASE' and arg[0] == 'string':
            out.append((key, STRING))
        elif kind.name == 'BASE' and arg[0] in CDR_PRIMITIVES:
            out.append((key, CDR_PRIMITIVES[arg[0]]))
        else:
            raise NoColumns(f'{msgtype}.{fname}: arrays and sequences have no column decoder')
    return out


class CdrColumns:
    """Many serialized messages of one type -> ``{flattened field: array}`` (module docstring)."""

    def __init__(self, msgtype: str, typestore: Any) -> None:
        self.msgtype = msgtype
        self.fields = fields_of(msgtype, typestore)
        self.has_strings = any(kind == STRING for _, kind in self.fields)

    def decode(self, buf: np.ndarray, start: np.ndarray, size: np.ndarray,
               names: Iterable[str] | None = None) -> dict[str, np.ndarray] | None:
        """Decode the messages ``buf[start[i]:start[i] + size[i]]`` into columns.

        ``names``: the fields wanted (None: all); the columns come in the message's field
        order, numbers with their CDR type (bool as bool), strings as object arrays of
        ``str``. None when a message is not this type's CDR (too short, a length running past
        its end, text that is not UTF-8): the caller's general decoder then says what is wrong.
        """
        wanted = None if names is None else set(names)
        last = max((i for i, (k, _) in enumerate(self.fields)
                    if wanted is None or k in wanted), default=-1)
        start = np.asarray(start, dtype=np.int64)
        size = np.asarray(size, dtype=np.int64)
        base = start + ENCAPSULATION_BYTES
        pos = np.zeros(start.size, dtype=np.int64)  # each message's cursor, relative to base
        out: dict[str, np.ndarray] = {}
        try:
            for key, kind in self.fields[:last + 1]:
                take = wanted is None or key in wanted
                if kind == STRING:
                    pos += -pos % 4
                    length = gather(buf, '<u4', base + pos).astype(np.int64)
                    if np.any(length < 1):
                        return None  # no room for the NUL: not a CDR string
                    if take:
                        out[key] = _texts(buf, base + pos + 4, length - 1)
                    pos += 4 + length
                    if np.any(ENCAPSULATION_BYTES + pos > size):
                        return None
                    continue
                itemsize = np.dtype(kind).itemsize
                if itemsize > 1:
                    pos += -pos % itemsize
                if take:
                    if kind == '?':  # a CDR bool is a byte: any nonzero value reads True
                        out[key] = gather(buf, 'u1', base + pos) != 0
                    else:
                        out[key] = gather(buf, kind, base + pos)
                pos += itemsize
        except (IndexError, UnicodeDecodeError):
            return None
        if np.any(ENCAPSULATION_BYTES + pos > size):
            return None
        return out


def _texts(buf: np.ndarray, at: np.ndarray, nbytes: np.ndarray) -> np.ndarray:
    """Decode the UTF-8 texts of ``nbytes[i]`` bytes at ``at[i]``: once per distinct text."""
    out = np.full(at.size, '', dtype=object)
    nonempty = nbytes > 0
    if not np.any(nonempty):
        return out
    for n in np.unique(nbytes[nonempty]).tolist():
        where = np.flatnonzero(nbytes == n)
        raw = gather(buf, np.dtype((np.void, n)), at[where])
        if np.all(raw == raw[0]):  # the usual case: one text (a commander) in every message
            out[where] = bytes(raw[0]).decode('utf-8')
            continue
        distinct, inverse = np.unique(raw, return_inverse=True)
        texts = np.empty(distinct.size, dtype=object)
        texts[:] = [bytes(t).decode('utf-8') for t in distinct]
        out[where] = texts[inverse.reshape(-1)]
    return out
