"""Messages of an indexed MCAP file read chunk by chunk as numpy rows (no per-message Python).

An hour of the contract at 2 kHz is 36 million messages. Per-message Python (rosbags' or the
``mcap`` library's readers build a record object per message, about 3 us each) costs minutes
per hour of bag; the report's target is 36 s. A finished MCAP file (ours, ``ros2 bag
record``'s) carries in its summary a *chunk index* per chunk and, after each chunk, one
*message index* per channel: the log time and the offset of each of the channel's messages
inside the decompressed chunk (MCAP specification, records ``ChunkIndex`` and
``MessageIndex``). With those, one chunk becomes, per wanted channel, a vector of offsets; the
messages are then gathered with one numpy fancy index into one buffer of the channel's
messages, which :class:`~.columns.CdrColumns` decodes into columns, strings included.

The ``mcap`` library reads the summary (:meth:`mcap.reader.SeekingReader.get_summary`) and
the chunk record (:meth:`mcap.records.Chunk.read`) and decompresses it
(``mcap.stream_reader.get_chunk_data_stream``). Only the two fixed layouts below are parsed here:

* Message record (opcode 0x05): opcode u8, record length u64, channel_id u16, sequence u32,
  log_time u64, publish_time u64, then the data (record length - 22 bytes);
* MessageIndex record (opcode 0x07): opcode u8, record length u64, channel_id u16, then a
  u32 byte length and (log_time u64, offset u64) pairs.

:func:`open_index` returns None when a file cannot be read this way (no summary, no chunk or
message indexes, chunks overlapping in time); the caller then reads it message by message.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import struct
from typing import IO, Iterator

import numpy as np

from .columns import gather

_MESSAGE, _MESSAGE_INDEX = 0x05, 0x07
_MSG_HEADER = 1 + 8 + 2 + 4 + 8 + 8   # opcode .. publish_time: the data starts here
_MSG_FIXED = 2 + 4 + 8 + 8             # record length - data length
_INDEX_ENTRY = np.dtype([('log_time', '<u8'), ('offset', '<u8')])


@dataclass
class ChannelRows:
    """One channel's messages in one chunk, in log-time order, packed into one buffer.

    Message ``i`` is ``data[start[i]:start[i] + size[i]]`` (:class:`~.columns.CdrColumns`
    decodes them all at once).
    """

    log_time_ns: np.ndarray
    data: np.ndarray
    start: np.ndarray
    size: np.ndarray


@dataclass(frozen=True)
class IndexedChannel:
    """A channel of the file: its id, topic and message type."""

    channel_id: int
    topic: str
    msgtype: str


class McapIndex:
    """The chunks of one finished MCAP file, read through their message indexes."""

    def __init__(self, path: Path, stream: IO[bytes], summary: object) -> None:
        self.path = path
        self._f = stream
        schemas = summary.schemas  # type: ignore[attr-defined]
        self.channels = {c.topic: IndexedChannel(cid, c.topic, schemas[c.schema_id].name)
                         for cid, c in summary.channels.items()  # type: ignore[attr-defined]
                         if c.schema_id in schemas}
        self.chunks = sorted(summary.chunk_indexes,  # type: ignore[attr-defined]
                             key=lambda c: (c.message_start_time, c.chunk_start_offset))
        self.bytes_total = sum(c.chunk_length + c.message_index_length for c in self.chunks)
        self.span_ns = ((self.chunks[0].message_start_time,
                         max(c.message_end_time for c in self.chunks)) if self.chunks else None)

    def close(self) -> None:
        """Close the file."""
        self._f.close()

    def read(self, channel_ids: set[int]) -> Iterator[tuple[int, dict[int, ChannelRows]]]:
        """Yield ``(bytes read, {channel id: ChannelRows})`` per chunk holding a wanted channel.

        A chunk holding none of ``channel_ids`` is skipped unread (a sparse topic such as
        ``follow/events`` costs only its own chunks).
        """
        from mcap.data_stream import ReadDataStream
        from mcap.records import Chunk

        for ci in self.chunks:
            wanted = {cid: off for cid, off in ci.message_index_offsets.items()
                      if cid in channel_ids}
            done = ci.chunk_length + ci.message_index_length
            if not wanted:
                yield done, {}
                continue
            self._f.seek(ci.chunk_start_offset)
            raw = self._f.read(ci.chunk_length + ci.message_index_length)
            if len(raw) != ci.chunk_length + ci.message_index_length or raw[0] != 0x06:
                raise ValueError(f'{self.path.name}: chunk at {ci.chunk_start_offset} is '
                                 'truncated or not a chunk')
            stream = ReadDataStream(_Bytes(raw[9:ci.chunk_length]))
            records = _decompress(Chunk.read(stream))
            out = {}
            for cid, off in wanted.items():
                out[cid] = _channel_rows(records, _index_entries(
                    raw, off - ci.chunk_start_offset, cid))
            yield done, out


class _Bytes:
    """The minimal file object ``ReadDataStream`` reads from (no copy of ``bytes``)."""

    def __init__(self, data: bytes) -> None:
        self._view = memoryview(data)
        self._pos = 0

    def read(self, n: int) -> bytes:
        b = self._view[self._pos:self._pos + n].tobytes()
        self._pos += n
        return b


def _decompress(chunk: object) -> bytes:
    """Return the chunk's records, decompressed by the ``mcap`` library (zstd, lz4, none)."""
    from mcap.stream_reader import get_chunk_data_stream

    stream, size = get_chunk_data_stream(chunk)  # type: ignore[arg-type]
    return stream.read(size)


