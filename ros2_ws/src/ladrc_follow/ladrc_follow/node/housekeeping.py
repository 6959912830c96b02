"""The follow node's housekeeping thread: follow commands, parameters, /diagnostics, topology.

The loop thread only takes samples, ticks and publishes (``node/loops.py``). Everything else is
served here by :class:`ladrc_contract.service_thread.ServiceThread`: the node's follow services
and its timers (diagnostics, the topology check), and ``ros2 param``.

Parameters: rclpy serves a node's parameter services on the executor that spins the node; a
set's check (its stability gate, ~10 ms) on the loop held it beyond the drive's 5 ms watchdog
(docs/safety.md, "Stalls"). Here rclpy's own
:class:`ParameterService` answers for the node, with the node's parameters and its ``on_set``
callbacks, but its six services belong to a hidden helper node (``_<name>_parameters``, same
namespace, no global remaps), so they keep the node's names (``<name>/set_parameters`` ...) and
``ros2 param`` sees no difference. What a callback hands to the loop crosses threads under the
node's lock or through its queue (follow_node.py).
"""

from __future__ import annotations

from typing import Any

from ladrc_contract.service_thread import ServiceThread
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter_service import ParameterService


class _Host:
    """What :class:`ParameterService` sees: the node's parameters, the helper's services."""

    def __init__(self, node: Node, server: Node) -> None:
        self._node, self._server = node, server

    def create_service(self, *args: Any, **kwargs: Any):
        return self._server.create_service(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._node, name)


class Housekeeping(ServiceThread):
    """Serve ``node`` (its services and timers) and its parameter services (:meth:`start`).

    ``node`` must be created with ``start_parameter_services=False``.
    """

    def __init__(self, node: Node) -> None:
        self.server = rclpy.create_node(
            f'_{node.get_name()}_parameters', namespace=node.get_namespace(),
            context=node.context, use_global_arguments=False, enable_rosout=False,
            start_parameter_services=False)
        self._host = _Host(node, self.server)  # ParameterService keeps a weak reference
        self._service = ParameterService(self._host)
        super().__init__(node.context, (node, self.server), name='housekeeping')

    def add_timer(self, period_s: float, callback) -> None:
        """Run ``callback`` every ``period_s`` (steady clock) on this thread."""
        self.server.create_timer(period_s, callback,
                                 clock=Clock(clock_type=ClockType.STEADY_TIME))

    def close(self) -> None:
        """Stop serving, end the thread, destroy the helper node."""
        super().close()
        self.server.destroy_node()
