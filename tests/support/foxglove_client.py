"""A Foxglove WebSocket client, as the Foxglove app speaks the protocol (tests and benches).

The protocol (foxglove/ws-protocol, docs/spec.md): on connecting the server sends ``serverInfo``,
``advertise`` (its channels: id, topic, encoding, schema) and ``advertiseServices``; the client
``subscribe``s a channel with an id of its choice and then receives binary *message data*
frames (opcode 0x01, uint32 subscription id, uint64 log time [ns], payload: here JSON). A
service call is a binary frame (0x02, service id, call id, encoding length, encoding,
payload); the answer is 0x03 with the same layout, or a JSON ``serviceCallFailure``. All
integers little endian.

Subprotocols: the client offers ``foxglove.sdk.v1`` and ``foxglove.websocket.v1``. The
``foxglove-sdk`` server (every version tried, 0.16-0.30.3) refuses a client that offers only
``foxglove.websocket.v1`` (HTTP 400 "Missing expected sec-websocket-protocol header") and
selects ``foxglove.sdk.v1``, whose frames are those of the v1 protocol above.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import json
import struct
import threading
import time
from typing import Any

SUBPROTOCOLS = ['foxglove.sdk.v1', 'foxglove.websocket.v1']


class ServiceCallFailure(RuntimeError):
    """The server answered a service call with a failure (its message)."""


@dataclass
class Received:
    """One message data frame: log time [ns], when it arrived (monotonic [s]), JSON payload."""

    log_time_ns: int
    arrived_s: float
    data: dict[str, Any]


@dataclass
class FoxgloveClient:
    """Connect, subscribe to ``topics`` (None: every channel), collect; call services."""

    url: str
    topics: list[str] | None = None
    connect_timeout_s: float = 30.0
    channels: dict[str, dict[str, Any]] = field(default_factory=dict)
    services: dict[str, dict[str, Any]] = field(default_factory=dict)
    messages: dict[str, list[Received]] = field(default_factory=dict)
    server_info: dict[str, Any] = field(default_factory=dict)
    subprotocol: str | None = None
    frames: int = 0

    def __post_init__(self) -> None:
        from websockets.sync.client import connect

        deadline = time.monotonic() + self.connect_timeout_s
        while True:
            try:
                self.ws = connect(self.url, subprotocols=SUBPROTOCOLS, open_timeout=5,
                                  max_size=None, compression=None)
                break
            except (OSError, TimeoutError):
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)
        self.subprotocol = self.ws.subprotocol
        self._lock = threading.Lock()
        self._subs: dict[int, str] = {}
        self._calls: dict[int, tuple[threading.Event, list]] = {}
        self._next_call = 1
        self._stop = False
        self._thread = threading.Thread(target=self._run, name='foxglove-client', daemon=True)
        self._thread.start()

    # -- receiving -----------------------------------------------------------------------------
    def _run(self) -> None:
        from websockets.exceptions import ConnectionClosed

        while not self._stop:
            try:
                frame = self.ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            except ConnectionClosed:
                return
            if isinstance(frame, str):
                self._text(json.loads(frame))
            else:
                self._binary(frame)

    def _text(self, msg: dict[str, Any]) -> None:
        op = msg.get('op')
        if op == 'serverInfo':
            self.server_info = msg
        elif op == 'advertise':
            new = []
            with self._lock:
                for ch in msg['channels']:
                    self.channels[ch['topic']] = ch
                    if self.topics is None or ch['topic'] in self.topics:
                        sub_id = len(self._subs) + 1
                        self._subs[sub_id] = ch['topic']
                        self.messages.setdefault(ch['topic'], [])
                        new.append({'id': sub_id, 'channelId': ch['id']})
            if new:
                self.ws.send(json.dumps({'op': 'subscribe', 'subscriptions': new}))
        elif op == 'advertiseServices':
            with self._lock:
                for s in msg['services']:
                    self.services[s['name']] = s
        elif op == 'serviceCallFailure':
            self._answer(msg['callId'], ServiceCallFailure(msg.get('message', '')))

    def _binary(self, frame: bytes) -> None:
        opcode = frame[0]
        if opcode == 0x01:
            sub_id, log_time = struct.unpack_from('<IQ', frame, 1)
            topic = self._subs.get(sub_id)
            if topic is not None:
                self.frames += 1
                self.messages[topic].append(Received(log_time, time.monotonic(),
                                                     json.loads(frame[13:])))
        elif opcode == 0x03:
            _sid, call_id, n = struct.unpack_from('<III', frame, 1)
            self._answer(call_id, json.loads(frame[13 + n:] or b'{}'))

    def _answer(self, call_id: int, result: Any) -> None:
        with self._lock:
            waiting = self._calls.pop(call_id, None)
        if waiting is not None:
            waiting[1].append(result)
            waiting[0].set()

    # -- using it ------------------------------------------------------------------------------
    def wait_for(self, condition, timeout_s: float) -> bool:
        """Wait until ``condition()`` holds; False if it did not within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if condition():
                return True
            time.sleep(0.02)
        return bool(condition())

    def call(self, name: str, request: dict[str, Any] | None = None,
             timeout_s: float = 15.0) -> dict[str, Any]:
        """Call service ``name`` with a JSON request; return its JSON response."""
        if not self.wait_for(lambda: name in self.services, 10.0):
            raise ServiceCallFailure(f'{name}: not advertised ({sorted(self.services)})')
        service = self.services[name]
        with self._lock:
            call_id = self._next_call
            self._next_call += 1
            waiting: tuple[threading.Event, list] = (threading.Event(), [])
            self._calls[call_id] = waiting
        enc = b'json'
        self.ws.send(struct.pack('<BIII', 0x02, service['id'], call_id, len(enc)) + enc
                     + json.dumps(request or {}).encode())
        if not waiting[0].wait(timeout_s):
            raise TimeoutError(f'{name}: no answer within {timeout_s} s')
        result = waiting[1][0]
        if isinstance(result, Exception):
            raise result
        return result

    def close(self) -> None:
        """Disconnect."""
        self._stop = True
        try:
            self.ws.close()
        finally:
            self._thread.join(timeout=5.0)
