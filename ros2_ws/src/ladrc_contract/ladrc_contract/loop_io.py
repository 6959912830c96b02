"""A 2 kHz loop's inputs: readers its own thread takes from straight, and the wait for a sample.

A loop node (the follow node, the sim node, the recorder) keeps its high-rate readers out of
every executor: no callback, no rclpy message object, no executor wake-up per sample. Its loop
thread takes the raw CDR bytes from the reader when it wants them (at its deadline, or when
:class:`SampleWait` says a sample has come) and parses them with
:meth:`ladrc_contract.cdr.CdrPacker.unpack`. Everything else of the node (services, clients,
parameters, timers) is served by an executor on another thread, which does not see these
readers (:class:`LoopNode`).

Why (docs/follow-node.md, "The loop"): on a VM a wake-up costs tens of
microseconds, and an executor wakes its thread once per incoming message and builds a Python
message field by field; the follow node's loop thread spent most of a core in the executor and
the sim's likewise, so the two 2 kHz processes plus a recorder filled both cores and a SCHED_FIFO
thread then ran into the kernel's real-time throttling (stalls of up to 50 ms). rclpy's own
``wait_for_message`` takes from a subscription the same way (``_rclpy.WaitSet``,
``handle.take_message``).

Reception time: the middleware's ``received_timestamp`` of each message (system clock, taken
when the sample arrived, not when the loop took it), so a loop that takes late does not blame
the sender for its own delay.
"""

from __future__ import annotations

import time
from typing import Any, Iterable

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node


def _never_called(_msg: Any) -> None:  # pragma: no cover - no executor spins a loop reader
    raise AssertionError('a loop reader was spun by an executor')


class LoopNode(Node):
    """A node whose loop readers (:meth:`create_loop_reader`) no executor sees.

    Executors collect a node's subscriptions and waitables from its ``subscriptions`` and
    ``waitables`` properties; these leave the loop readers and their QoS event handlers out, so
    the node can be spun for its services and timers by a thread of its own while the loop
    thread takes the samples. (A keep-last-1 reader that is taken from once per period reports
    a "message lost" event for each sample superseded in between: an executor that saw those
    handlers woke thousands of times a second.) The readers stay the node's (the graph shows
    them under its name; ``destroy_node`` destroys them).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._loop_subscriptions: set = set()
        self._loop_handlers: set = set()
        super().__init__(*args, **kwargs)

    @property
    def subscriptions(self):
        """The node's subscriptions that an executor serves (the loop readers left out)."""
        hidden = self._loop_subscriptions
        return (s for s in Node.subscriptions.fget(self) if s not in hidden)

    @property
    def waitables(self):
        """The node's waitables that an executor serves (the loop readers' events left out)."""
        hidden = self._loop_handlers
        return (w for w in Node.waitables.fget(self) if w not in hidden)

    def create_loop_reader(self, msg_type: Any, topic: str, qos: Any) -> LoopReader:
        """Return a reader of ``topic`` for the loop thread (raw, no callback, no executor)."""
        sub = self.create_subscription(msg_type, topic, _never_called, qos, raw=True)
        self._loop_subscriptions.add(sub)
        self._loop_handlers.update(sub.event_handlers)
        return LoopReader(sub)


class LoopReader:
    """One topic's reader: the loop thread takes the raw messages (see the module docstring)."""

    def __init__(self, subscription: Any) -> None:
        self.subscription = subscription
        self.handle = subscription.handle
        self.msg_type = subscription.msg_type
        self.topic_name: str = subscription.topic_name

    def take(self) -> tuple[bytes, int] | None:
        """Return the oldest waiting message ``(cdr, received_ns)``, or None when none waits."""
        with self.handle:
            taken = self.handle.take_message(self.msg_type, True)
        if taken is None:
            return None
        data, info = taken
        return data, int(info['received_timestamp'])

    def take_all(self, limit: int = 1 << 30) -> list[tuple[bytes, int]]:
        """Return every waiting message (at most ``limit``), oldest first."""
        out: list[tuple[bytes, int]] = []
        handle, msg_type = self.handle, self.msg_type
        with handle:
            while len(out) < limit:
                taken = handle.take_message(msg_type, True)
                if taken is None:
                    break
                out.append((taken[0], int(taken[1]['received_timestamp'])))
        return out


class SampleWait:
    """Block the calling thread until one of ``readers`` has a message or ``timeout_ns`` passed.

    The rcl wait set of an executor, without the executor: built once, refilled per wait.
    """

    def __init__(self, context: Any, readers: Iterable[LoopReader]) -> None:
        self.handles = [r.handle for r in readers]
        self._ws = _rclpy.WaitSet(len(self.handles), 0, 0, 0, 0, 0, context.handle)

    def wait(self, timeout_ns: int) -> None:
        """Wait (``timeout_ns`` < 0: without a limit); return early on the first message.

        With no reader at all, a plain sleep of ``timeout_ns`` (rcl refuses an empty wait set).
        """
        if not self.handles:
            time.sleep(max(0, timeout_ns) * 1e-9 if timeout_ns >= 0 else 0.05)
            return
        ws = self._ws
        ws.clear_entities()
        entered = []
        try:
            for h in self.handles:
                h.__enter__()
                entered.append(h)
                ws.add_subscription(h)
            ws.wait(timeout_ns)
        finally:
            for h in reversed(entered):
                h.__exit__(None, None, None)
