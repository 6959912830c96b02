"""Live view: the contract's topics, decimated, served over the Foxglove WebSocket protocol.

    ros2 run ladrc_tools view_node                      # beside any bring-up, ws://127.0.0.1:8765
    ros2 run ladrc_tools view_node --port 8766          # or: --ros-args -p port:=8766
    bringup --scenario showcase --view [--view-port N]  # started with the node set

Open Foxglove, *Open connection* -> Foxglove WebSocket ``ws://127.0.0.1:8765``, and import the
shipped layout ``share/ladrc_bags/config/foxglove_layout.json`` (docs/live-view.md).

What it serves (``foxglove-sdk``'s WebSocket server, JSON channels with JSON schemas):

* ``/follow/status``, ``/sim/truth`` (when a simulator publishes it), ``/axis/velocity_command``,
  ``/cnc/motion`` (in a job): decimated to the display rate (``display_rate_hz``, 50 Hz): per
  display interval the messages at each extreme field's minimum and maximum, the interval's
  last message and every message at which a state, a fault or a hold reason changes
  (:mod:`.view_channels` says exactly which, and how: numpy per batch). Field names are the
  messages' own, so the layout's paths (``/follow/status.gap_mm``) read a bag and the live view
  alike; ``view_ticks`` (live only) is how many messages the view received in that interval.
* ``/follow/events``: every event, not decimated (``kind_name`` added). A client that
  subscribes gets the events so far first (the last 100, the ROS topic's transient-local
  history: the parameter set in force is among them), as a late ROS reader would; clients
  subscribed before see those again then.
* ``/view/xy_gap_error``: the XY path of a job coloured by the gap error (one point per
  interval, its band), ``/view/log``: foxglove.Log lines for each state change, each new fault
  reason (ERROR), each new hold reason (WARNING), each event and each operator call.
* Services (the ``services`` capability): ``/follow/start``, ``/follow/stop``,
  ``/follow/reset_fault``, ``/follow/lift``, JSON requests with the ROS request's fields
  (``{"target_gap_mm": 1.0}``), each forwarded to the follow node's ROS service of that name
  and answered with its ``{"accepted", "message"}``: the follow node's own checks decide. The
  view commands nothing else; in the SROS2 policy it is the operator enclave's ``ladrc_view``
  profile (docs/safety.md).

Safety: read-only but for those four calls. It listens on 127.0.0.1 only (``host`` is a
parameter: another address only when asked, with a warning). It runs in its own process at
the normal scheduler and reads the topics as the recorder does: loop readers taken in batches
every few milliseconds, BEST_EFFORT keep-last on the 2 kHz topics (the publishers' loops never
wait for it), events reliable transient local. A port in use: one line on stderr, exit 2.

Parameters: ``port`` (8765; 0: a free port, printed), ``host`` (127.0.0.1),
``display_rate_hz`` (50), ``service_timeout_s`` (5). On SIGINT/SIGTERM it stops the server and
prints a one-line JSON summary (messages received and sent per topic).
"""

from __future__ import annotations

import argparse
from collections import deque
from dataclasses import dataclass
import ipaddress
import json
import sys
import threading
import time
from typing import Any

from ladrc_contract.node_entry import NodeRun, StartError, run_node
import numpy as np

from .view_channels import (
    DISPLAY_RATE_HZ,
    EVENTS_TOPIC,
    EVENTS_TYPE,
    LOG_CHANNEL,
    LOG_SCHEMA,
    STATUS,
    VIEWS,
    XY_CHANNEL,
    XY_SCHEMA,
    Decimator,
    ReasonLog,
    TopicView,
    XyPath,
    json_schema,
    log_record,
    rows_as_json,
    stamps_ns,
)

DEFAULT_PORT = 8765
OPERATOR_SERVICES = ('start_follow', 'stop_follow', 'reset_fault', 'lift')
"""The commissioning calls served (ladrc_contract.services.FOLLOW_SERVICES names)."""
NAME = 'ladrc_view'


