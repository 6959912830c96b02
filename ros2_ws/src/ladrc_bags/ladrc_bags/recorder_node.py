"""Recorder node: every contract topic, raw CDR, into a crash-safe rosbag2 bag.

The readers are loop readers (:mod:`ladrc_contract.loop_io`): the main thread takes the raw CDR
bytes (byte-identical to what the bag stores, so nothing is deserialized) from every reader
every ``poll_s`` (5 ms), all that waits, in order of reception, and appends
``(topic, bytes, receive time)`` to a bounded deque; a writer thread writes them with
:class:`ladrc_bags.BagWriter` (one streaming MCAP file flushed every ``flush_s``, see
bag.py for the crash-safety design). A full queue drops the new message and counts it per
topic (summary and /diagnostics). No executor handles the 2 kHz topics: a callback per message
(12 000 a second with the whole contract) cost the recorder most of a core on this machine
class; taking them in batches costs a few microseconds each, and the readers' history (5 s)
outlasts any pause. The receive time is the middleware's reception stamp of each message.

QoS matches the publishers (``ladrc_contract.qos.TOPIC_QOS``): BEST_EFFORT on the 2 kHz topics,
RELIABLE + TRANSIENT_LOCAL on ``follow/events`` (depth 100) and ``run/*`` (depth 1), default on
``/diagnostics``. The same profiles go into the bag as ``offered_qos_profiles``.

Parameters: ``output`` (bag folder; default ``bags/run_<date>_<time>``), ``storage``
(``mcap`` | ``sqlite3``), ``split_s`` (a new storage file every that many seconds, 0 = one per
run; sqlite3 needs it for crash safety and uses 1 s when 0), ``flush_s`` (mcap: chunk flush
period, the most a kill loses besides the queue), ``compression`` (mcap chunks: ``zstd`` |
``lz4`` | ``none``), ``queue_max`` (messages), ``stop_grace_s`` (keeps recording this long
after SIGINT/SIGTERM, for the other nodes' last messages when all are interrupted at once),
``topics`` (the contract topics to record; empty = all; bench/loop_timing.py records two),
``poll_s`` (how often the readers are emptied), ``machine_id`` (the bag's
``ladrc.machine_id``: bring-up passes the follow node's ``hardware_id``; with the wall-clock
start, the software version and the hash of the first ``run/parameters``, bags/provenance.py),
``reliable`` (subscribe the 2 kHz topics RELIABLE: lock step, whose writers are reliable, so a
recorder that falls behind is repaired rather than losing messages; docs/follow-node.md).
Topics are stored under their fully qualified names (the node's namespace applies).
/diagnostics once a second: queue length, messages written, dropped per topic. On
SIGINT/SIGTERM: drain the queue, close the bag, print a one-line JSON summary (messages per
topic, messages_lost from the seq counters of the 2 kHz topics, messages_dropped by the full
queue) and write it as ``recording.json`` into the bag folder.
"""

from __future__ import annotations

from collections import deque
import json
from pathlib import Path
import struct
import sys
import threading
import time
from typing import Any

from ladrc_contract import qos
from ladrc_contract.node_entry import NodeRun, StartError, run_node
from ladrc_contract.qos import TOPIC_QOS, to_rclpy
from ladrc_contract.topics import PARAMETERS_TOPIC, SEQ_FIELD, TOPIC_TYPES

from ladrc_bags import BagError, BagWriter, seq_of, storage_of
from ladrc_bags.provenance import PARAMS_KEY, param_hash, provenance_data


def string_of_cdr(data: bytes) -> str:
    """Return the ``data`` of a serialized std_msgs/String ('' when it is not one)."""
    if len(data) < 8:
        return ''
    order = '<' if data[1] & 1 else '>'  # the encapsulation: CDR_LE / CDR_BE
    (n,) = struct.unpack_from(order + 'I', data, 4)
    raw = data[8:8 + n]
    return raw[:-1].decode('utf-8', 'replace') if len(raw) == n and n else ''


def _qos_profile(topic: str, reliable: bool = False) -> Any:
    """Return the reader of ``topic``: the publishers' profile, deeper on the 2 kHz topics.

    The reader's history must outlast the time between two takes and a stall of this process
    (the bag writer's thread holding the GIL while it closes a segment, a loaded machine):
    5 s (``RECORDER_READER``); lock step (``reliable``): the writers' 10 s. Depth is not part
    of QoS matching, so a deep reader still matches the publishers.
    """
    if topic not in SEQ_FIELD:
        return to_rclpy(TOPIC_QOS[topic])
    return to_rclpy(qos.LOCKSTEP_HIGH_RATE if reliable else qos.RECORDER_READER)


def msg_class(msgtype: str) -> Any:
    """Return the rclpy message class of ``msgtype`` ('pkg/msg/Name')."""
    import importlib

    pkg, _, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{pkg}.msg'), name)


