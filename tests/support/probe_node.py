"""The test probe as a process of its own: records topics, calls services, publishes.

Started by :class:`rosnodes.Probe` as the nodes are (``start_new_session``, the test's
environment: ROS_DOMAIN_ID and localhost discovery from tests/ros/conftest.py), so rclpy runs
outside pytest, as launch_testing runs it: a crash in rclpy ends this process, and the test
reports its exit code and output instead of dying with it.

Why a process (the segmentation fault in ``destroy_node`` that could end a pytest run): a race
in Fast DDS 2.14's shared-memory transport, not in the project's use of rclpy and not
ros2/rclpy#1644 (no EventsExecutor involved). A publisher SIGKILLed while it
holds a subscriber's shared-memory port lock leaves the lock held; about a second later Fast
DDS replaces the port and frees the old segment, and a participant torn down in that window
(the last ``destroy_node`` of a context) waits on a mutex in the freed segment and crashes.
Minimal reproduction without project code (one node, three raw subscriptions, a flooding
publisher SIGKILLed, ``destroy_node`` 0.2 s later): 12 crashes in 450 runs, 0 in 150 with
SIGINT instead, 0 in 100 with the teardown 3 s later; the code path is the same in Fast DDS
2.14.6. So the tests end processes with SIGINT first (``NodeProcesses.close``), wait 3 s after
a deliberate SIGKILL before the probe's teardown, and a crash that still happens is this
process' crash, reported with its signal and stack, never pytest's.

Protocol: JSON lines. Each line on stdin is one command ``{"id": n, "op": ..., ...}``; each
command gets exactly one line on stdout, ``{"id": n, "ok": true, "result": ...}`` or
``{"id": n, "ok": false, "error": ..., "kind": ...}`` (an exception while handling a command is
an error reply, never a crash). The first line, before any command, is ``{"ready": pid}``.
Floats are encoded as Python's json writes them (NaN, Infinity, -Infinity), which json reads
back: a NaN in a message survives the trip. Operations:

``record``  ``type`` ('pkg/msg/Name'), ``topic``, ``qos``, ``fields`` -> log number. Messages
            are kept raw (serialized bytes, taken from the subscription's reader by polling, no
            executor) and decoded only when fetched: a Python subscriber that deserializes three
            2 kHz topics takes a core of a 2-core machine from the nodes under test.
``poll``    take what waits in every reader -> the number of messages of each log.
``fetch``   ``log``, ``start``, ``stop`` -> the rows ``start:stop`` of a log, each row the value
            of ``fields`` (one dotted path: its value; a list of paths: a list of values; none:
            the whole message), messages as dicts of their fields.
``call``    ``type`` ('pkg/srv/Name'), ``name``, ``request`` (a dict of fields), ``timeout_s``
            -> the response as a dict. A new client waits for the service, then gives
            discovery 0.3 s once (a response sent before the server matched the client's
            response reader is lost).
``get_parameters`` ``node``, ``names`` -> the ParameterValue dicts (rcl_interfaces services).
``set_parameters`` ``node``, ``parameters`` ({name: value}; the type follows the value, or a
            ParameterValue dict) -> the SetParametersResult dicts (successful, reason).
``publish`` ``type``, ``topic``, ``qos``, ``fields``, ``count`` (1), ``period_s`` (0),
            ``increment`` (integer fields raised by one per message) -> number published.
``quit``    destroy every entity and node, shut the context down, reply, exit 0.

QoS names: 'reader' (best effort, keep last 1000: the contract's 2 kHz topics), 'latched'
(reliable, transient local, keep last 100), 'reliable' (reliable, volatile, keep last 20 000:
lock step's writers keep 10 s, and so must the probe's reader, which only the probe's own
takes empty: a depth of 1 000 loses messages when the probe stalls a second), or an integer
depth (reliable, volatile, keep last n, as rclpy reads an integer).
"""

from __future__ import annotations

import argparse
import array
import faulthandler
import importlib
import json
import os
import select
import sys
import time
import traceback

MATCH_WAIT_S = 5.0  # a new publisher waits this long at most for a subscription to match


class Timeout(Exception):
    """A wait of a command ran out (reported as kind 'timeout')."""


