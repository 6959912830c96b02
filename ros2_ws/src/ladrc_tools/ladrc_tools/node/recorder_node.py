"""Recorder node: every contract topic, raw CDR, into a crash-safe rosbag2 bag.

Subscriptions are ``raw=True`` (rclpy hands over the CDR bytes, byte-identical to what the bag
stores, so nothing is deserialized); the callback only appends ``(topic, bytes, receive time)``
to a deque, and a writer thread writes them with :class:`ladrc_tools.bags.bag.BagWriter` (1 s
segments, see bag.py for the crash-safety design). The node spins an ``EventsExecutor`` with a
``spin_once`` loop: the notes' measurement (SingleThreadedExecutor dropped up to 20-30 % of
2 kHz messages; EventsExecutor received all).

QoS matches the publishers (bag.TOPIC_QOS): BEST_EFFORT keep-last 100 on the 2 kHz topics,
RELIABLE + TRANSIENT_LOCAL on ``follow/events`` (depth 100) and ``run/*`` (depth 1), default on
``/diagnostics``. The same profiles go into the bag as ``offered_qos_profiles``.

Parameters: ``output`` (bag folder; default ``bags/run_<date>_<time>``), ``storage``
(``mcap`` | ``sqlite3``), ``split_s`` (segment length, s). On SIGINT/SIGTERM: drain the queue,
close the bag, print a one-line JSON summary (messages per topic, messages_lost from the seq
counters of the 2 kHz topics) and write it as ``recording.json`` into the bag folder.
"""

from __future__ import annotations

from collections import deque
import json
from pathlib import Path
import signal
import sys
import threading
import time
from typing import Any

from ..bags.bag import (
    SEQ_FIELD,
    TOPIC_QOS,
    TOPIC_TYPES,
    BagError,
    BagWriter,
    count_lost,
    seq_of,
    storage_of,
)

READER_DEPTH = 10000  # 5 s of a 2 kHz topic


def _qos_profile(topic: str) -> Any:
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    q = TOPIC_QOS[topic]
    # The reader's own history must outlast a stall of this process (GIL held by the writer
    # thread while it closes a segment, a loaded machine): keep-last 100 at 2 kHz is only
    # 50 ms. Depth is not part of QoS matching, so a deep reader still matches the publishers.
    depth = max(q.depth, READER_DEPTH) if topic in SEQ_FIELD else q.depth
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth,
        reliability=(ReliabilityPolicy.RELIABLE if q.reliability.name == 'RELIABLE'
                     else ReliabilityPolicy.BEST_EFFORT),
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if q.durability.name == 'TRANSIENT_LOCAL'
                    else DurabilityPolicy.VOLATILE))


def _msg_class(msgtype: str) -> Any:
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
    """Queue + writer thread around a BagWriter (no rclpy: the node feeds :meth:`enqueue`)."""

    def __init__(self, path: str | Path, storage: str = 'mcap', split_s: float = 1.0) -> None:
        self.writer = BagWriter(path, storage=storage_of(storage), split_s=split_s,
                                custom_data={'ladrc.source': 'recorder'})
        for topic in TOPIC_TYPES:
            self.writer.add_topic(topic)
        self.queue: deque[tuple[str, bytes, int]] = deque()
        self.counters = {t: SeqCounter() for t in SEQ_FIELD}
        self._stop = threading.Event()
        self.error: str | None = None
        self._thread = threading.Thread(target=self._run, name='bag-writer', daemon=True)
        self._thread.start()

    def enqueue(self, topic: str, data: bytes) -> None:
        """Queue one received message (called from the subscription callback)."""
        self.queue.append((topic, data, time.time_ns()))

    def _drain(self) -> int:
        q = self.queue
        write = self.writer.write_raw
        counters = self.counters
        done = 0
        while q:
            topic, data, ts = q.popleft()
            c = counters.get(topic)
            if c is not None:
                try:
                    c.add(seq_of(data))
                except Exception:  # a malformed message still goes into the bag
                    pass
            write(topic, ts, data)
            done += 1
        return done

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                if not self._drain():
                    self.writer.poll()
                    time.sleep(0.002)
            self._drain()
        except Exception as exc:  # disk full, ...: stop writing, report at the end
            self.error = f'{type(exc).__name__}: {exc}'

    def close(self) -> dict[str, Any]:
        """Stop the writer thread after draining, close the bag and return the summary."""
        self._stop.set()
        self._thread.join()
        self.writer.close()
        counts = self.writer.counts()
        lost = {t: c.lost for t, c in self.counters.items()}
        summary: dict[str, Any] = {
            'bag': str(self.writer.path), 'storage': self.writer.storage,
            'messages': counts, 'messages_total': sum(counts.values()),
            'messages_lost': sum(lost.values()), 'messages_lost_by_topic': lost,
        }
        if self.error:
            summary['error'] = self.error
        tmp = self.writer.path / 'recording.json.tmp'
        tmp.write_text(json.dumps(summary, indent=1) + '\n', encoding='utf-8')
        tmp.replace(self.writer.path / 'recording.json')
        return summary


def lost_in_bag(bag: Any) -> dict[str, int]:
    """Seq-gap loss per counter topic of an open :class:`ladrc_tools.bags.bag.Bag`."""
    import numpy as np

    out = {}
    for topic in SEQ_FIELD:
        if topic in bag.topics:
            seq = np.fromiter((seq_of(d) for _, d in bag.raw(topic)), dtype=np.int64)
            out[topic] = count_lost(seq)
    return out


def main(args: list[str] | None = None) -> int:
    """Run the recorder node until SIGINT/SIGTERM; print the JSON summary."""
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()

    def on_signal(signum: int, frame: Any) -> None:
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    node = rclpy.create_node('recorder')
    recorder = None
    try:
        output = node.declare_parameter('output', '').value or time.strftime(
            'bags/run_%Y%m%d_%H%M%S')
        storage = node.declare_parameter('storage', 'mcap').value
        split_s = float(node.declare_parameter('split_s', 1.0).value)
        try:
            recorder = Recorder(output, storage, split_s)
        except BagError as exc:
            print(f'recorder: {exc}', file=sys.stderr)
            return 2
        for topic, msgtype in TOPIC_TYPES.items():
            node.create_subscription(
                _msg_class(msgtype), topic,
                lambda data, t=topic: recorder.enqueue(t, data),
                _qos_profile(topic), raw=True)
        executor = EventsExecutor()
        executor.add_node(node)
        node.get_logger().info(f'recording to {output} ({storage})')
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)
        executor.shutdown()
    finally:
        if recorder is not None:
            summary = recorder.close()
            print(json.dumps(summary), flush=True)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