class SeqCounter:
    """Received count and seq-gap loss of one counter topic, updated per message."""

    def __init__(self) -> None:
        self.last: int | None = None
        self.lost = 0

    def add(self, seq: int) -> None:
        """Account for one received ``seq``."""
        if self.last is not None and seq > self.last + 1:
            self.lost += seq - self.last - 1
        self.last = seq


class Recorder:
    """Queue + writer thread around a BagWriter (no rclpy: the node feeds :meth:`enqueue`).

    ``topics`` maps each contract topic (``TOPIC_TYPES`` key) to the name it is stored under
    (default: fully qualified, ``/axis/feedback``).
    """

    def __init__(self, path: str | Path, storage: str = 'mcap', split_s: float = 0.0,
                 flush_s: float = 0.25, compression: str = 'zstd', queue_max: int = 200_000,
                 topics: dict[str, str] | None = None, machine_id: str = '') -> None:
        if storage_of(storage) == 'sqlite3' and not split_s > 0:
            split_s = 1.0  # rosbags' sqlite3 commits on close only: complete 1 s files
        if not (isinstance(queue_max, int) and queue_max >= 1):
            raise BagError(f'queue_max must be an integer >= 1, got {queue_max!r}')
        self.writer = BagWriter(path, storage=storage, split_s=split_s if split_s > 0 else None,
                                flush_s=flush_s, compression=compression,
                                custom_data={'ladrc.source': 'recorder',
                                             **provenance_data(machine_id)})
        self._params_hashed = False  # ladrc.param_hash: from the first run/parameters
        self.names = topics or {t: '/' + t.lstrip('/') for t in TOPIC_TYPES}
        for topic, name in self.names.items():
            self.writer.add_topic(name, TOPIC_TYPES[topic])
        self.queue: deque[tuple[str, bytes, int]] = deque()
        self.queue_max = queue_max
        self.dropped = {t: 0 for t in TOPIC_TYPES}
        self.counters = {t: SeqCounter() for t in SEQ_FIELD}
        self._stop = threading.Event()
        self.error: str | None = None
        self._thread = threading.Thread(target=self._run, name='bag-writer', daemon=True)
        self._thread.start()

    def enqueue(self, topic: str, data: bytes, stamp_ns: int | None = None) -> None:
        """Queue one received message (called from the subscription callback).

        A full queue (the writer fell ``queue_max`` messages behind) drops the message and
        counts it: memory stays bounded whatever the disk does.
        """
        if len(self.queue) >= self.queue_max:
            self.dropped[topic] += 1
            return
        self.queue.append((topic, data, time.time_ns() if stamp_ns is None else stamp_ns))

    def _drain(self) -> int:
        q = self.queue
        write = self.writer.write_raw
        counters = self.counters
        names = self.names
        done = 0
        while q:
            topic, data, ts = q.popleft()
            if topic == PARAMETERS_TOPIC and not self._params_hashed:
                self._params_hashed = True
                text = string_of_cdr(data)
                if text:
                    self.writer.custom_data[PARAMS_KEY] = param_hash(text)
            c = counters.get(topic)
            if c is not None:
                try:
                    c.add(seq_of(data))
                except Exception:  # a malformed message still goes into the bag
                    pass
            write(names[topic], ts, data)
            done += 1
        return done

    def _run(self) -> None:
        # every storage call happens on this thread (sqlite3 connections are bound to the
        # thread that opened them), the final close included
        try:
            while not self._stop.is_set():
                if not self._drain():
                    self.writer.poll()
                    time.sleep(0.002)
            self._drain()
        except Exception as exc:  # disk full, ...: stop writing, report at the end
            self.error = f'{type(exc).__name__}: {exc}'
        try:
            self.writer.close()
        except Exception as exc:
            self.error = self.error or f'{type(exc).__name__}: {exc}'

    def close(self) -> dict[str, Any]:
        """Stop the writer thread after draining (it closes the bag); return the summary."""
        self._stop.set()
        self._thread.join()
        counts = self.writer.counts()
        lost = {t: c.lost for t, c in self.counters.items()}
        summary: dict[str, Any] = {
            'bag': str(self.writer.path), 'storage': self.writer.storage,
            'messages': counts, 'messages_total': sum(counts.values()),
            'messages_lost': sum(lost.values()), 'messages_lost_by_topic': lost,
            'messages_dropped': sum(self.dropped.values()),
            'messages_dropped_by_topic': dict(self.dropped),
        }
        if self.error:
            summary['error'] = self.error
        tmp = self.writer.path / 'recording.json.tmp'
        tmp.write_text(json.dumps(summary, indent=1) + '\n', encoding='utf-8')
        tmp.replace(self.writer.path / 'recording.json')
        return summary