def ros_type(name: str):
    """Return the rclpy class of 'pkg/msg/Name' or 'pkg/srv/Name'."""
    parts = name.split('/')
    if len(parts) == 2:  # 'pkg/Name' as get_fields_and_field_types spells nested types
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3 or parts[1] not in ('msg', 'srv', 'action'):
        raise ValueError(f'not a ROS type name: {name!r} (pkg/msg/Name or pkg/srv/Name)')
    return getattr(importlib.import_module(f'{parts[0]}.{parts[1]}'), parts[2])


def to_plain(value):
    """Return a message (or field value) as JSON-able plain values."""
    if hasattr(value, 'get_fields_and_field_types'):
        return {k: to_plain(getattr(value, k)) for k in value.get_fields_and_field_types()}
    if isinstance(value, (bytes, bytearray)):  # a byte field is a 1-byte bytes object
        return value[0] if len(value) == 1 else list(value)
    if isinstance(value, str) or value is None or isinstance(value, (bool, int, float)):
        return value
    if isinstance(value, array.array):
        return value.tolist()
    if hasattr(value, 'tolist'):  # numpy arrays and scalars
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [to_plain(v) for v in value]
    return value


def _field(msg, path: str):
    value = msg
    for part in path.split('.'):
        value = value[int(part)] if part.isdigit() else getattr(value, part)
    return value


def _convert(slot, value):
    """Turn a plain value into what a message field of rosidl type ``slot`` takes."""
    from rosidl_parser.definition import AbstractNestedType, BasicType, NamespacedType

    if isinstance(slot, NamespacedType):
        cls = getattr(importlib.import_module('.'.join(slot.namespaces)), slot.name)
        return value if isinstance(value, cls) else fill(cls(), value)
    if isinstance(slot, AbstractNestedType):
        return [_convert(slot.value_type, v) for v in value]
    if isinstance(slot, BasicType):
        if slot.typename in ('float', 'double', 'long double') and isinstance(value, int) \
                and not isinstance(value, bool):
            return float(value)
        if slot.typename in ('octet', 'char') and isinstance(value, int):
            return bytes([value]) if slot.typename == 'octet' else value
    return value


def fill(msg, values: dict):
    """Set the fields of ``msg`` from a dict (nested messages as dicts); return ``msg``."""
    fields = list(msg.get_fields_and_field_types())
    slots = dict(zip(fields, msg.SLOT_TYPES, strict=True))
    for name, value in values.items():
        if name not in slots:
            raise KeyError(f'{type(msg).__name__} has no field {name!r} (fields: {fields})')
        setattr(msg, name, _convert(slots[name], value))
    return msg


def parameter_value(value) -> dict:
    """Return the ParameterValue fields of a plain value (its type follows the value)."""
    from rcl_interfaces.msg import ParameterType as T

    if isinstance(value, dict):
        return value
    if isinstance(value, bool):
        return {'type': T.PARAMETER_BOOL, 'bool_value': value}
    if isinstance(value, int):
        return {'type': T.PARAMETER_INTEGER, 'integer_value': value}
    if isinstance(value, float):
        return {'type': T.PARAMETER_DOUBLE, 'double_value': value}
    if isinstance(value, str):
        return {'type': T.PARAMETER_STRING, 'string_value': value}
    if isinstance(value, (list, tuple)) and value:
        kinds = {type(v) for v in value}
        if kinds == {bool}:
            return {'type': T.PARAMETER_BOOL_ARRAY, 'bool_array_value': list(value)}
        if kinds == {int}:
            return {'type': T.PARAMETER_INTEGER_ARRAY, 'integer_array_value': list(value)}
        if kinds <= {int, float}:
            return {'type': T.PARAMETER_DOUBLE_ARRAY,
                    'double_array_value': [float(v) for v in value]}
        if kinds == {str}:
            return {'type': T.PARAMETER_STRING_ARRAY, 'string_array_value': list(value)}
    raise TypeError(f'no parameter type for {value!r}: pass a ParameterValue dict')