def _index_entries(raw: bytes, pos: int, channel_id: int) -> np.ndarray:
    """Return the (log_time, offset) pairs of the MessageIndex record at ``raw[pos:]``."""
    op, _length, cid, nbytes = struct.unpack_from('<BQHI', raw, pos)
    if op != _MESSAGE_INDEX or cid != channel_id:
        raise ValueError(f'no message index of channel {channel_id} where the chunk index '
                         'points')
    start = pos + 1 + 8 + 2 + 4
    return np.frombuffer(raw, dtype=_INDEX_ENTRY, count=nbytes // 16, offset=start)


def _channel_rows(records: bytes, entries: np.ndarray) -> ChannelRows:
    """Gather one channel's message data from the decompressed chunk ``records``."""
    if entries.size > 1 and np.any(np.diff(entries['log_time'].astype(np.int64)) < 0):
        entries = entries[np.argsort(entries['log_time'], kind='stable')]
    off = entries['offset'].astype(np.int64)
    t = entries['log_time'].astype(np.int64)
    if not off.size:
        return ChannelRows(t, np.zeros(0, np.uint8), off, off)
    if off.max() + _MSG_HEADER > len(records) or np.any(gather(records, 'u1', off) != _MESSAGE):
        raise ValueError('a message index points at no message record')
    size = gather(records, '<u8', off + 1).astype(np.int64) - _MSG_FIXED
    first = off + _MSG_HEADER
    if np.any(size < 0) or np.any(first + size > len(records)):
        raise ValueError('a message record runs past the end of its chunk')
    start = np.zeros(size.size, dtype=np.int64)
    np.cumsum(size[:-1], out=start[1:])
    if size[0] > 0 and np.all(size == size[0]):  # one gather of n rows of the same size
        rows = gather(records, np.dtype((np.void, int(size[0]))), first)
        return ChannelRows(t, rows.view(np.uint8).reshape(-1), start, size)
    # one gather of every byte of the channel's messages: byte j of message i is at first[i] + j
    index = np.arange(int(size.sum()), dtype=np.int64) + np.repeat(first - start, size)
    return ChannelRows(t, np.frombuffer(records, dtype=np.uint8)[index], start, size)


def open_index(path: Path) -> McapIndex | None:
    """Open ``path`` for indexed reading; None when it lacks what that needs (docstring).

    Needed: a summary with a chunk index per chunk, a message index of every channel in
    every chunk, chunks that do not overlap in time, one channel per topic, each with its
    schema.
    """
    from mcap.reader import make_reader

    try:
        f = open(path, 'rb')  # noqa: SIM115 (closed by McapIndex.close or below)
    except OSError:
        return None
    try:
        summary = make_reader(f).get_summary()
    except Exception:  # a damaged file: the message-by-message reader says what is wrong
        summary = None
    ok = summary is not None and bool(summary.chunk_indexes)
    if ok:
        chunks = sorted(summary.chunk_indexes, key=lambda c: c.message_start_time)
        topics = [c.topic for c in summary.channels.values()]
        ok = (all(c.message_index_offsets for c in chunks)
              and len(set(topics)) == len(topics)
              and all(c.schema_id in summary.schemas for c in summary.channels.values())
              # chunks interleaving in time: only a merging reader orders them
              and not any(b.message_start_time < a.message_end_time
                          for a, b in zip(chunks, chunks[1:], strict=False)))
    if not ok:
        f.close()
        return None
    return McapIndex(path, f, summary)
