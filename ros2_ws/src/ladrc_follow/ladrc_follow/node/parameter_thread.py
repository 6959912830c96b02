"""A node's parameter services (``ros2 param``), served from a thread of their own.

rclpy serves a node's parameter services on the executor that spins the node; for the follow
node that is the 2 kHz loop thread. A set's check there (its stability gate, ~10 ms) held the
loop beyond the drive's 5 ms watchdog: one valid ``law.kp`` change while following quick-stopped
the axis (bench/repro/RESULTS.md, "Set a parameter while following").

Here rclpy's own :class:`ParameterService` answers for the node, with the node's parameters and
its ``on_set`` callbacks, but its six services belong to a hidden helper node
(``_<name>_parameters``, same namespace, no global remaps) spun by a ``SingleThreadedExecutor``
in a thread of its own. The services keep the node's names
(``<name>/set_parameters`` ...), so ``ros2 param`` sees no difference. What a callback hands
to the loop must cross threads safely (the follow node: one queue, drained at a tick).

Priority: with a SCHED_FIFO loop the thread runs SCHED_FIFO one below it. Both share the
interpreter lock; a thread at the normal scheduler could be preempted by any busy process while
it holds the lock, and the loop would wait for it (a priority inversion). One below the loop,
only the loop and the middleware preempt it, and the loop takes the lock within the switch
interval. Without a real-time loop it runs at the normal scheduler like the loop.
"""

from __future__ import annotations

import os
import sys
import threading
from typing import Any

import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter_service import ParameterService

SWITCH_INTERVAL_S = 1e-4
"""The interpreter's thread switch interval while the thread runs (default 5 ms): the loop
thread waits at most about this long for the interpreter lock while a set is checked."""


class _Host:
    """What :class:`ParameterService` sees: the node's parameters, the helper's services."""

    def __init__(self, node: Node, server: Node) -> None:
        self._node, self._server = node, server

    def create_service(self, *args: Any, **kwargs: Any):
        return self._server.create_service(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._node, name)


class ParameterThread:
    """Serve ``node``'s parameter services from a normal-priority thread (:meth:`start`).

    ``node`` must be created with ``start_parameter_services=False``.
    """

    def __init__(self, node: Node) -> None:
        self.server = rclpy.create_node(
            f'_{node.get_name()}_parameters', namespace=node.get_namespace(),
            context=node.context, use_global_arguments=False, enable_rosout=False,
            start_parameter_services=False)
        self._host = _Host(node, self.server)  # ParameterService keeps a weak reference
        self._service = ParameterService(self._host)
        self.executor = SingleThreadedExecutor(context=node.context)
        self.executor.add_node(self.server)
        self._priority = 0
        self._thread = threading.Thread(target=self._run, name='parameters', daemon=True)

    def add_timer(self, period_s: float, callback) -> None:
        """Run ``callback`` every ``period_s`` (steady clock) on this thread."""
        self.server.create_timer(period_s, callback,
                                 clock=Clock(clock_type=ClockType.STEADY_TIME))

    def start(self, fifo_priority: int = 0) -> None:
        """Start serving at SCHED_FIFO ``fifo_priority`` (0: the normal scheduler).

        Call after the loop thread's real-time settings: the thread sets its own here.
        """
        self._priority = fifo_priority
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        self._thread.start()

    def _run(self) -> None:
        # a thread inherits its creator's scheduling: set this one's (module docstring)
        try:
            if self._priority > 0:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self._priority))
            else:
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        except (OSError, AttributeError):
            pass  # the creator's scheduling stays: the loop's or the normal one
        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass

    def close(self) -> None:
        """Stop serving and end the thread."""
        self.executor.shutdown(timeout_sec=1.0)
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self.server.destroy_node()