@dataclass
class ViewSettings:
    """The node's settings (parameters), checked."""

    host: str = '127.0.0.1'
    port: int = DEFAULT_PORT
    display_rate_hz: float = DISPLAY_RATE_HZ
    service_timeout_s: float = 5.0

    def check(self) -> str | None:
        """Return why the settings are unusable (one line), or None."""
        try:
            ipaddress.ip_address(self.host)
        except ValueError:
            return f'host must be an IP address (default 127.0.0.1), got {self.host!r}'
        if not 0 <= self.port <= 65535:
            return f'port must be 0..65535 (0: any free port), got {self.port}'
        if not 1.0 <= self.display_rate_hz <= 1000.0:
            return f'display_rate_hz must be 1..1000, got {self.display_rate_hz}'
        if not self.service_timeout_s > 0:
            return f'service_timeout_s must be > 0, got {self.service_timeout_s}'
        return None

    @property
    def interval_ns(self) -> int:
        """The display interval [ns]."""
        return int(round(1e9 / self.display_rate_hz))


def _decode(columns: Any, batch: list[tuple[bytes, int]],
            names: list[str] | None) -> dict[str, np.ndarray] | None:
    """Decode a batch of raw CDR messages of one type into columns (None: malformed)."""
    datas = [d for d, _ in batch]
    size = np.fromiter(map(len, datas), dtype=np.int64, count=len(datas))
    start = np.zeros(size.size, dtype=np.int64)
    np.cumsum(size[:-1], out=start[1:])
    return columns.decode(np.frombuffer(b''.join(datas), dtype=np.uint8), start, size, names)


def _schema_type(ros_type: str) -> dict[str, Any]:
    if ros_type == 'string':
        return {'type': 'string'}
    if ros_type == 'boolean':
        return {'type': 'boolean'}
    if ros_type in ('float', 'double'):
        return {'type': 'number'}
    if ros_type.startswith('sequence<') or '[' in ros_type:
        return {'type': 'array', 'items': {'type': 'number'}}
    return {'type': 'integer'}


def service_schemas(name: str) -> tuple[str, dict[str, Any], dict[str, Any]]:
    """Return the ROS type and the JSON schemas of request and response of command ``name``."""
    from ladrc_contract.services import FOLLOW_SERVICES, service_class

    typename = FOLLOW_SERVICES[name][0]
    cls = service_class(typename)

    def schema(part: Any, title: str) -> dict[str, Any]:
        return {'title': title, 'type': 'object', 'properties': {
            f: _schema_type(t) for f, t in part.get_fields_and_field_types().items()}}

    return typename, schema(cls.Request, typename + '_Request'), schema(cls.Response,
                                                                         typename + '_Response')


