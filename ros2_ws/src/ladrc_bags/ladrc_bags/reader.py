"""Reading a bag: :func:`open_bag` -> :class:`Bag`, topics into numpy columns (no rclpy).

rosbags' ``AnyReader`` for complete bags (ours and ``ros2 bag record``'s), a scan of the MCAP
files for a bag whose writer was killed (:mod:`.recovery`, ``Bag.recovered``). Topics are
looked up with or without the leading ``/``. One-line :class:`BagError` for a missing path, a
folder that is not a bag, a truncated or foreign file and a missing topic; topics into numpy
columns (``field.sub`` -> array); sequence-counter loss per topic.
"""

from __future__ import annotations

from dataclasses import fields, is_dataclass
from pathlib import Path
import struct
from typing import Any, Callable, Iterable, Iterator, Mapping

from ladrc_contract.topics import SEQ_FIELD
import numpy as np
from rosbags.highlevel import AnyReader
import yaml

from .columns import CdrColumns
from .errors import BagError
from .mcap_index import ChannelRows, open_index
from .recovery import _ScanReader, _unfinished_mcap


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

    Messages come one by one (:meth:`add`, CDR bytes) or a chunk's messages at a time
    (:meth:`add_rows`, from :mod:`.mcap_index`); :class:`~.columns.CdrColumns` decodes a batch
    at once, strings included; a type with arrays, or a batch it cannot read, goes message by
    message through rosbags (which names what is wrong).
    """

    def __init__(self, bag: Bag, topic: str, names: Iterable[str] | None) -> None:
        self.bag = bag
        self.msgtype = bag.topics.get(bag.name(topic))
        try:
            # built per bag: a bag of an older revision has its own definitions of the same type
            self.columns: CdrColumns | None = CdrColumns(self.msgtype, bag.reader.typestore)
        except (BagError, KeyError):
            self.columns = None
        if names is not None:
            names = list(names)
            if 'stamp_s' in names:
                names += ['header.stamp.sec', 'header.stamp.nanosec']
        self.names = names
        self.parts: list[ChannelRows] = []
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
        self.parts.append(rows)
        self.n += len(rows.log_time_ns)
        return self.n

    def _close_batch(self) -> None:
        if self.batch:
            size = np.fromiter(map(len, self.batch), dtype=np.int64, count=len(self.batch))
            start = np.zeros(size.size, dtype=np.int64)
            np.cumsum(size[:-1], out=start[1:])
            self.parts.append(ChannelRows(np.asarray(self.stamps, dtype=np.int64),
                                          np.frombuffer(b''.join(self.batch), dtype=np.uint8),
                                          start, size))
            self.stamps, self.batch = [], []

    def decode(self) -> dict[str, np.ndarray]:
        """Decode what is queued (columns at once, else message by message)."""
        self._close_batch()
        parts, self.parts, self.n = self.parts, [], 0
        rows = parts[0] if len(parts) == 1 else _joined_rows(parts)
        cols = None
        if self.columns is not None:
            cols = self.columns.decode(rows.data, rows.start, rows.size, self.names)
        if cols is None:  # arrays in the type, or bytes that are not its CDR: rosbags says why
            datas = [rows.data[a:a + n].tobytes()
                     for a, n in zip(rows.start.tolist(), rows.size.tolist(), strict=True)]
            cols = {k: _to_array(v)
                    for k, v in self.bag._slow_columns(self.msgtype, datas, self.names).items()}
        out = {'timestamp_ns': rows.log_time_ns, **cols}
        if 'header.stamp.sec' in out:
            out['stamp_s'] = out['header.stamp.sec'] + out['header.stamp.nanosec'] * 1e-9
        return out


def _joined_rows(parts: list[ChannelRows]) -> ChannelRows:
    """One buffer of several batches' messages (their starts shifted)."""
    shift = np.cumsum([0] + [p.data.size for p in parts[:-1]])
    return ChannelRows(np.concatenate([p.log_time_ns for p in parts]),
                       np.concatenate([p.data for p in parts]),
                       np.concatenate([p.start + s for p, s in zip(parts, shift, strict=True)]),
                       np.concatenate([p.size for p in parts]))


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


def read_text_topic(bag: Bag, topic: str) -> str | None:
    """Return the last std_msgs/String ``data`` on ``topic``; None when absent."""
    if not bag.has(topic):
        return None
    text = None
    for _, msg in bag.messages(topic):
        text = msg.data
    return text


def read_first_text(bag: Bag, topic: str) -> str | None:
    """Return the first std_msgs/String ``data`` on ``topic``; None when absent.

    ``run/parameters``: the set the run started with (the follow node re-publishes the latched
    text on every change).
    """
    if not bag.has(topic):
        return None
    for _, msg in bag.messages(topic):
        return str(msg.data)
    return None
