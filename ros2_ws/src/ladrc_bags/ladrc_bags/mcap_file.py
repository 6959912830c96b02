"""One MCAP storage file of a rosbag2 bag: a streaming writer, and a reader for a killed one.

Writer (:class:`McapFileWriter`): the ``mcap`` library's writer with the layout rosbag2's mcap
plugin writes (profile ``ros2``; schemas ``ros2msg`` with the full message definition; channels
with ``cdr`` encoding and the metadata ``offered_qos_profiles`` and ``topic_type_hash``), chunk
compression ``zstd`` (default), ``lz4`` or none. :meth:`~McapFileWriter.flush` ends the open
chunk and hands it to the operating system, so a SIGKILLed writer leaves every flushed chunk
readable. Memory: the summary's chunk indexes, about 100 bytes per chunk. :meth:`finish` writes
the summary and footer (then ``ros2 bag``, rosbags, Foxglove and PlotJuggler read it directly).

Reader (:class:`McapScan`): a file without its footer (the writer was killed) is read by a
linear scan (:class:`mcap.stream_reader.StreamReader`) up to its last complete record; what
follows, at most the last unflushed chunk, is gone. Complete files are read by rosbags
(bag.py).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Iterable, Iterator

from mcap.exceptions import McapError
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
from rosbags.interfaces import Qos
from rosbags.rosbag2.metadata import dump_qos_v9
import yaml

COMPRESSION = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
               'none': CompressionType.NONE}
LIBRARY = 'ladrc_bags'


def qos_yaml(qos: Iterable[Qos]) -> str:
    """``offered_qos_profiles`` as rosbag2 stores it (a YAML list, metadata version 9)."""
    return yaml.safe_dump(dump_qos_v9(list(qos)), default_flow_style=False,
                          sort_keys=False).strip()


class McapFileWriter:
    """Write one rosbag2 MCAP storage file, flushed chunk by chunk (module docstring)."""

    def __init__(self, path: Path, compression: str = 'zstd',
                 chunk_size: int = 4 * 2**20) -> None:
        if compression not in COMPRESSION:
            raise ValueError(f'unknown compression {compression!r}: use one of '
                             f'{", ".join(COMPRESSION)}')
        self.path = path
        self._file: IO[bytes] = open(path, 'xb')  # noqa: SIM115 (closed in finish)
        self._writer = Writer(self._file, chunk_size=chunk_size,
                              compression=COMPRESSION[compression])
        self._writer.start(profile='ros2', library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seq: Counter[int] = Counter()
        self.counts: Counter[str] = Counter()
        self.start_ns = 2**63 - 1
        self.end_ns = 0

    def add_channel(self, topic: str, msgtype: str, msgdef: str, rihs01: str,
                    qos: Iterable[Qos]) -> None:
        """Register ``topic`` (idempotent)."""
        if topic in self._channels:
            return
        sid = self._schemas.get(msgtype)
        if sid is None:
            sid = self._schemas[msgtype] = self._writer.register_schema(
                msgtype, 'ros2msg', msgdef.encode())
        self._channels[topic] = self._writer.register_channel(
            topic, 'cdr', sid, metadata={'offered_qos_profiles': qos_yaml(qos),
                                         'topic_type_hash': rihs01})
        self.counts[topic] += 0

    def write(self, topic: str, timestamp_ns: int, data: bytes | memoryview) -> None:
        """Write one CDR message of a registered topic at ``timestamp_ns``."""
        cid = self._channels[topic]
        seq = self._seq[cid]
        self._seq[cid] = seq + 1
        self._writer.add_message(cid, log_time=timestamp_ns, data=bytes(data),
                                 publish_time=timestamp_ns, sequence=seq & 0xFFFFFFFF)
        self.counts[topic] += 1
        if timestamp_ns < self.start_ns:
            self.start_ns = timestamp_ns
        if timestamp_ns > self.end_ns:
            self.end_ns = timestamp_ns

    def flush(self) -> None:
        """End the open chunk and hand everything to the OS (no fsync: a killed process)."""
        self._writer.flush()

    def finish(self) -> None:
        """Write the summary and the footer, close the file."""
        self._writer.finish()
        self._file.close()


@dataclass
class _Topic:
    name: str
    msgtype: str
    msgcount: int


class McapScan:
    """Read a storage file whose writer was killed: channels, counts, messages by a scan."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.topics: dict[str, _Topic] = {}
        self.schemas: dict[str, str] = {}  # msgtype -> message definition (ros2msg)
        self.complete_bytes = 0
        counts: Counter[int] = Counter()
        channels: dict[int, Channel] = {}
        types: dict[int, str] = {}
        for record in self._records():
            if isinstance(record, Schema):
                types[record.id] = record.name
                self.schemas[record.name] = record.data.decode(errors='replace')
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                counts[record.channel_id] += 1
        for cid, ch in channels.items():
            self.topics[ch.topic] = _Topic(ch.topic, types.get(ch.schema_id, ''), counts[cid])
        self._ids = {ch.topic: cid for cid, ch in channels.items()}

    def _records(self) -> Iterator[Any]:
        with open(self.path, 'rb') as f:
            reader = StreamReader(f, skip_magic=False, emit_chunks=False)
            try:
                for record in reader.records:
                    yield record
            except (McapError, ValueError, EOFError):
                return  # the tail the killed writer never finished

    def messages(self, topics: Iterable[str]) -> Iterator[tuple[str, int, bytes]]:
        """Yield ``(topic, log time ns, data)`` of ``topics`` in file order."""
        wanted = {self._ids[t]: t for t in topics if t in self._ids}
        for record in self._records():
            if isinstance(record, Message) and record.channel_id in wanted:
                yield wanted[record.channel_id], record.log_time, record.data


def is_complete(path: Path) -> bool:
    """Tell whether the file ends in an MCAP footer and magic (its writer finished it)."""
    try:
        with open(path, 'rb') as f:
            f.seek(-8, 2)
            return f.read(8) == b'\x89MCAP0\r\n'
    except OSError:
        return False