class LiveView:
    """Readers, decimators and the Foxglove channels and services of one view node."""

    def __init__(self, node: Any, settings: ViewSettings) -> None:
        import foxglove
        from ladrc_bags.columns import CdrColumns
        from ladrc_bags.recorder_node import msg_class
        from ladrc_bags.typestore import ladrc_typestore
        from ladrc_contract import qos
        from ladrc_contract.qos import to_rclpy
        from ladrc_contract.services import FOLLOW_SERVICES, service_class

        self.node, self.settings = node, settings
        self.context = foxglove.Context()
        store = ladrc_typestore()
        self.views = {v.topic: v for v in VIEWS}
        # the 2 kHz topics best effort with the recorder's deep history (5 s): the publishers
        # never wait for this reader, and a stalled view loses nothing it could show
        self.readers = {v.topic: node.create_loop_reader(msg_class(v.msgtype), v.topic,
                                                         to_rclpy(qos.RECORDER_READER))
                        for v in VIEWS}
        self.readers[EVENTS_TOPIC] = node.create_loop_reader(
            msg_class(EVENTS_TYPE), EVENTS_TOPIC, to_rclpy(qos.EVENTS))
        self.columns = {v.topic: CdrColumns(v.msgtype, store) for v in VIEWS}
        self.columns[EVENTS_TOPIC] = CdrColumns(EVENTS_TYPE, store)
        self.event_fields = [f for f, _ in self.columns[EVENTS_TOPIC].fields]
        self.decimators = {v.topic: Decimator(v, settings.interval_ns) for v in VIEWS}
        self.channels = {}
        for v in VIEWS:
            kinds = [(f, k) for f, k in self.columns[v.topic].fields if f in v.fields]
            schema = json_schema(v.msgtype.replace('/msg/', '/') + '_view', kinds, {
                'view_ticks': {'type': 'integer',
                               'description': 'messages of this display interval received'}})
            self.channels[v.topic] = foxglove.Channel(v.channel, schema=schema,
                                                      context=self.context)
        self.channels[EVENTS_TOPIC] = foxglove.Channel(
            '/' + EVENTS_TOPIC, context=self.context, schema=json_schema(
                'ladrc_msgs/FollowEvent_view', self.columns[EVENTS_TOPIC].fields,
                {'kind_name': {'type': 'string'}}))
        self.xy_channel = foxglove.Channel(XY_CHANNEL, schema=XY_SCHEMA, context=self.context)
        self.log_channel = foxglove.Channel(LOG_CHANNEL, schema=LOG_SCHEMA,
                                            context=self.context)
        self.xy = XyPath(settings.interval_ns)
        self.reasons = ReasonLog()
        self.last_rx = {v.topic: 0.0 for v in VIEWS}
        self.events = {'received': 0, 'sent': 0}
        self.malformed = 0
        self.calls: dict[str, int] = {}
        self.clients = {name: node.create_client(service_class(FOLLOW_SERVICES[name][0]),
                                                 FOLLOW_SERVICES[name][1])
                        for name in OPERATOR_SERVICES}
        self.services = [self._service(name) for name in OPERATOR_SERVICES]
        self._lock = threading.Lock()  # the log channel: from the loop and service calls
        self.history: deque[tuple[dict[str, Any], int]] = deque(maxlen=qos.EVENTS.depth)

    # -- the services ----------------------------------------------------------------------
    def _service(self, name: str) -> Any:
        import foxglove
        from foxglove import MessageSchema, Schema, ServiceSchema
        from ladrc_contract.services import FOLLOW_SERVICES

        typename, req, res = service_schemas(name)

        def part(schema: dict[str, Any]) -> Any:
            return MessageSchema(encoding='json', schema=Schema(
                name=schema['title'], encoding='jsonschema', data=json.dumps(schema).encode()))

        return foxglove.Service('/' + FOLLOW_SERVICES[name][1],
                                schema=ServiceSchema(typename, request=part(req),
                                                     response=part(res)),
                                handler=lambda request: self.call(name, request.payload))

    def call(self, name: str, payload: bytes) -> bytes:
        """Forward one operator call to the follow node; return its JSON response.

        Raises (the client gets a service call failure with the message) on a request that is
        not a JSON object of the request's fields, or when the follow node does not answer.
        """
        from ladrc_contract.services import FOLLOW_SERVICES, fill_request

        service = FOLLOW_SERVICES[name][1]
        try:
            args = json.loads(bytes(payload) or b'{}')
        except ValueError as exc:
            raise ValueError(f'{service}: the request is not JSON: {exc}') from None
        fields = FOLLOW_SERVICES[name][2]
        if not isinstance(args, dict) or set(args) - set(fields):
            raise ValueError(f'{service}: a JSON object of {sorted(fields) or "no fields"} '
                             f'expected, got {str(args)[:200]}')
        try:
            request = fill_request(name, args)
        except (TypeError, ValueError) as exc:
            raise ValueError(f'{service}: {exc}') from None
        client = self.clients[name]
        timeout = self.settings.service_timeout_s
        if not client.wait_for_service(timeout_sec=min(1.0, timeout)):
            raise RuntimeError(f'{service}: the follow node does not offer it')
        done = threading.Event()
        future = client.call_async(request)
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(timeout):
            client.remove_pending_request(future)
            raise TimeoutError(f'{service}: no answer within {timeout:g} s')
        response = future.result()
        self.calls[service] = self.calls.get(service, 0) + 1
        answer = {'accepted': bool(response.accepted), 'message': str(response.message)}
        self._log(time.time_ns(), 'info' if answer['accepted'] else 'warning',
                  f'operator {service} {json.dumps(args)}: '
                  + ('accepted' if answer['accepted'] else 'refused')
                  + (f' ({answer["message"]})' if answer['message'] else ''), NAME)
        return json.dumps(answer).encode()

    # -- the topics ------------------------------------------------------------------------
    def _log(self, stamp_ns: int, level: str, message: str, name: str) -> None:
        with self._lock:
            self.log_channel.log(log_record(stamp_ns, level, message, name), log_time=stamp_ns)

    def _send(self, view: TopicView, rows: dict[str, np.ndarray], index: np.ndarray,
              counts: np.ndarray) -> None:
        if not index.size:
            return
        channel = self.channels[view.topic]
        is_status = view is STATUS
        if not (is_status or channel.has_sinks()):
            return
        objs = rows_as_json(rows, view.fields, index)
        stamps = stamps_ns(rows)[index].tolist()
        for obj, n, t in zip(objs, counts.tolist(), stamps, strict=True):
            obj['view_ticks'] = n
            channel.log(obj, log_time=t)
        if is_status:
            for t, line in self.reasons.lines(objs, stamps):
                with self._lock:
                    self.log_channel.log(line, log_time=t)
            for t, point in self.xy.points(rows):
                self.xy_channel.log(point, log_time=t)

    def _events(self, batch: list[tuple[bytes, int]]) -> None:
        from ladrc_contract.codes import EventKind

        cols = _decode(self.columns[EVENTS_TOPIC], batch, None)
        if cols is None:
            self.malformed += len(batch)
            return
        self.events['received'] += len(batch)
        stamps = stamps_ns(cols).tolist()
        for obj, t in zip(rows_as_json(cols, self.event_fields, np.arange(len(batch))), stamps,
                          strict=True):
            try:
                kind = EventKind(obj['kind']).name
            except ValueError:
                kind = str(obj['kind'])
            obj['kind_name'] = kind
            with self._lock:
                self.history.append((obj, t))
                self.channels[EVENTS_TOPIC].log(obj, log_time=t)
            self.events['sent'] += 1
            what = ('parameters' if kind == 'PARAMETERS' else
                    f'{kind} value_mm={obj["value_mm"]}' + (f' {obj["text"]}' if obj['text']
                                                            else ''))
            self._log(t, 'info', f'event at tick {obj["tick"]}: {what}', 'ladrc_follow')

    def poll(self) -> None:
        """Take every waiting message, decimate, send; close intervals of quiet topics."""
        now = time.monotonic()
        quiet_s = 2.0 * self.settings.interval_ns * 1e-9
        events = self.readers[EVENTS_TOPIC].take_all()
        if events:
            self._events(events)
        for view in (VIEWS[1:] + VIEWS[:1]):  # the XY sources before the status
            dec = self.decimators[view.topic]
            batch = self.readers[view.topic].take_all()
            if batch:
                cols = _decode(self.columns[view.topic], batch, list(view.fields))
                if cols is None:
                    self.malformed += len(batch)
                    continue
                self.last_rx[view.topic] = now
                if 'x_mm' in cols:
                    self.xy.add_xy(cols)
                self._send(view, *dec.push(cols))
            elif dec.pending and now - self.last_rx[view.topic] > quiet_s:
                self._send(view, *dec.flush())

    def on_subscribe(self, client: Any, channel: Any) -> None:
        """Send the events so far to a client that subscribes to them (module docstring)."""
        if channel.topic != '/' + EVENTS_TOPIC:
            return
        with self._lock:
            for obj, t in self.history:
                self.channels[EVENTS_TOPIC].log(obj, log_time=t)

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        """Nothing to do (the server listener's other callback in use)."""

    def summary(self) -> dict[str, Any]:
        """Messages received and sent per topic (the exit line)."""
        return {'received': {t: d.received for t, d in self.decimators.items()},
                'sent': {t: d.sent for t, d in self.decimators.items()},
                'events': dict(self.events), 'malformed': self.malformed,
                'operator_calls': dict(self.calls)}


