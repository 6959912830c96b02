"""Writing a bag: the crash-safe rosbag2 writer of the recorder and the tools (no rclpy).

Storage ``mcap`` (the default, as ``ros2 bag record``): one MCAP file per run (or per
``split_s`` seconds), written as a stream by :mod:`.mcap_file` with chunk compression (zstd by
default) and flushed every ``flush_s`` seconds, so a SIGKILLed writer loses at most the last
``flush_s`` plus the writer's queue. ``metadata.yaml`` lists the file from the first moment and
is rewritten (constant size) every ``metadata_s`` and on close; a file its writer never
finished is read by a scan (:mod:`.recovery`). Topic names are fully qualified
(``/axis/capacitive_height``), as ``ros2 bag record`` writes them; channels carry
``offered_qos_profiles`` and ``topic_type_hash`` as rosbag2's mcap plugin writes them.

Storage ``sqlite3``: rosbags' sqlite3 writer commits only on close, so the bag is split into
short *complete* files (``split_s``, as ``ros2 bag record --max-bag-duration``), each written
in a hidden folder and moved next to ``metadata.yaml`` when complete.

No fsync: the threat is a killed process, not a lost page cache. Messages come as raw CDR
bytes (the recorder writes what rclpy received, byte-identical to ``serialize_cdr``) or as
rosbags messages.
"""

from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
import shutil
import time
from typing import Any, Mapping, Sequence

from ladrc_contract import qos as contract_qos
from ladrc_contract.qos import TOPIC_QOS
from ladrc_contract.topics import TOPIC_TYPES
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

from .errors import BagError
from .mcap_file import McapFileWriter
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


def string_msg(text: str, typestore: Any = None) -> Any:
    """Return a rosbags std_msgs/String."""
    store = typestore or ladrc_typestore()
    return store.types['std_msgs/msg/String'](data=text)


def storage_of(name: str) -> str:
    """Validate a storage name (``mcap`` or ``sqlite3``)."""
    if name not in STORAGES:
        raise BagError(f'unknown storage {name!r}: use one of {", ".join(STORAGES)}')
    return name