class ProbeNode:
    """The rclpy side: a node of raw readers and publishers, a node of clients."""

    def __init__(self, name: str) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.service_node = rclpy.create_node(f'{name}_services', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.service_node)
        self.logs: list[dict] = []       # {'sub', 'type', 'fields', 'raw': [bytes]}
        self.clients: dict[str, object] = {}
        self.publishers: dict[tuple, object] = {}

    # -- QoS, readers -------------------------------------------------------------------------
    @staticmethod
    def qos(spec):
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        if isinstance(spec, int) and not isinstance(spec, bool):
            return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=spec,
                              reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.VOLATILE)
        profiles = {
            'reader': (1000, ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.VOLATILE),
            'latched': (100, ReliabilityPolicy.RELIABLE, DurabilityPolicy.TRANSIENT_LOCAL),
            'reliable': (20000, ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE),
        }
        if spec not in profiles:
            raise ValueError(f'unknown QoS {spec!r}: one of {sorted(profiles)} or a depth')
        depth, reliability, durability = profiles[spec]
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability,
                          durability=durability)

    def take(self) -> None:
        """Move every message waiting in the readers' histories into their logs (raw)."""
        for log in self.logs:
            sub = log['sub']
            with sub.handle:
                while (taken := sub.handle.take_message(sub.msg_type, True)) is not None:
                    log['raw'].append(taken[0])

    def wait(self, condition, timeout_s: float) -> bool:
        """Serve the readers and the client node until ``condition()`` or the timeout."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.take()
            if condition():
                return True
            self.executor.spin_once(timeout_sec=min(0.01, max(0.0, deadline - time.monotonic())))
        self.take()
        return bool(condition())

    # -- operations ---------------------------------------------------------------------------
    def op_record(self, type: str, topic: str, qos='reader', fields=None) -> int:
        msg_type = ros_type(type)
        sub = self.node.create_subscription(msg_type, topic, lambda _: None, self.qos(qos),
                                            raw=True)
        self.logs.append({'sub': sub, 'type': msg_type, 'fields': fields, 'raw': []})
        return len(self.logs) - 1

    def op_poll(self) -> list[int]:
        self.take()
        return [len(log['raw']) for log in self.logs]

    def op_fetch(self, log: int, start: int = 0, stop: int | None = None) -> list:
        from rclpy.serialization import deserialize_message

        entry = self.logs[log]
        fields = entry['fields']
        rows = []
        for data in entry['raw'][start:stop]:
            msg = deserialize_message(data, entry['type'])
            if fields is None:
                rows.append(to_plain(msg))
            elif isinstance(fields, str):
                rows.append(to_plain(_field(msg, fields)))
            else:
                rows.append([to_plain(_field(msg, f)) for f in fields])
        return rows

    def op_call(self, type: str, name: str, request: dict | None = None,
                timeout_s: float = 10.0) -> dict:
        srv_type = ros_type(type)
        client = self.clients.get(name)
        if client is None:
            client = self.service_node.create_client(srv_type, name)
            if not self.wait(client.service_is_ready, timeout_s):
                raise Timeout(f'{name} not available')
            # "ready" means the server's request reader is matched; the server may not have
            # matched this client's response reader yet, and a response sent before that is
            # lost (a known race of new clients): give discovery a moment, once per client
            self.wait(lambda: False, 0.3)
            self.clients[name] = client
        future = client.call_async(fill(srv_type.Request(), request or {}))
        if not self.wait(future.done, timeout_s):
            raise Timeout(f'{name} did not answer')
        return to_plain(future.result())

    def op_get_parameters(self, node: str, names: list[str], timeout_s: float = 10.0) -> list:
        res = self.op_call('rcl_interfaces/srv/GetParameters', f'{node}/get_parameters',
                           {'names': list(names)}, timeout_s)
        return res['values']

    def op_set_parameters(self, node: str, parameters: dict, timeout_s: float = 10.0) -> list:
        req = {'parameters': [{'name': k, 'value': parameter_value(v)}
                              for k, v in parameters.items()]}
        res = self.op_call('rcl_interfaces/srv/SetParameters', f'{node}/set_parameters', req,
                           timeout_s)
        return res['results']

    def op_graph(self) -> dict:
        """Every other node's endpoints: {'/ns/name': {'publishers': [[name, [types]]], ...}}."""
        node = self.node
        mine = {node.get_fully_qualified_name(), self.service_node.get_fully_qualified_name()}
        out = {}
        for name, ns in node.get_node_names_and_namespaces():
            full = f'{ns.rstrip("/")}/{name}'
            if full in mine:
                continue
            out[full] = {
                'publishers': node.get_publisher_names_and_types_by_node(name, ns),
                'subscriptions': node.get_subscriber_names_and_types_by_node(name, ns),
                'services': node.get_service_names_and_types_by_node(name, ns),
                'clients': node.get_client_names_and_types_by_node(name, ns)}
        return to_plain(out)

    def op_publish(self, type: str, topic: str, fields: dict | None = None,
                   qos=10, count: int = 1, period_s: float = 0.0,
                   increment: list[str] | None = None) -> int:
        msg_type = ros_type(type)
        key = (topic, type, json.dumps(qos))
        pub = self.publishers.get(key)
        if pub is None:
            pub = self.publishers[key] = self.node.create_publisher(msg_type, topic,
                                                                    self.qos(qos))
            # a new publisher's first messages reach nobody until discovery has matched it
            # (slow on a loaded machine: a test's commands were all lost once); a topic no one
            # reads costs this wait once
            deadline = time.monotonic() + MATCH_WAIT_S
            while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
                self.take()
                time.sleep(0.005)
        msg = fill(msg_type(), fields or {})
        t0 = time.monotonic()
        for i in range(count):
            if i:
                for path in increment or ():
                    parent, _, name = path.rpartition('.')
                    owner = _field(msg, parent) if parent else msg
                    setattr(owner, name, getattr(owner, name) + 1)
                # the next one at t0 + i * period; the readers are served meanwhile
                while (wait := t0 + i * period_s - time.monotonic()) > 0:
                    self.take()
                    time.sleep(min(wait, 0.001))
            pub.publish(msg)
        self.take()
        return count

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        for log in self.logs:
            self.node.destroy_subscription(log['sub'])
        for pub in self.publishers.values():
            self.node.destroy_publisher(pub)
        for client in self.clients.values():
            self.service_node.destroy_client(client)
        self.service_node.destroy_node()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


