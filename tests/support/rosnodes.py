"""Start the project's nodes as real processes and watch topics from the test process.

The environment (ROS_DOMAIN_ID, localhost discovery) comes from tests/ros/conftest.py; every
process started here is killed at teardown by :class:`NodeProcesses`.
"""

from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import tempfile
import time
from typing import Callable

from ladrc_tools.bringup.bringup import executable_path, interrupt_process
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message

# The contract's 2 kHz topics are best effort (docs/interfaces.md): a test reader matches that,
# with a deep history so a slow test process drops nothing it could have had.
READER = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                    reliability=ReliabilityPolicy.BEST_EFFORT,
                    durability=DurabilityPolicy.VOLATILE)
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


class NodeProcesses:
    """Processes of one test; ``close()`` ends every one of them."""

    def __init__(self) -> None:
        self.procs: dict[str, subprocess.Popen] = {}
        self.logdir = Path(tempfile.mkdtemp(prefix='ladrc-nodes-'))

    def start(self, name: str, package: str, executable: str, *ros_args: str) -> subprocess.Popen:
        cmd = [executable_path(package, executable), '--ros-args', *ros_args]
        log = open(self.logdir / f'{name}.log', 'wb')  # noqa: SIM115
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=dict(os.environ),
                                start_new_session=True)
        log.close()
        self.procs[name] = proc
        return proc

    def log(self, name: str) -> str:
        return (self.logdir / f'{name}.log').read_text(errors='replace')

    def interrupt(self, name: str, timeout_s: float = 10.0) -> int:
        return interrupt_process(self.procs[name], timeout_s)

    def kill(self, name: str) -> None:
        proc = self.procs[name]
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()

    def close(self) -> None:
        for name in list(self.procs):
            self.kill(name)


class RawLog:
    """Messages received raw (no deserialization on the receive path), decoded on access.

    A Python subscriber that deserializes three 2 kHz topics needs a core of its own; on a
    2-core machine that starves the very nodes under test. Raw bytes cost little; the test
    decodes only what it looks at.
    """

    def __init__(self, msg_type, keep: Callable | None) -> None:
        self.msg_type = msg_type
        self.keep = keep
        self.raw: list[bytes] = []
        self._cache: dict[int, object] = {}

    def append(self, data: bytes) -> None:
        self.raw.append(data)

    def __len__(self) -> int:
        return len(self.raw)

    def _decode(self, i: int):
        if i < 0:
            i += len(self.raw)
        if i not in self._cache:
            msg = deserialize_message(self.raw[i], self.msg_type)
            self._cache[i] = msg if self.keep is None else self.keep(msg)
        return self._cache[i]

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self._decode(i) for i in range(*index.indices(len(self.raw)))]
        return self._decode(index)

    def __iter__(self):
        return (self._decode(i) for i in range(len(self.raw)))


class Probe:
    """A test-side rclpy node that records topics and calls services.

    Topics are taken straight from each subscription's reader (raw bytes, a deep history) by
    polling, with no executor: a Python executor cannot keep up with three 2 kHz topics on a
    2-core machine (../shared/notes), and the EventsExecutor that can is experimental and was
    seen to crash the test process when the node processes it matched were killed (rclpy issue
    1644). Service calls go through a second node on a SingleThreadedExecutor (a few messages).
    """

    def __init__(self, context, name: str = 'probe') -> None:
        self.node = rclpy.create_node(name, context=context)
        self._service_node = rclpy.create_node(f'{name}_services', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self._service_node)
        self.messages: dict[str, list] = {}
        self._readers: list[tuple[object, RawLog]] = []
        self._clients: dict[str, object] = {}

    def record(self, msg_type, topic: str, qos: QoSProfile = READER,
               keep: Callable | None = None) -> RawLog:
        """Collect every message of ``topic`` (decoded to ``keep(msg)`` on access)."""
        store = RawLog(msg_type, keep)
        self.messages[topic] = store
        sub = self.node.create_subscription(msg_type, topic, store.append, qos, raw=True)
        self._readers.append((sub, store))
        return store

    def subscribe(self, msg_type, topic: str, callback: Callable, qos=10) -> None:
        """Subscribe with a decoded callback, for low-rate topics (diagnostics, events)."""
        self._service_node.create_subscription(msg_type, topic, callback, qos)

    def poll(self) -> None:
        """Move every message waiting in the subscriptions' histories into their logs."""
        for sub, store in self._readers:
            with sub.handle:
                while (taken := sub.handle.take_message(sub.msg_type, True)) is not None:
                    store.append(taken[0])

    def spin_until(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.poll()
            if condition():
                return True
            self.executor.spin_once(timeout_sec=min(0.01, max(0.0, deadline - time.monotonic())))
        self.poll()
        return condition()

    def spin_for(self, seconds: float) -> None:
        self.spin_until(lambda: False, seconds)

    def call(self, srv_type, name: str, request, timeout_s: float = 10.0):
        client = self._clients.get(name)
        if client is None:
            client = self._service_node.create_client(srv_type, name)
            assert self.spin_until(client.service_is_ready, timeout_s), f'{name} not available'
            # "ready" means the server's request reader is matched; the server may not have
            # matched this client's response reader yet, and a response sent before that is
            # lost (a known race of new clients): give discovery a moment, once per client
            self.spin_for(0.3)
            self._clients[name] = client
        future = client.call_async(request)
        assert self.spin_until(future.done, timeout_s), f'{name} did not answer'
        return future.result()

    def close(self) -> None:
        self.executor.shutdown()
        self._service_node.destroy_node()
        self.node.destroy_node()