class _Diagnostics:
    """Once a second on /diagnostics: the writer's queue, messages written, drops per topic."""

    def __init__(self, node: Any, recorder: Recorder) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        self.node, self.recorder = node, recorder
        self.pub = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.name = f'{node.get_fully_qualified_name().lstrip("/")}: bag writer'

    def publish(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        r = self.recorder
        dropped = sum(r.dropped.values())
        level = DiagnosticStatus.OK if not (dropped or r.error) else (
            DiagnosticStatus.ERROR if r.error else DiagnosticStatus.WARN)
        values = [KeyValue(key='queue', value=str(len(r.queue))),
                  KeyValue(key='queue_max', value=str(r.queue_max)),
                  KeyValue(key='messages_written',
                           value=str(sum(r.writer.counts().values()))),
                  KeyValue(key='messages_dropped', value=str(dropped))]
        values += [KeyValue(key=f'dropped {t}', value=str(n)) for t, n in r.dropped.items()]
        msg = DiagnosticArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.status = [DiagnosticStatus(
            level=level, name=self.name, hardware_id=str(r.writer.path),
            message=r.error or ('queue full: messages dropped' if dropped else 'recording'),
            values=values)]
        self.pub.publish(msg)


def take_batch(readers: dict[str, Any]) -> list[tuple[int, str, bytes]]:
    """Every message waiting in ``readers`` (topic -> LoopReader), in order of reception."""
    batch = [(stamp, topic, data) for topic, reader in readers.items()
             for data, stamp in reader.take_all()]
    batch.sort(key=lambda item: item[0])
    return batch


def _make_node():
    from ladrc_contract.loop_io import LoopNode

    return LoopNode('recorder')


def _close(recorder: Recorder) -> None:
    print(json.dumps(recorder.close()), flush=True)


def _run(node, node_run: NodeRun) -> int:
    """Record the contract's topics until a stop is requested, then a grace; 0."""
    from ladrc_contract.service_thread import ServiceThread

    output = node.declare_parameter('output', '').value or time.strftime(
        'bags/run_%Y%m%d_%H%M%S')
    storage = node.declare_parameter('storage', 'mcap').value
    split_s = float(node.declare_parameter('split_s', 0.0).value)
    flush_s = float(node.declare_parameter('flush_s', 0.25).value)
    compression = node.declare_parameter('compression', 'zstd').value
    queue_max = int(node.declare_parameter('queue_max', 200_000).value)
    grace_s = float(node.declare_parameter('stop_grace_s', 0.5).value)
    machine_id = str(node.declare_parameter('machine_id', '').value)
    reliable = bool(node.declare_parameter('reliable', False).value)
    poll_s = float(node.declare_parameter('poll_s', 0.005).value)
    only = [t.strip('/') for t in node.declare_parameter('topics', ['']).value if t]
    unknown = sorted(set(only) - {t.strip('/') for t in TOPIC_TYPES})
    if unknown:
        raise StartError(f'not contract topics: {", ".join(unknown)}')
    wanted = {t: m for t, m in TOPIC_TYPES.items() if not only or t.strip('/') in only}
    # bag time = receive time on the node clock, as ros2 bag: the middleware's reception
    # stamp (system clock), or the node clock at the take with use_sim_time
    sim_clock = node.get_clock() if node.get_parameter('use_sim_time').value else None
    readers = {topic: node.create_loop_reader(msg_class(msgtype), topic,
                                              _qos_profile(topic, reliable))
               for topic, msgtype in wanted.items()}
    try:
        recorder = Recorder(output, storage, split_s, flush_s, compression, queue_max,
                            topics={t: r.topic_name for t, r in readers.items()},
                            machine_id=machine_id)
    except (BagError, ValueError, TypeError) as exc:
        raise StartError(str(exc)) from None
    node_run.defer(_close, recorder)
    diag = _Diagnostics(node, recorder)
    node.create_timer(1.0, diag.publish)
    services = ServiceThread(node.context, (node,))  # /diagnostics, parameters
    node_run.defer(services.close)
    services.start()
    node.get_logger().info(f'recording to {output} ({storage})')

    def record_until(done) -> None:
        while True:  # a last take once done
            finished = done()
            batch = take_batch(readers)
            now = sim_clock.now().nanoseconds if sim_clock is not None else None
            for stamp, topic, data in batch:
                recorder.enqueue(topic, data, stamp if now is None else now)
            if finished:
                return
            time.sleep(poll_s)

    record_until(lambda: node_run.stop_requested)
    # interrupted together with the other nodes (launch's Ctrl-C): keep recording a moment,
    # so the controller's zero command on its way down is in the bag
    end = time.monotonic() + max(0.0, grace_s)
    record_until(lambda: time.monotonic() >= end)
    return 0


def main(args: list[str] | None = None) -> int:
    """Run the recorder node until SIGINT/SIGTERM; print the JSON summary.

    The recorder commands nothing: it has no zero hook; its bag is closed after the stop.
    """
    return run_node('recorder', _make_node, _run, args=args)


if __name__ == '__main__':
    sys.exit(main())
