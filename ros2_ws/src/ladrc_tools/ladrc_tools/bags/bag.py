"""rosbag2 bags of a run: a crash-safe writer and a reader into numpy columns (no rclpy).

Writing (:class:`BagWriter`), storage ``mcap`` (the default, as ``ros2 bag record``): one MCAP
file per run (or per ``split_s`` seconds), written as a stream by :mod:`.mcap_file` with chunk
compression (zstd by default) and flushed every ``flush_s`` seconds, so a SIGKILLed writer
loses at most the last ``flush_s`` plus the writer's queue. ``metadata.yaml`` lists the file
from the first moment and is rewritten (constant size) every ``metadata_s`` and on close; a
file its writer never finished is read by a scan (below). Topic names are fully qualified
(``/axis/capacitive_height``), as ``ros2 bag record`` writes them; channels carry
``offered_qos_profiles`` and ``topic_type_hash`` as rosbag2's mcap plugin writes them.

Storage ``sqlite3``: rosbags' sqlite3 writer commits only on close, so the bag is split into
short *complete* files (``split_s``, as ``ros2 bag record --max-bag-duration``), each written
in a hidden folder and moved next to ``metadata.yaml`` when complete.

No fsync: the threat is a killed process, not a lost page cache. Messages come as raw CDR
bytes (the recorder writes what rclpy received, byte-identical to ``serialize_cdr``) or as
rosbags messages.

Reading (:func:`open_bag` -> :class:`Bag`): rosbags' ``AnyReader`` for complete bags (ours and
``ros2 bag record``'s), a scan of the MCAP files for a bag whose writer was killed
(``Bag.recovered``). Topics are looked up with or without the leading ``/``. One-line
:class:`BagError` for a missing path, a folder that is not a bag, a truncated or foreign file
and a missing topic; topics into numpy columns (``field.sub`` -> array); sequence-counter loss
per topic.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, is_dataclass
import math
import os
from pathlib import Path
import shutil
import struct
import time
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

from ladrc_contract import qos as contract_qos
from ladrc_contract.codes import EventKind, FollowState, GapStatus
from ladrc_contract.events import COMMAND_KIND, EventFields, encode
from ladrc_contract.qos import TOPIC_QOS
from ladrc_contract.topics import SEQ_FIELD, TOPIC_TYPES
import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.metadata import dump_qos_v9
import yaml

from .mcap_file import McapFileWriter, McapScan, is_complete
from .mcap_index import ChannelRows, open_index
from .typestore import ladrc_typestore

BAG_VERSION = 9  # rosbag2 metadata version written by Jazzy
STORAGES = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
SUFFIX = {'mcap': '.mcap', 'sqlite3': '.db3'}

_ZERO = QosTime(0, 0)
# rmw's "infinite" duration as rosbag2 stores it (deadline / lifespan / lease unset).
_INF = QosTime(2147483647, 4294967295)


def rosbags_qos(q: contract_qos.Qos) -> Qos:
    """Return the rosbags profile of a contract profile, for ``offered_qos_profiles``."""
    return Qos(QosHistory.KEEP_LAST, q.depth,
               QosReliability.RELIABLE if q.reliable else QosReliability.BEST_EFFORT,
               QosDurability.TRANSIENT_LOCAL if q.transient_local else QosDurability.VOLATILE,
               _INF, _INF, QosLiveliness.AUTOMATIC, _INF, False)


class BagError(Exception):
    """A bag cannot be written or read; the message is one line saying what and why."""


@dataclass
class _Topic:
    name: str
    msgtype: str
    msgdef: str
    rihs01: str
    qos: tuple[Qos, ...]
    count: int = 0


@dataclass
class _Segment:
    path: str           # file name relative to the bag folder
    start_ns: int
    end_ns: int
    count: int

    def yaml(self) -> tuple[str, str]:
        """Its entries of ``relative_file_paths`` and ``files`` as metadata.yaml text."""
        entry = {'path': self.path, 'starting_time': {'nanoseconds_since_epoch': self.start_ns},
                 'duration': {'nanoseconds': max(0, self.end_ns - self.start_ns)},
                 'message_count': self.count}
        return (_indent(yaml.safe_dump([self.path])),
                _indent(yaml.safe_dump([entry], sort_keys=False)))


def fq(topic: str) -> str:
    """Fully qualified topic name (``/axis/feedback``), as ``ros2 bag record`` stores it."""
    return topic if topic.startswith('/') else '/' + topic


class BagWriter:
    """Write a rosbag2 bag (mcap or sqlite3) that a killed writer leaves readable.

    mcap: one streaming file, a new one every ``split_s`` seconds (``None``: one per bag),
    flushed every ``flush_s``; ``compression`` zstd | lz4 | none. sqlite3: complete files of
    ``split_s`` seconds (``None``: one file, closed by :meth:`close`). Times are wall-clock
    seconds checked on every write and on :meth:`poll`. ``name`` names the storage files
    (default: the folder's name).
    """

    def __init__(self, path: str | Path, *, storage: str = 'mcap', split_s: float | None = None,
                 flush_s: float = 0.25, metadata_s: float = 5.0, compression: str = 'zstd',
                 custom_data: Mapping[str, str] | None = None, typestore: Any = None,
                 name: str | None = None) -> None:
        if storage not in STORAGES:
            raise BagError(f'unknown storage {storage!r}: use one of {", ".join(STORAGES)}')
        if split_s is not None and not split_s > 0:
            raise BagError(f'split_s must be > 0 s or None (one file), got {split_s!r}')
        if not flush_s > 0:
            raise BagError(f'flush_s must be > 0 s, got {flush_s!r}')
        if compression not in ('zstd', 'lz4', 'none'):
            raise BagError(f'unknown compression {compression!r}: use zstd, lz4 or none')
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f'{self.path} exists already: a bag is never overwritten')
        self.storage = storage
        self.split_s = split_s
        self.flush_s = flush_s
        self.metadata_s = metadata_s
        self.compression = compression
        self.name = name or self.path.name  # storage files are <name>_<index>.<suffix>
        self.custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self.typestore = typestore or ladrc_typestore()
        self._topics: dict[str, _Topic] = {}
        self._segments: list[_Segment] = []
        self._segment_yaml: list[tuple[str, str]] = []  # closed files' metadata entries
        self._segments_start: int | None = None
        self._segments_end = 0
        self._segments_count = 0
        self._mcap: McapFileWriter | None = None
        self._writer: Writer | None = None  # sqlite3 segment writer
        self._conns: dict[str, Any] = {}
        self._seg_dir: Path | None = None
        self._seg_opened = 0.0
        self._seg_count = 0
        self._seg_start = 2**63 - 1
        self._seg_end = 0
        self._flushed = self._meta_written = time.monotonic()
        self._closed = False
        self.path.mkdir(parents=True)
        self._write_metadata()  # an empty but valid bag from the first moment

    # -- topics and messages --------------------------------------------------------------
    def add_topic(self, topic: str, msgtype: str | None = None,
                  qos: Qos | Sequence[Qos] | None = None) -> None:
        """Register ``topic`` (type and QoS default to the contract's); idempotent."""
        name = fq(topic)
        if name in self._topics:
            return
        short = name[1:]
        msgtype = msgtype or TOPIC_TYPES.get(short) or TOPIC_TYPES.get(name)
        if msgtype is None:
            raise BagError(f'topic {topic!r} is not in the contract: give its message type')
        if msgtype not in self.typestore.types:
            raise BagError(f'message type {msgtype!r} of {topic!r} is unknown to the typestore')
        if qos is None:
            qos = rosbags_qos(TOPIC_QOS.get(short, TOPIC_QOS.get(name,
                                                                 contract_qos.DIAGNOSTICS)))
        qos_t = (qos,) if isinstance(qos, Qos) else tuple(qos)
        msgdef, _ = self.typestore.generate_msgdef(msgtype, ros_version=2)
        t = self._topics[name] = _Topic(name, msgtype, msgdef,
                                        self.typestore.hash_rihs01(msgtype), qos_t)
        if self._mcap is not None:
            self._mcap.add_channel(t.name, t.msgtype, t.msgdef, t.rihs01, t.qos)
        if self._writer is not None:
            self._add_connection(t)

    def write_raw(self, topic: str, timestamp_ns: int, data: bytes | memoryview) -> None:
        """Write one CDR-serialized message received at ``timestamp_ns`` (bag time)."""
        if self._closed:
            raise BagError(f'bag {self.path} is closed')
        name = fq(topic)
        if name not in self._topics:
            self.add_topic(name)
        if self._mcap is None and self._writer is None:
            self._open_segment()
        if self._mcap is not None:
            self._mcap.write(name, timestamp_ns, data)
        else:
            self._writer.write(self._conns[name], timestamp_ns, data)
        self._topics[name].count += 1
        self._seg_count += 1
        if timestamp_ns < self._seg_start:
            self._seg_start = timestamp_ns
        if timestamp_ns > self._seg_end:
            self._seg_end = timestamp_ns
        self.poll()

    def write(self, topic: str, timestamp_ns: int, msg: Any) -> None:
        """Serialize a rosbags message of the topic's type and write it."""
        name = fq(topic)
        if name not in self._topics:
            self.add_topic(name)
        self.write_raw(name, timestamp_ns,
                       self.typestore.serialize_cdr(msg, self._topics[name].msgtype))

    def poll(self) -> None:
        """Flush, split and rewrite ``metadata.yaml`` when due (also call while idle)."""
        if self._mcap is None and self._writer is None:
            return
        now = time.monotonic()
        if (self.split_s is not None and self._seg_count
                and now - self._seg_opened >= self.split_s):
            self._close_segment()
            return
        if self._mcap is not None:
            if now - self._flushed >= self.flush_s:
                self._mcap.flush()
                self._flushed = now
            if now - self._meta_written >= self.metadata_s:
                self._write_metadata()

    def counts(self) -> dict[str, int]:
        """Messages written per topic so far."""
        return {t.name: t.count for t in self._topics.values()}

    def close(self) -> None:
        """Close the open storage file and write the final ``metadata.yaml``."""
        if self._closed:
            return
        if self._mcap is None and self._writer is None and not self._segments:
            self._open_segment()  # a bag with topics and no messages still has a storage file
        if self._mcap is not None or self._writer is not None:
            self._close_segment()
        self._closed = True

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- storage files --------------------------------------------------------------------
    def _add_connection(self, t: _Topic) -> None:
        self._conns[t.name] = self._writer.add_connection(
            t.name, t.msgtype, msgdef=t.msgdef, rihs01=t.rihs01,
            offered_qos_profiles=list(t.qos))

    def _file_name(self) -> str:
        return f'{self.name}_{len(self._segments)}{SUFFIX[self.storage]}'

    def _open_segment(self) -> None:
        self._seg_opened = self._flushed = time.monotonic()
        self._seg_count = 0
        self._seg_start = 2**63 - 1
        self._seg_end = 0
        if self.storage == 'mcap':
            self._mcap = McapFileWriter(self.path / self._file_name(), self.compression)
            for t in self._topics.values():
                self._mcap.add_channel(t.name, t.msgtype, t.msgdef, t.rihs01, t.qos)
            self._write_metadata()  # the open file is part of the bag from now on
            return
        index = len(self._segments)
        self._seg_dir = self.path / f'.segment-{index}'
        if self._seg_dir.exists():  # left by an earlier attempt
            shutil.rmtree(self._seg_dir)
        self._writer = Writer(self._seg_dir, version=BAG_VERSION,
                              storage_plugin=STORAGES[self.storage])
        for key, value in self.custom_data.items():
            self._writer.set_custom_data(key, value)
        self._writer.open()
        for t in self._topics.values():
            self._add_connection(t)

    def _close_segment(self) -> None:
        name = self._file_name()
        if self._mcap is not None:
            self._mcap.finish()
            self._mcap = None
        else:
            writer = self._writer
            src = writer.storage.path
            writer.close()
            self._writer = None
            # the storage file only becomes part of the bag once it is complete
            os.replace(src, self.path / name)
            shutil.rmtree(self._seg_dir, ignore_errors=True)
            self._seg_dir = None
        start = self._seg_start if self._seg_count else 0
        seg = _Segment(name, start, self._seg_end if self._seg_count else 0, self._seg_count)
        self._segments.append(seg)
        self._segment_yaml.append(seg.yaml())
        if seg.count:  # the bag's time span and count, kept as running figures
            self._segments_start = (seg.start_ns if self._segments_start is None
                                    else min(self._segments_start, seg.start_ns))
            self._segments_end = max(self._segments_end, seg.end_ns)
            self._segments_count += seg.count
        self._write_metadata()

    def _write_metadata(self) -> None:
        """Rewrite ``metadata.yaml``: its cost must not grow with the files already closed.

        Each closed file's two list entries (``relative_file_paths``, ``files``) are rendered
        once, when it closes (:meth:`_Segment.yaml`), and joined as text; only the parts of
        constant size (topics, counts, the open file) go through ``yaml.safe_dump`` each time.
        """
        open_seg = None
        if self._mcap is not None:  # the open file, as far as written
            open_seg = _Segment(self._file_name(), self._seg_start if self._seg_count else 0,
                                self._seg_end, self._seg_count)
        first = self._segments_start
        start = min([x for x in (first, open_seg.start_ns if open_seg and open_seg.count
                                 else None) if x is not None], default=0)
        end = max(self._segments_end, open_seg.end_ns if open_seg and open_seg.count else 0)
        done = {t.name: t.count for t in self._topics.values()}
        if self._writer is not None:  # sqlite3: the open segment is not in the bag yet
            for name, conn in self._conns.items():
                done[name] -= self._writer.counts[conn.id]
        head = {
            'version': BAG_VERSION,
            'storage_identifier': self.storage,
            'duration': {'nanoseconds': max(0, end - start)},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': self._segments_count + (open_seg.count if open_seg else 0),
            'topics_with_message_count': [
                {'topic_metadata': {'name': t.name, 'type': t.msgtype,
                                    'serialization_format': 'cdr',
                                    'offered_qos_profiles': dump_qos_v9(list(t.qos)),
                                    'type_description_hash': t.rihs01},
                 'message_count': done[t.name]}
                for t in self._topics.values()],
            'compression_format': '',
            'compression_mode': '',
        }
        tail = {'custom_data': dict(self.custom_data) or None, 'ros_distro': 'jazzy'}
        entries = self._segment_yaml + ([open_seg.yaml()] if open_seg else [])
        paths = [e[0] for e in entries]
        files = [e[1] for e in entries]
        text = ''.join([
            yaml.safe_dump({'rosbag2_bagfile_information': head}, sort_keys=False),
            '  relative_file_paths:' + ('\n' + ''.join(paths) if paths else ' []\n'),
            '  files:' + ('\n' + ''.join(files) if files else ' []\n'),
            _indent(yaml.safe_dump(tail, sort_keys=False))])
        tmp = self.path / 'metadata.yaml.tmp'
        tmp.write_text(text, encoding='utf-8')
        os.replace(tmp, self.path / 'metadata.yaml')
        self._meta_written = time.monotonic()


def _indent(text: str, by: str = '  ') -> str:
    return ''.join(by + line for line in text.splitlines(keepends=True))


# ---- fast serialization of fixed-layout rows ------------------------------------------------
_BASE = {'bool': '?', 'uint8': 'u1', 'int8': 'i1', 'byte': 'u1', 'char': 'u1', 'octet': 'u1',
         'uint16': '<u2', 'int16': '<i2', 'uint32': '<u4', 'int32': '<i4', 'uint64': '<u8',
         'int64': '<i8', 'float32': '<f4', 'float64': '<f8'}
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

    def unpack(self, datas: Sequence[bytes],
               names: Iterable[str] | None = None) -> dict[str, Any]:
        """Columns of serialized messages; ``{}`` unless every one has all strings empty."""
        size = self.dtype.itemsize
        if any(len(d) != size for d in datas):
            return {}
        return self.unpack_rows(np.frombuffer(b''.join(datas), dtype=np.uint8).reshape(
            len(datas), size), names)

    def unpack_rows(self, rows: np.ndarray,
                    names: Iterable[str] | None = None) -> dict[str, Any]:
        """Columns of an ``(n, size)`` uint8 array of messages; ``{}`` as :meth:`unpack`."""
        if rows.ndim != 2 or rows.shape[1] != self.dtype.itemsize:
            return {}
        arr = np.ascontiguousarray(rows).view(self.dtype)[:, 0]
        # same length is not enough: a short string can hide in alignment padding
        if any(np.any(arr[f'~len.{k}'] != 1) for k in self.strings):
            return {}
        wanted = self.fields if names is None else [f for f in self.fields if f in set(names)]
        out: dict[str, Any] = {f: arr[f].copy() for f in wanted}
        for k in self.strings:
            if names is None or k in set(names):
                out[k] = np.full(arr.size, '', dtype=object)
        # keep the message's field order
        order = [k for k in self._order if k in out]
        return {k: out[k] for k in order}


def _packer(msgtype: str, typestore: Any) -> RowPacker:
    key = (msgtype, id(typestore))
    if key not in _PACKERS:
        _PACKERS[key] = RowPacker(msgtype, typestore)
    return _PACKERS[key]


_PACKERS: dict[tuple[str, int], RowPacker] = {}


def stamp_parts(t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split seconds into ``builtin_interfaces/Time`` (sec, nanosec) arrays."""
    ns = np.round(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)
    return ns // 1_000_000_000, ns % 1_000_000_000


# ---- headless runs ----------------------------------------------------------------------
FRAME_ID = 'z_axis'  # the sim node's frame_id (its parameter's default)
COMMANDER = '/ladrc_follow'  # the follow node's fully qualified name (VelocityCommand.commander)


def _fresh(n: int, h_s: float, spans: list[tuple[float, float]]) -> np.ndarray:
    """Return True on ticks with a new sample (the runner holds samples in dropouts)."""
    fresh = np.ones(n, dtype=bool)
    for t_s, dur in spans:
        i0 = int(round(t_s / h_s))
        fresh[i0:i0 + max(1, int(round(dur / h_s)))] = False
    return fresh


def _drive_schedule(n: int, h_s: float, timeline: Sequence[Any]) -> tuple[np.ndarray, ...]:
    enabled = np.ones(n, dtype=bool)
    fault = np.zeros(n, dtype=bool)
    for e in sorted((e for e in timeline if e.name == 'drive'), key=lambda e: e.t_s):
        i = min(n - 1, int(round(e.t_s / h_s)))
        enabled[i:] = bool(e.args.get('enabled', True))
        fault[i:] = bool(e.args.get('fault', False))
    return enabled, fault


def _last_seq(fresh: np.ndarray) -> np.ndarray:
    """Seq (0-based count of fresh samples) of the sample held at each tick."""
    return np.maximum(np.cumsum(fresh) - 1, 0).astype(np.uint64)


def _pack_by_text(packer: RowPacker, n: int, cols: Mapping[str, Any], key: str,
                  texts: Any) -> list[bytes]:
    """Pack ``n`` rows whose string field ``key`` is ``texts[i]`` (one packer per text)."""
    rows = packer.pack(n, cols)
    if texts is None:
        return rows
    texts = np.asarray(texts, dtype=object)
    for text in set(texts.tolist()) - {'', None}:
        idx = np.flatnonzero(texts == text)
        sub = {k: (v[idx] if isinstance(v, np.ndarray) and v.shape == (n,) else v)
               for k, v in cols.items()}
        strings = {k: v.decode('utf-8') for k, v in packer.texts.items()}
        strings[key] = str(text)
        for i, row in zip(idx.tolist(), RowPacker(packer.msgtype, packer.store,
                                                  strings).pack(idx.size, sub),
                          strict=True):
            rows[i] = row
    return rows


def write_run_bag(result: Any, path: str | Path, params_yaml: str = '',
                  scenario_yaml: str = '', *, storage: str = 'mcap',
                  controller: str = '') -> Path:
    """Write a headless ``ladrc_sim.headless.runner.RunResult`` as a bag with a live run's layout.

    One message per tick on the 2 kHz topics (capacitive height and feedback only on ticks
    with a fresh sample, as a driver publishes nothing during a dropout), ``follow/events``
    from the scenario's commands at the runner's ticks (plus a PARAMETERS event at tick 0),
    ``run/parameters`` and ``run/scenario`` texts. Stamps and bag times are sim time. Status
    fields come from ``result.internals`` when the controller reports them under FollowStatus
    names, else from the run's series (floats the run does not know are NaN). The command's
    ``enable`` is ``internals['command_enable']`` when the controller reports it (the
    excitation player), else derived from the follow state. Written into a temporary folder
    and renamed, so ``path`` appears only complete.
    """
    path = Path(path)
    if path.exists():
        raise BagError(f'{path} exists already: a bag is never overwritten')
    store = ladrc_typestore()
    sc = result.scenario
    h_s = float(result.h_s)
    t = np.asarray(result.t_s, dtype=float)
    n = t.size
    internals = {k: np.asarray(v) for k, v in (result.internals or {}).items()}
    timeline = list(getattr(sc, 'timeline', ()))
    gap_fresh = _fresh(n, h_s, [(e.t_s, e.args['duration_s']) for e in timeline
                                if e.name == 'sensor_dropout'])
    enc_fresh = _fresh(n, h_s, [(e.t_s, e.args['duration_s']) for e in timeline
                                if e.name == 'encoder_dropout'])
    gap_seq, enc_seq = _last_seq(gap_fresh), _last_seq(enc_fresh)
    # sample time of the held sample: the time of the last fresh tick
    gap_stamp = t[np.maximum.accumulate(np.where(gap_fresh, np.arange(n), 0))]
    enc_stamp = t[np.maximum.accumulate(np.where(enc_fresh, np.arange(n), 0))]
    enabled, fault = _drive_schedule(n, h_s, timeline)
    reading = np.asarray(result.reading_mm, dtype=float)
    valid = np.asarray(result.reading_valid, dtype=bool)
    collision = np.asarray(result.collision, dtype=bool)
    encoder = np.asarray(result.encoder_mm, dtype=float)
    command = np.asarray(result.command_mm_s, dtype=float)
    target = np.asarray(result.target_gap_mm, dtype=float)
    status_code = np.where(valid, GapStatus.OK,
                           np.where(collision, GapStatus.COLLISION, GapStatus.OUT_OF_RANGE))
    enc_vel = np.diff(encoder, prepend=encoder[:1]) / h_s  # what a driver differentiates
    # the raw value behind each reading, as the sim node sends it (models/sensor.py)
    raw_hz = result.raw_hz() if callable(getattr(result, 'raw_hz', None)) else np.nan
    ticks = np.arange(n, dtype=np.uint64)

    frame = {'header.frame_id': FRAME_ID}
    cap_rows = RowPacker('ladrc_msgs/msg/CapacitiveHeight', store, frame).pack(n, {
        'stamp_s': t, 'seq': gap_seq, 'gap_mm': reading,
        'raw_hz': raw_hz, 'valid': valid, 'status': status_code})
    from ladrc_sim.headless.scenario import DRIVE_FAULT_REASON

    fb_rows = _pack_by_text(
        RowPacker('ladrc_msgs/msg/AxisFeedback', store, frame), n, {
            'stamp_s': t, 'seq': enc_seq, 'position_mm': encoder,
            'velocity_mm_s': np.nan_to_num(enc_vel), 'drive_enabled': enabled,
            'drive_fault': fault}, 'fault_reason', np.where(fault, DRIVE_FAULT_REASON, ''))
    state = internals.get('state')
    if 'command_enable' in internals:  # a controller that says it (the excitation player)
        enable = np.nan_to_num(internals['command_enable']).astype(bool)
    elif state is not None:
        # FollowController.enable: approaching or following, or a command not yet zero
        # (a retract, a ramp down)
        state = np.nan_to_num(state).astype(np.uint8)
        enable = (((state >= FollowState.PREINTERPOLATE) & (state <= FollowState.LADRC))
                  | (command != 0.0))
    else:
        enable = np.isfinite(target)
    # the runner's convention is lock step's: command k answers step k (docs/follow-node.md)
    cmd_rows = RowPacker('ladrc_msgs/msg/VelocityCommand', store,
                         {'commander': COMMANDER}).pack(n, {
        'stamp_s': t, 'seq': ticks, 'velocity_mm_s': command, 'enable': enable,
        'sample_seq': ticks})
    status_packer = RowPacker('ladrc_msgs/msg/FollowStatus', store)
    status_cols: dict[str, Any] = {
        'stamp_s': t, 'tick': ticks, 't_s': t, 'sample_seq': ticks, 'feed_override_request': 1.0,
        'target_gap_mm': target, 'gap_seq': gap_seq, 'gap_mm': reading, 'gap_valid': valid,
        'gap_status': status_code,
        'gap_stamp_s': gap_stamp, 'encoder_seq': enc_seq, 'encoder_mm': encoder,
        'encoder_stamp_s': enc_stamp, 'drive_enabled': enabled, 'drive_fault': fault,
        'velocity_mm_s': command, 'u_unlimited_mm_s': command, 'period_us': h_s * 1e6,
        'compute_us': np.nan,
        'input_age_us': (t - np.minimum(gap_stamp, enc_stamp)) * 1e6,
    }
    for f in status_packer.fields:
        if f.startswith('header.') or f in status_cols:
            continue
        if status_packer.dtype[f].kind == 'f':
            status_cols[f] = np.nan
    for key, values in internals.items():
        if key in status_packer.fields and not key.startswith('header.'):
            kind = status_packer.dtype[key].kind
            status_cols[key] = (values if kind == 'f'
                                else np.nan_to_num(values).astype(status_packer.dtype[key]))
    status_rows = _pack_by_text(status_packer, n, status_cols, 'fault_reason',
                                internals.get('fault_reason'))
    plate_v = getattr(result, 'plate_velocity_mm_s', None)
    truth_rows = RowPacker('ladrc_msgs/msg/SimTruth', store, frame).pack(n, {
        'stamp_s': t, 'seq': ticks,
        'true_gap_mm': result.true_gap_mm, 'sheet_mm': result.sheet_mm,
        'nozzle_mm': result.nozzle_mm, 'edge_coverage': result.coverage,
        'plate_velocity_mm_s': np.nan if plate_v is None else plate_v, 'collision': collision,
        'x_mm': np.nan, 'y_mm': np.nan})

    # events: PARAMETERS at tick 0, then the scenario's commands at the runner's ticks
    Event = store.types['ladrc_msgs/msg/FollowEvent']
    Header = store.types['std_msgs/msg/Header']
    Time = store.types['builtin_interfaces/msg/Time']

    def event(tick: int, f: EventFields) -> tuple[int, bytes]:
        sec, nsec = divmod(int(round(t[tick] * 1e9)), 1_000_000_000)
        msg = Event(header=Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=''),
                    tick=tick, kind=f.kind, value_mm=f.value_mm, delay_s=f.delay_s,
                    velocity_mm_s=f.velocity_mm_s, accel_mm_s2=f.accel_mm_s2, flag=f.flag,
                    text=f.text)
        return tick, bytes(store.serialize_cdr(msg, 'ladrc_msgs/msg/FollowEvent'))

    # as the follow node logs them (ladrc_contract.events)
    events = [event(0, EventFields(EventKind.PARAMETERS, text=params_yaml))] if params_yaml else []
    for e in timeline:
        if getattr(e, 'is_command', False) and e.name in COMMAND_KIND:
            events.append(event(min(n - 1, int(round(e.t_s / h_s))), encode(e.name, e.args)))
    events.sort(key=lambda x: x[0])

    tmp = path.with_name(f'.{path.name}.partial')
    if tmp.exists():
        shutil.rmtree(tmp)
    custom = {'ladrc.source': 'headless', 'ladrc.scenario': str(getattr(sc, 'name', ''))}
    if controller:
        custom['ladrc.controller'] = controller
    # no flush or metadata rewrite on the wall clock: the bag is renamed into place only when
    # complete, and chunks cut by size alone make the same run the same bytes however fast
    # the machine writes (a 0.25 s flush cut a loaded run's chunks elsewhere)
    writer = BagWriter(tmp, storage=storage, split_s=None, custom_data=custom, typestore=store,
                       name=path.name, flush_s=math.inf, metadata_s=math.inf)
    try:
        for topic in ('axis/capacitive_height', 'axis/feedback', 'axis/velocity_command',
                      'follow/status', 'follow/events', 'sim/truth', 'run/parameters',
                      'run/scenario'):
            writer.add_topic(topic)
        for topic, text in (('run/parameters', params_yaml), ('run/scenario', scenario_yaml)):
            writer.write(topic, 0, string_msg(text, store))
        ns = np.round(t * 1e9).astype(np.int64).tolist()
        w = writer.write_raw
        k = 0
        gap_fresh_l, enc_fresh_l = gap_fresh.tolist(), enc_fresh.tolist()
        for i in range(n):
            ts = ns[i]
            while k < len(events) and events[k][0] == i:
                w('follow/events', ts, events[k][1])
                k += 1
            if gap_fresh_l[i]:
                w('axis/capacitive_height', ts, cap_rows[i])
            w('sim/truth', ts, truth_rows[i])
            if enc_fresh_l[i]:
                w('axis/feedback', ts, fb_rows[i])
            w('follow/status', ts, status_rows[i])
            w('axis/velocity_command', ts, cmd_rows[i])
        writer.close()
        os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return path


# ---- reading --------------------------------------------------------------------------------
def _flatten(msg: Any, prefix: str = '') -> Iterator[tuple[str, Any]]:
    for f in fields(msg):
        if f.name == '__msgtype__':
            continue
        value = getattr(msg, f.name)
        if is_dataclass(value):
            yield from _flatten(value, f'{prefix}{f.name}.')
        else:
            yield f'{prefix}{f.name}', value


def _getter(path: str) -> Callable[[Any], Any]:
    parts = path.split('.')
    if len(parts) == 1:
        name = parts[0]
        return lambda m: getattr(m, name)

    def get(m: Any) -> Any:
        for p in parts:
            m = getattr(m, p)
        return m
    return get


@dataclass
class _ScanTopic:
    msgtype: str
    msgcount: int


@dataclass
class _ScanConnection:
    topic: str
    msgtype: str


class _ScanReader:
    """The part of rosbags' ``AnyReader`` that :class:`Bag` uses, over scanned MCAP files.

    For a bag whose writer was killed: its last file has no summary, which rosbags cannot
    open. Every file is scanned (:class:`.mcap_file.McapScan`); message types the bag defines
    and the contract's typestore does not know are registered from their definitions.
    """

    def __init__(self, files: list[Path]) -> None:
        from rosbags.typesys import get_types_from_msg

        self.scans = [McapScan(f) for f in files]
        self.typestore = ladrc_typestore()
        self.topics: dict[str, _ScanTopic] = {}
        for scan in self.scans:
            for name, t in scan.topics.items():
                cur = self.topics.get(name)
                self.topics[name] = _ScanTopic(t.msgtype, t.msgcount + (cur.msgcount
                                                                       if cur else 0))
            for msgtype, text in scan.schemas.items():
                if msgtype not in self.typestore.types:
                    try:
                        self.typestore.register(get_types_from_msg(text, msgtype))
                    except Exception:  # a definition rosbags cannot parse: raw bytes only
                        pass
        self.connections = [_ScanConnection(n, t.msgtype) for n, t in self.topics.items()]

    def messages(self, connections: Iterable[_ScanConnection]
                 ) -> Iterator[tuple[_ScanConnection, int, bytes]]:
        conns = {c.topic: c for c in connections}
        for scan in self.scans:
            for topic, ts, data in scan.messages(conns):
                yield conns[topic], ts, data

    def deserialize(self, data: bytes, msgtype: str) -> Any:
        return self.typestore.deserialize_cdr(data, msgtype)

    def close(self) -> None:
        self.scans = []


COLUMN_CHUNK = 65536
"""Messages decoded at a time by :meth:`Bag.columns` (bounds its temporary memory)."""


class Bag:
    """An open bag: topics, custom data, messages, numpy columns and loss counts.

    Topic names are looked up with or without their leading ``/`` (the project's older bags
    stored ``axis/feedback``, ``ros2 bag record`` stores ``/axis/feedback``). ``recovered``:
    the bag's writer was killed and its last file was read by a scan.
    """

    def __init__(self, path: Path, reader: Any, recovered: bool = False) -> None:
        self.path = path
        self.reader = reader
        self.recovered = recovered
        self.topics: dict[str, str] = {name: info.msgtype
                                       for name, info in reader.topics.items()}
        self.message_counts: dict[str, int] = {name: info.msgcount
                                               for name, info in reader.topics.items()}
        self._alias: dict[str, str] = {}
        for name in list(self.topics):  # aliases: with and without the leading slash
            alias = name[1:] if name.startswith('/') else '/' + name
            if alias not in self.topics:
                self._alias[alias] = name
        custom: dict[str, str] = {}
        self._storage = ''
        self._files: list[Path] = []
        meta = path / 'metadata.yaml'
        if meta.is_file():
            try:
                info = yaml.safe_load(meta.read_text(encoding='utf-8'))
                info = info['rosbag2_bagfile_information']
                custom = dict(info.get('custom_data') or {})
                self._storage = str(info.get('storage_identifier', ''))
                self._files = [path / str(f) for f in info.get('relative_file_paths') or []]
            except (yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError):
                custom = {}
        self.custom_data = custom

    def close(self) -> None:
        """Close the underlying reader."""
        self.reader.close()

    def __enter__(self) -> Bag:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def name(self, topic: str) -> str:
        """Return the bag's own name of ``topic`` (given with or without the leading ``/``)."""
        return self._alias.get(topic, topic)

    def has(self, topic: str) -> bool:
        """Whether the bag holds ``topic`` (with or without the leading ``/``)."""
        return self.name(topic) in self.topics

    def count(self, topic: str) -> int:
        """Messages of ``topic`` in the bag (0 when absent)."""
        return self.message_counts.get(self.name(topic), 0)

    def require(self, *topics: str) -> None:
        """Raise :class:`BagError` naming the first of ``topics`` the bag does not hold."""
        for t in topics:
            if not self.has(t):
                raise BagError(f'{self.path}: bag has no {t!r} topic (it holds: '
                               f'{", ".join(sorted(self.topics)) or "nothing"})')

    def raw(self, topic: str,
            progress: Callable[[int, int], None] | None = None
            ) -> Iterator[tuple[int, bytes]]:
        """Yield ``(bag timestamp ns, CDR bytes)`` of ``topic`` in time order."""
        self.require(topic)
        topic = self.name(topic)
        conns = [c for c in self.reader.connections if c.topic == topic]
        total = self.message_counts.get(topic, 0)
        try:
            for i, (_, ts, data) in enumerate(self.reader.messages(connections=conns)):
                if progress is not None and i % 5000 == 0:
                    progress(i, total)
                yield ts, data
        except Exception as exc:  # rosbags raises various errors on damaged storage
            raise BagError(f'{self.path}: cannot read {topic!r}: {_one_line(exc)}') from None
        if progress is not None:
            progress(total, total)

    def messages(self, topic: str) -> Iterator[tuple[int, Any]]:
        """Yield ``(bag timestamp ns, deserialized message)`` of ``topic``."""
        msgtype = self.topics.get(self.name(topic))
        for ts, data in self.raw(topic):
            yield ts, self.reader.deserialize(data, msgtype)

    def columns(self, topic: str, names: Iterable[str] | None = None,
                progress: Callable[[int, int], None] | None = None) -> dict[str, np.ndarray]:
        """Read ``topic`` into ``{flattened field: array}`` plus ``timestamp_ns``.

        Nested fields are joined with dots (``header.stamp.sec``); ``stamp_s`` is added when
        the message has a header. Sequences (e.g. diagnostics' status list) stay objects.
        Decoded :data:`COLUMN_CHUNK` messages at a time (:meth:`iter_columns`), so the memory is
        that of the requested columns (give ``names`` for long bags), not of the messages.
        """
        parts: dict[str, list[np.ndarray]] = {}
        for cols in self.iter_columns(topic, names, progress):
            for k, v in cols.items():
                parts.setdefault(k, []).append(v)
        if not parts:
            return {'timestamp_ns': np.zeros(0, np.int64)}
        return _joined(parts)

    def iter_columns(self, topic: str, names: Iterable[str] | None = None,
                     progress: Callable[[int, int], None] | None = None,
                     chunk: int | None = None) -> Iterator[dict[str, np.ndarray]]:
        """Yield ``topic`` as column dicts of about ``chunk`` messages (default COLUMN_CHUNK).

        The same columns, types and order in every chunk (see :meth:`columns`); a consumer
        that handles one chunk at a time (CSV export) needs memory for one chunk only.
        """
        self.require(topic)
        for part in self.stream({topic: names}, progress, chunk):
            if topic in part:
                yield part[topic]

    def read_topics(self, wanted: Mapping[str, Iterable[str] | None],
                    progress: Callable[[int, int], None] | None = None
                    ) -> dict[str, dict[str, np.ndarray]]:
        """Read several topics into columns in ONE pass over the bag (see :meth:`columns`).

        ``wanted`` maps topic -> field names (None: all); topics the bag lacks are left out
        of the result. A long bag is read once instead of once per topic.
        """
        parts: dict[str, dict[str, list[np.ndarray]]] = {t: {} for t in wanted if self.has(t)}
        for part in self.stream(wanted, progress):
            for topic, cols in part.items():
                for k, v in cols.items():
                    parts[topic].setdefault(k, []).append(v)
        return {t: _joined(cols) if cols else {'timestamp_ns': np.zeros(0, np.int64)}
                for t, cols in parts.items()}

    def stream(self, wanted: Mapping[str, Iterable[str] | None],
               progress: Callable[[int, int], None] | None = None,
               chunk: int | None = None) -> Iterator[dict[str, dict[str, np.ndarray]]]:
        """Yield the bag in time slices: ``{topic: columns}`` of about ``chunk`` messages.

        ONE pass over the bag for all of ``wanted`` (topic -> field names, None: all; topics
        the bag lacks are left out). Each slice holds the messages of consecutive bag time,
        every topic's columns as :meth:`columns` builds them (a topic with no message in a
        slice is absent from it), so a consumer that joins topics by time (the report, the
        replay) holds one slice at a time. Finished MCAP files are read through their
        message indexes (:mod:`.mcap_index`), others message by message.
        """
        names = {self.name(t): t for t in wanted if self.has(t)}
        decoders = {n: _Decoder(self, n, wanted[asked]) for n, asked in names.items()}
        size = chunk or COLUMN_CHUNK
        pending = 0

        def slice_() -> dict[str, dict[str, np.ndarray]]:
            return {names[n]: d.decode() for n, d in decoders.items() if d.n}

        files = self._indexed_files() if decoders else None
        try:
            if files is not None:
                total = sum(f.stat().st_size for f in files)
                done = 0
                for f in files:  # one file open at a time
                    ix = open_index(f)
                    if ix is None:
                        raise BagError(f'{f}: its MCAP index became unreadable')
                    try:
                        ids = {ix.channels[n].channel_id: n for n in decoders
                               if n in ix.channels}
                        for nbytes, rows in ix.read(set(ids)):
                            done += nbytes
                            for cid, r in rows.items():
                                if len(r.log_time_ns):
                                    decoders[ids[cid]].add_rows(r)
                                    pending += len(r.log_time_ns)
                            if pending >= size:
                                yield slice_()
                                pending = 0
                                if progress is not None:
                                    progress(done, total)
                    finally:
                        ix.close()
            else:
                conns = [c for c in self.reader.connections if c.topic in decoders]
                total = sum(self.message_counts.get(n, 0) for n in decoders)
                for i, (conn, ts, data) in enumerate(self.reader.messages(connections=conns)):
                    decoders[conn.topic].add(ts, data)
                    pending += 1
                    if pending >= size:
                        yield slice_()
                        pending = 0
                        if progress is not None:
                            progress(i, total)
            if pending:
                yield slice_()
        except BagError:
            raise
        except Exception as exc:  # rosbags, mcap, numpy and the OS raise various errors
            raise BagError(f'{self.path}: cannot read the bag: {_one_line(exc)}') from None
        if progress is not None:
            progress(1, 1)

    def _indexed_files(self) -> list[Path] | None:
        """Return the bag's MCAP files if each can be read through its indexes, in time order.

        Each file is opened and closed in turn (a bag split per minute has 1 440 files a
        day); None sends the caller to the message-by-message reader.
        """
        if not isinstance(self.reader, AnyReader) or self._storage != 'mcap' or not self._files:
            return None
        end = -1
        for f in self._files:
            ix = open_index(f)
            if ix is None:
                return None
            span = ix.span_ns
            ix.close()
            if span is not None:
                if span[0] < end:
                    return None  # files interleave in time: only a merging reader orders them
                end = span[1]
        return list(self._files)

    def _slow_columns(self, msgtype: str, datas: list[bytes],
                      names: Iterable[str] | None) -> dict[str, list]:
        deserialize = self.reader.typestore.deserialize_cdr
        cols: dict[str, list] = {}
        getters: list[tuple[list, Callable[[Any], Any]]] | None = None
        for data in datas:
            msg = deserialize(data, msgtype)
            if getters is None:
                keys = [k for k, _ in _flatten(msg)]
                if names is not None:
                    wanted = set(names)
                    keys = [k for k in keys if k in wanted]
                for k in keys:
                    cols[k] = []
                getters = [(cols[k], _getter(k)) for k in keys]
            for col, get in getters:
                col.append(get(msg))
        return cols

    def seq_loss(self, topic: str) -> tuple[int, int]:
        """Return ``(received, lost)`` of a counter topic: lost = sum of gaps in its seq."""
        self.require(topic)
        field = SEQ_FIELD.get(topic.lstrip('/'), 'seq')
        seq = self.columns(topic, [field]).get(field, np.zeros(0, np.int64)).astype(np.int64)
        return int(seq.size), count_lost(seq)


def _to_array(values: list) -> np.ndarray:
    if values and isinstance(values[0], (bool, np.bool_)):
        return np.asarray(values, dtype=bool)
    if values and isinstance(values[0], (int, float, np.integer, np.floating)):
        return np.asarray(values)
    out = np.empty(len(values), dtype=object)
    out[:] = values
    return out


def _joined(parts: dict[str, list[np.ndarray]]) -> dict[str, np.ndarray]:
    """Concatenate each column's chunks, releasing them column by column (peak memory)."""
    out = {}
    for k in list(parts):
        v = parts.pop(k)
        out[k] = v[0] if len(v) == 1 else np.concatenate(v)
    return out


class _Decoder:
    """Messages of one topic -> column dicts, a batch at a time (:meth:`Bag.stream`).

    Messages come one by one (:meth:`add`, CDR bytes) or a chunk's rows at a time
    (:meth:`add_rows`, from :mod:`.mcap_index`).
    """

    def __init__(self, bag: Bag, topic: str, names: Iterable[str] | None) -> None:
        self.bag = bag
        self.msgtype = bag.topics.get(bag.name(topic))
        try:
            self.packer: RowPacker | None = _packer(self.msgtype, bag.reader.typestore)
        except (BagError, KeyError):
            self.packer = None
        if names is not None:
            names = list(names)
            if 'stamp_s' in names:
                names += ['header.stamp.sec', 'header.stamp.nanosec']
        self.names = names
        self.parts: list[tuple[np.ndarray, np.ndarray | list[bytes]]] = []
        self.stamps: list[int] = []
        self.batch: list[bytes] = []
        self.n = 0

    def add(self, ts: int, data: bytes) -> int:
        """Queue one message; return the number queued."""
        self.stamps.append(ts)
        self.batch.append(data)
        self.n += 1
        return self.n

    def add_rows(self, rows: ChannelRows) -> int:
        """Queue one chunk's messages of this topic; return the number queued."""
        if not len(rows.log_time_ns):
            return self.n
        self._close_batch()
        self.parts.append((rows.log_time_ns, rows.rows))
        self.n += len(rows.log_time_ns)
        return self.n

    def _close_batch(self) -> None:
        if self.batch:
            self.parts.append((np.asarray(self.stamps, dtype=np.int64), self.batch))
            self.stamps, self.batch = [], []

    def decode(self) -> dict[str, np.ndarray]:
        """Decode what is queued (fast fixed-layout path, else the general one)."""
        self._close_batch()
        parts, self.parts, self.n = self.parts, [], 0
        packer, names = self.packer, self.names
        stamps = (np.concatenate([p[0] for p in parts]) if len(parts) != 1 else parts[0][0])
        cols: dict[str, Any] = {}
        arrays = [p[1] for p in parts if isinstance(p[1], np.ndarray)
                  and packer is not None and p[1].shape[1] == packer.dtype.itemsize]
        if packer is not None and len(arrays) == len(parts):
            cols = packer.unpack_rows(arrays[0] if len(arrays) == 1 else np.concatenate(arrays),
                                      names)
        elif packer is not None:
            cols = packer.unpack(_as_bytes(parts), names)
        if not cols:  # strings in the messages: the general (slow) path for this batch
            slow = self.bag._slow_columns(self.msgtype, _as_bytes(parts), names)
            if packer is not None:  # the same columns, order and types as the fast path
                slow = {k: slow[k] for k in packer._order if k in slow}
            for k, v in slow.items():
                arr = _to_array(v)
                if packer is not None and k in packer.fields and arr.dtype != object:
                    arr = arr.astype(packer.dtype[k])
                cols[k] = arr
        out = {'timestamp_ns': np.asarray(stamps, dtype=np.int64), **cols}
        if 'header.stamp.sec' in out:
            out['stamp_s'] = out['header.stamp.sec'] + out['header.stamp.nanosec'] * 1e-9
        return out


def _as_bytes(parts: list[tuple[np.ndarray, np.ndarray | list[bytes]]]) -> list[bytes]:
    out: list[bytes] = []
    for _, rows in parts:
        out.extend(r.tobytes() for r in rows) if isinstance(rows, np.ndarray) else out.extend(rows)
    return out


def _one_line(exc: BaseException) -> str:
    text = ' '.join(str(exc).split()) or type(exc).__name__
    return text if len(text) < 300 else text[:297] + '...'


def seq_of(data: bytes | memoryview) -> int:
    """Return the uint64 right after the std_msgs/Header of a CDR message (its seq/tick).

    CDR: 4-byte encapsulation, header stamp (int32 + uint32), frame_id (uint32 length incl.
    NUL + bytes), then the uint64 aligned to 8 relative to the end of the encapsulation.
    """
    n = struct.unpack_from('<I', data, 12)[0]
    off = 8 + 4 + n
    off += -off % 8
    return struct.unpack_from('<Q', data, 4 + off)[0]


def count_lost(seq: np.ndarray) -> int:
    """Count the values skipped in an increasing ``seq`` (a restart counts nothing)."""
    if seq.size < 2:
        return 0
    d = np.diff(seq.astype(np.int64))
    return int(np.sum(d[d > 1] - 1))


def open_bag(path: str | Path) -> Bag:
    """Open a bag folder (or a file inside it); :class:`BagError` on anything unreadable."""
    p = Path(path)
    if not p.exists():
        raise BagError(f'{p}: no such file or folder')
    if p.is_file() and p.suffix != '.bag':
        if (p.parent / 'metadata.yaml').is_file():
            p = p.parent
        else:
            raise BagError(f'{p}: not a rosbag2 bag (no metadata.yaml beside it)')
    elif p.is_dir() and not (p / 'metadata.yaml').is_file():
        raise BagError(f'{p}: not a rosbag2 bag folder (no metadata.yaml)')
    unfinished = _unfinished_mcap(p)
    if unfinished:
        # the writer was killed: rosbags needs the summary it never wrote; scan the files
        try:
            return Bag(p, _ScanReader(unfinished), recovered=True)
        except Exception as exc:
            raise BagError(f'{p}: cannot recover bag: {_one_line(exc)}') from None
    try:
        reader = AnyReader([p])
        reader.open()
    except Exception as exc:  # AnyReaderError, ReaderError, yaml and storage errors
        raise BagError(f'{p}: cannot open bag: {_one_line(exc)}') from None
    return Bag(p, reader)


def _unfinished_mcap(folder: Path) -> list[Path] | None:
    """Return the MCAP files if one has no footer (its writer was killed), else None."""
    try:
        info = yaml.safe_load((folder / 'metadata.yaml').read_text(encoding='utf-8'))
        meta = info['rosbag2_bagfile_information']
        if meta.get('storage_identifier') != 'mcap':
            return None
        files = [folder / str(f) for f in meta.get('relative_file_paths') or []]
    except (OSError, ValueError, yaml.YAMLError, KeyError, TypeError, AttributeError):
        return None  # AnyReader says what is wrong with it (UnicodeDecodeError: a ValueError)
    files = [f for f in files if f.is_file()]
    if files and not all(is_complete(f) for f in files):
        return files
    return None


def read_text_topic(bag: Bag, topic: str) -> str | None:
    """Return the last std_msgs/String ``data`` on ``topic``; None when absent."""
    if not bag.has(topic):
        return None
    text = None
    for _, msg in bag.messages(topic):
        text = msg.data
    return text


def string_msg(text: str, typestore: Any = None) -> Any:
    """Return a rosbags std_msgs/String."""
    store = typestore or ladrc_typestore()
    return store.types['std_msgs/msg/String'](data=text)


def storage_of(name: str) -> str:
    """Validate a storage name (``mcap`` or ``sqlite3``)."""
    if name not in STORAGES:
        raise BagError(f'unknown storage {name!r}: use one of {", ".join(STORAGES)}')
    return name


__all__ = ['Bag', 'BagError', 'BagWriter', 'count_lost', 'fq', 'open_bag', 'read_text_topic',
           'seq_of', 'string_msg', 'rosbags_qos']