class Lines:
    """Read stdin in whole lines with a timeout (select on the descriptor, no buffering)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.buf = b''
        self.eof = False

    def next(self, timeout_s: float) -> bytes | None:
        while b'\n' not in self.buf and not self.eof:
            ready, _, _ = select.select([self.fd], [], [], timeout_s)
            if not ready:
                return None
            chunk = os.read(self.fd, 1 << 16)
            if not chunk:
                self.eof = True
            self.buf += chunk
        if b'\n' in self.buf:
            line, self.buf = self.buf.split(b'\n', 1)
            return line
        line, self.buf = self.buf, b''
        return line or None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--name', default='probe')
    args = parser.parse_args(argv)
    faulthandler.enable()  # a crash in rclpy prints every thread's Python stack to stderr
    # stdout carries the replies only: anything else printing there goes to stderr
    out = os.fdopen(os.dup(sys.stdout.fileno()), 'w', buffering=1)
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())

    def reply(obj) -> None:
        out.write(json.dumps(obj, allow_nan=True) + '\n')
        out.flush()

    probe = ProbeNode(args.name)
    reply({'ready': os.getpid()})
    lines = Lines(sys.stdin.fileno())
    while True:
        line = lines.next(0.01)
        if line is None:
            if lines.eof:  # the test process is gone: clean up and end
                probe.close()
                return 0
            probe.take()  # idle: keep the readers' histories from overflowing
            continue
        if not line.strip():
            continue
        cmd_id = None
        try:
            cmd = json.loads(line)
            cmd_id = cmd.pop('id', None)
            op = cmd.pop('op')
            if op == 'quit':
                try:
                    probe.close()
                except Exception as exc:
                    reply({'id': cmd_id, 'ok': False, 'kind': type(exc).__name__,
                           'error': f'quit: {type(exc).__name__}: {exc}',
                           'traceback': traceback.format_exc()})
                    return 1
                reply({'id': cmd_id, 'ok': True, 'result': None})
                return 0
            handler = getattr(probe, f'op_{op}', None)
            if handler is None:
                raise ValueError(f'unknown op {op!r}')
            result = handler(**cmd)
            reply({'id': cmd_id, 'ok': True, 'result': result})
        except Timeout as exc:
            reply({'id': cmd_id, 'ok': False, 'kind': 'timeout', 'error': str(exc)})
        except Exception as exc:  # any failure of a command is its reply, never a crash
            reply({'id': cmd_id, 'ok': False, 'kind': type(exc).__name__,
                   'error': f'{type(exc).__name__}: {exc}', 'traceback': traceback.format_exc()})


if __name__ == '__main__':
    sys.exit(main())