def _arguments(argv: list[str]) -> argparse.Namespace:
    from rclpy.utilities import remove_ros_args

    ap = argparse.ArgumentParser(prog='view_node', description=__doc__.split('\n\n')[0])
    ap.add_argument('--port', type=int, default=DEFAULT_PORT,
                    help=f'WebSocket port on the host [{DEFAULT_PORT}; 0: any free port]')
    ap.add_argument('--host', default='127.0.0.1',
                    help='address to listen on [127.0.0.1: this machine only]')
    ap.add_argument('--rate-hz', type=float, default=DISPLAY_RATE_HZ,
                    help=f'display intervals per second [{DISPLAY_RATE_HZ:g}]')
    return ap.parse_args(remove_ros_args(argv)[1:])


def _run(node, node_run: NodeRun, cli: argparse.Namespace) -> int:
    """Serve the live view until a stop is requested; print its summary; 0."""
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    settings = ViewSettings(
        host=str(node.declare_parameter('host', cli.host).value),
        port=int(node.declare_parameter('port', cli.port).value),
        display_rate_hz=float(node.declare_parameter('display_rate_hz', cli.rate_hz).value),
        service_timeout_s=float(node.declare_parameter('service_timeout_s', 5.0).value))
    problem = settings.check()
    if problem:
        raise StartError(problem)
    import foxglove
    from foxglove.websocket import Capability

    view = LiveView(node, settings)
    try:
        server = foxglove.start_server(
            name='ladrc live view', host=settings.host, port=settings.port,
            capabilities=[Capability.Services], supported_encodings=['json'],
            services=view.services, context=view.context, server_listener=view)
    except Exception as exc:  # the port in use, an address not on this machine
        why = ' '.join(str(exc).split()).removeprefix('FoxgloveError: ')
        raise StartError(f'cannot listen on {settings.host}:{settings.port}: {why}') from None
    executor = thread = None

    def _end() -> None:
        server.stop()
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        if thread is not None:
            thread.join(timeout=2.0)
        print(json.dumps(view.summary()), flush=True)

    node_run.defer(_end)
    if not ipaddress.ip_address(settings.host).is_loopback:
        node.get_logger().warning(f'listening on {settings.host}: reachable from the '
                                  'network (host parameter); the default is 127.0.0.1')
    print(f'view_node: serving ws://{settings.host}:{server.port} '
          f'(display {settings.display_rate_hz:g} Hz)', file=sys.stderr, flush=True)
    executor = SingleThreadedExecutor(context=node.context)  # the service clients
    executor.add_node(node)

    def spin() -> None:
        try:
            executor.spin()
        except ExternalShutdownException:
            pass

    thread = threading.Thread(target=spin, name='clients', daemon=True)
    thread.start()
    poll_s = min(0.01, 0.5 * settings.interval_ns * 1e-9)
    while not node_run.stop_requested:
        view.poll()
        node_run.wait(poll_s)
    view.poll()
    return 0


def main(args: list[str] | None = None) -> int:
    """Run the view node until SIGINT/SIGTERM (it commands nothing: no zero hook)."""
    from ladrc_contract.loop_io import LoopNode

    argv = list(sys.argv if args is None else args)
    cli = _arguments(argv)
    return run_node('view_node', lambda: LoopNode(NAME),
                    lambda node, node_run: _run(node, node_run, cli), args=argv)


if __name__ == '__main__':
    sys.exit(main())
