"""A loop node's everything-but-the-loop: its services, clients and timers, on a thread of its own.

The loop thread of a 2 kHz node takes its samples straight from its readers
(:mod:`.loop_io`) and never spins an executor. What else the node offers (follow commands,
``axis/reset_drive``, parameter services, the scenario's service calls, /diagnostics and other
timers) is served here, by a ``SingleThreadedExecutor`` in a thread of its own, which does not
see the loop readers (:class:`~ladrc_contract.loop_io.LoopNode`). What a callback hands to the
loop crosses threads under the node's own lock or through a queue.

Priority: with a SCHED_FIFO loop this thread runs SCHED_FIFO one below it. Both share the
interpreter lock; a thread at the normal scheduler could be preempted by any busy process while
it holds the lock, and the loop would wait for it (a priority inversion). One below the loop,
only the loop and the middleware preempt it, and the loop takes the interpreter lock within the
switch interval (:data:`SWITCH_INTERVAL_S`). Without a real-time loop it runs at the normal
scheduler like the loop.
"""

from __future__ import annotations

import sys
import threading
from typing import Any

from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

from .realtime import schedule_this_thread

SWITCH_INTERVAL_S = 1e-4
"""The interpreter's thread switch interval while the thread runs (default 5 ms): the loop
thread waits at most about this long for the interpreter lock while a callback runs here."""


class ServiceThread:
    """Spin ``nodes`` in a thread of their own (:meth:`start`, :meth:`close`)."""

    def __init__(self, context: Any, nodes: tuple = (), name: str = 'services') -> None:
        self.executor = SingleThreadedExecutor(context=context)
        for node in nodes:
            self.executor.add_node(node)
        self._priority = 0
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def add_node(self, node: Any) -> None:
        """Serve ``node`` too (before :meth:`start`)."""
        self.executor.add_node(node)

    def start(self, fifo_priority: int = 0) -> None:
        """Start serving at SCHED_FIFO ``fifo_priority`` (0: the normal scheduler).

        Call after the loop thread's real-time settings: the thread sets its own here.
        """
        self._priority = fifo_priority
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        self._thread.start()

    def _run(self) -> None:
        # a thread inherits its creator's scheduling: set this one's (module docstring); if
        # refused, the creator's scheduling stays (the loop's or the normal one)
        schedule_this_thread(self._priority)
        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass

    def close(self) -> None:
        """Stop serving and end the thread."""
        self.executor.shutdown(timeout_sec=1.0)
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
