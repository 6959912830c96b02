"""Start the project's nodes as real processes and watch topics through a probe process.

The environment (ROS_DOMAIN_ID, localhost discovery) comes from tests/ros/conftest.py; every
process started here is killed at teardown by :class:`NodeProcesses`. The test process itself
uses no rclpy: :class:`Probe` is the client of tests/support/probe_node.py, a process of its own
(as launch_testing runs its test nodes), so a crash in rclpy is that process' crash, reported
with its exit code and output, and the test session goes on.
"""

from __future__ import annotations

from collections.abc import Sequence
import json
import os
from pathlib import Path
import select
import signal
import subprocess
import sys
import tempfile
import time
from typing import Callable
import weakref

from ladrc_bringup.bringup import executable_path, interrupt_process

# QoS of a recording (probe_node.py): the contract's 2 kHz topics are best effort
# (docs/interfaces.md): a test reader matches that, with a deep history (1000) so a slow probe
# drops nothing it could have had; 'latched' is reliable transient local (depth 100), for the
# event log; 'reliable' is reliable volatile (depth 1000). An integer n is reliable, volatile,
# keep last n, as rclpy reads an integer.
READER = 'reader'
LATCHED = 'latched'
RELIABLE = 'reliable'
PROBE_NODE = Path(__file__).with_name('probe_node.py')


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
        """End every process: SIGINT (a node commands zero and leaves), SIGKILL if it hangs.

        Not SIGKILL first: a process killed while it holds a shared-memory port lock of a
        subscriber leaves that lock held, and a participant torn down in the second after can
        crash in Fast DDS 2.14 (tests/support/probe_node.py, "Why a process").
        """
        for name in list(self.procs):
            if self.procs[name].poll() is None:
                self.interrupt(name, timeout_s=10.0)



class ProbeError(RuntimeError):
    """The probe process failed a command, or died: the message holds its exit and output."""


def type_name(t) -> str:
    """Return 'pkg/msg/Name' (or 'pkg/srv/Name') for a ROS type class or such a string."""
    if isinstance(t, str):
        return t
    parts = getattr(t, '__module__', '').split('.')
    if len(parts) >= 2 and parts[1] in ('msg', 'srv', 'action'):
        return f'{parts[0]}/{parts[1]}/{t.__name__}'
    raise TypeError(f'not a ROS message or service type: {t!r}')


def plain(value):
    """Return a message instance (or field value) as plain JSON-able values, for the probe."""
    if hasattr(value, 'get_fields_and_field_types'):
        return {k: plain(getattr(value, k)) for k in value.get_fields_and_field_types()}
    if isinstance(value, Msg):
        return value.as_dict()
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (bytes, bytearray)):
        return value[0] if len(value) == 1 else list(value)
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if hasattr(value, 'tolist'):  # array.array, numpy
        return value.tolist()
    return value


def _wrap(value):
    if isinstance(value, dict):
        return Msg(value)
    if isinstance(value, list):
        return [_wrap(v) for v in value]
    return value


class Msg:
    """A message as the probe decoded it: its fields as attributes (nested messages too)."""

    __slots__ = ('_fields',)

    def __init__(self, fields: dict) -> None:
        object.__setattr__(self, '_fields', {k: _wrap(v) for k, v in fields.items()})

    def __getattr__(self, name: str):
        try:
            return self._fields[name]
        except KeyError:
            raise AttributeError(f'no field {name!r} (fields: {list(self._fields)})') from None

    def __setattr__(self, name: str, value) -> None:
        raise AttributeError('a probe message is read-only')

    def __eq__(self, other) -> bool:
        return isinstance(other, Msg) and self._fields == other._fields

    __hash__ = None

    def __repr__(self) -> str:
        return 'Msg(' + ', '.join(f'{k}={v!r}' for k, v in self._fields.items()) + ')'

    def as_dict(self) -> dict:
        return {k: plain(v) for k, v in self._fields.items()}


class Log(Sequence):
    """The rows of one recorded topic: as many as the probe held at the last poll.

    Rows are decoded by the probe process when first read here (and kept): the test decodes
    only what it looks at, off the receive path. A row is the value of the recording's
    ``fields`` (one path: its value; a list: a tuple; none: the whole message as :class:`Msg`),
    passed through ``keep`` when given.
    """

    FETCH_ROWS = 5000  # rows per fetch: bounded replies

    def __init__(self, probe: Probe, index: int, topic: str, fields, keep: Callable | None):
        self._probe = probe
        self._index = index
        self.topic = topic
        self._fields = fields
        self._keep = keep
        self._count = 0
        self._rows: dict[int, object] = {}

    def __len__(self) -> int:
        return self._count

    def _row(self, raw):
        if self._fields is None:
            row = Msg(raw)
        elif isinstance(self._fields, str):
            row = _wrap(raw)
        else:
            row = tuple(_wrap(v) for v in raw)
        return row if self._keep is None else self._keep(row)

    def _load(self, start: int, stop: int) -> None:
        i = start
        while i < stop:
            if i in self._rows:
                i += 1
                continue
            j = i
            while j < stop and j not in self._rows and j - i < self.FETCH_ROWS:
                j += 1
            raws = self._probe._request('fetch', log=self._index, start=i, stop=j)
            if len(raws) != j - i:
                raise ProbeError(f'{self.topic}: asked for rows {i}:{j}, got {len(raws)}')
            for k, raw in enumerate(raws):
                self._rows[i + k] = self._row(raw)
            i = j

    def __getitem__(self, index):
        if isinstance(index, slice):
            rows = range(*index.indices(self._count))
            if rows:
                self._load(min(rows), max(rows) + 1)
            return [self._rows[i] for i in rows]
        i = index + self._count if index < 0 else index
        if not 0 <= i < self._count:
            raise IndexError(f'{self.topic}: row {index} of {self._count}')
        self._load(i, i + 1)
        return self._rows[i]

    def __iter__(self):
        n = self._count
        self._load(0, n)
        return (self._rows[i] for i in range(n))


def _describe_exit(rc: int | None) -> str:
    if rc is None:
        return 'still running'
    if rc < 0:
        try:
            return f'signal {-rc} ({signal.Signals(-rc).name})'
        except ValueError:
            return f'signal {-rc}'
    return f'exit code {rc}'


def _kill_group(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()
    for pipe in (proc.stdin, proc.stdout):
        if pipe is not None:
            try:
                pipe.close()
            except OSError:
                pass


class Probe:
    """Records topics, calls services, publishes: through a probe process (probe_node.py).

    ``record`` starts a recording and returns its :class:`Log`; ``poll`` (and ``spin_until`` /
    ``spin_for``, which poll every 10 ms and evaluate the condition here) brings the logs' counts
    up to date. The probe process takes every topic's messages raw from the subscriptions'
    readers (deep histories, no executor: a Python executor cannot keep up with three 2 kHz
    topics on a 2-core machine), also between polls, and decodes a row only when the test
    reads it. Service calls go through a second node on a SingleThreadedExecutor there; a
    call or a publish ends with a poll (the in-process probe spun while it waited). Types
    are ROS classes (``FollowStatus``) or 'pkg/msg/Name' strings; requests and published
    messages are message instances or dicts of their fields; responses are :class:`Msg`.

    ``close()`` asks the process to quit and raises :class:`ProbeError` with its exit code and
    output if it does not end cleanly (a crash of rclpy is that process' crash, not pytest's).

    """

    def __init__(self, name: str = 'probe', start_timeout_s: float = 60.0) -> None:
        self.name = name
        self.logdir = Path(tempfile.mkdtemp(prefix='ladrc-probe-'))
        self.log_path = self.logdir / f'{name}.log'
        err = open(self.log_path, 'wb')  # noqa: SIM115
        self.proc = subprocess.Popen([sys.executable, str(PROBE_NODE), '--name', name],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=err,
                                     env=dict(os.environ), start_new_session=True)
        err.close()
        self._finalizer = weakref.finalize(self, _kill_group, self.proc)
        self._buf = b''
        self._id = 0
        self._logs: list[Log] = []
        self._subscribers: list[list] = []  # [log, callback, rows delivered]
        self._closed = False
        self._failed = False
        hello = self._read_reply(start_timeout_s, 'start-up')
        if 'ready' not in hello:
            self._fail(f'probe process: unexpected first line {hello!r}')

    # -- the process ----------------------------------------------------------------------------
    def log(self) -> str:
        """Return the probe process' output (stderr: rclpy's log, a crash's stack)."""
        try:
            return self.log_path.read_text(errors='replace')
        except OSError:
            return ''

    def _fail(self, what: str):
        """Kill the process (if still alive), raise ProbeError with its exit and output."""
        self._failed = True
        try:
            rc = self.proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            rc = None
        self._finalizer()
        tail = self.log()[-6000:]
        raise ProbeError(f'{what}; probe process {self.proc.pid} {_describe_exit(rc)}'
                         f'\n--- probe output ({self.log_path}) ---\n{tail}')

    def _read_reply(self, timeout_s: float, what: str) -> dict:
        deadline = time.monotonic() + timeout_s
        fd = self.proc.stdout.fileno()
        while b'\n' not in self._buf:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self._finalizer()  # kill it: its state is unknown
                self._fail(f'probe: no answer to {what} within {timeout_s:g} s (killed)')
            if select.select([fd], [], [], remaining)[0]:
                chunk = os.read(fd, 1 << 20)
                if not chunk:
                    self._fail(f'probe process died during {what}')
                self._buf += chunk
        line, self._buf = self._buf.split(b'\n', 1)
        return json.loads(line)

    def _exchange(self, op: str, timeout_s: float, args: dict) -> dict:
        if self._closed or self._failed:
            raise ProbeError(f'probe {op}: the probe is closed or has failed')
        self._id += 1
        line = json.dumps({'id': self._id, 'op': op, **args}, allow_nan=True).encode() + b'\n'
        try:
            self.proc.stdin.write(line)
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError):
            self._fail(f'probe process died before {op}')
        reply = self._read_reply(timeout_s, op)
        if reply.get('id') != self._id:
            self._fail(f'probe {op}: reply {reply!r} out of order')
        return reply

    def _request(self, op: str, wait_s: float = 60.0, **args):
        reply = self._exchange(op, wait_s, args)
        if reply['ok']:
            return reply['result']
        if reply.get('kind') == 'timeout':  # a wait ran out: as the in-process probe asserted
            raise AssertionError(reply['error'])
        raise ProbeError(f'probe {op} failed: {reply["error"]}\n{reply.get("traceback", "")}')

    # -- topics ---------------------------------------------------------------------------------
    def record(self, msg_type, topic: str, fields=None, qos=READER,
               keep: Callable | None = None) -> Log:
        """Collect every message of ``topic``: rows of ``fields`` (dotted paths), see Log."""
        if fields is not None and not isinstance(fields, str):
            fields = list(fields)
        index = self._request('record', type=type_name(msg_type), topic=topic, qos=qos,
                              fields=fields)
        log = Log(self, index, topic, fields, keep)
        self._logs.append(log)
        return log

    def subscribe(self, msg_type, topic: str, callback: Callable, qos=10, fields=None) -> Log:
        """Record ``topic`` and call ``callback(row)`` for each new row at every poll.

        Every message is decoded as it comes: for low-rate topics (diagnostics, events).
        """
        log = self.record(msg_type, topic, fields=fields, qos=qos)
        self._subscribers.append([log, callback, 0])
        return log

    def poll(self) -> None:
        """Bring every log up to what the probe holds; run the subscribe callbacks."""
        counts = self._request('poll')
        for log, n in zip(self._logs, counts, strict=True):
            log._count = n
        for sub in self._subscribers:
            log, callback, done = sub
            for row in log[done:]:
                callback(row)
            sub[2] = len(log)

    def spin_until(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.poll()
            if condition():
                return True
            time.sleep(min(0.01, max(0.0, deadline - time.monotonic())))
        self.poll()
        return condition()

    def spin_for(self, seconds: float) -> None:
        self.spin_until(lambda: False, seconds)

    def publish(self, msg_type, topic: str, fields=None, qos=10, count: int = 1,
                period_s: float = 0.0, increment: Sequence[str] = ()) -> int:
        """Publish a message ``count`` times, one per ``period_s``, raising ``increment`` fields.

        ``fields`` is a message instance or a dict of its fields. The probe serves its readers
        between the messages. Returns the number published.
        """
        n = self._request('publish', wait_s=60.0 + count * period_s, type=type_name(msg_type),
                          topic=topic, fields=plain(fields or {}), qos=qos, count=count,
                          period_s=period_s, increment=list(increment))
        self.poll()
        return n

    def graph(self) -> dict:
        """Every other node on the domain: its publishers, subscriptions, services, clients.

        ``{'/ns/name': {'publishers': [[topic, [type, ...]], ...], 'subscriptions': ...,
        'services': ..., 'clients': ...}}``, as the graph holds them now.
        """
        return self._request('graph', wait_s=30.0)

    # -- services -------------------------------------------------------------------------------
    def call(self, srv_type, name: str, request=None, timeout_s: float = 10.0) -> Msg:
        """Call a service (request: an instance or a dict of its fields); return the response.

        An AssertionError if the service is not available or does not answer in ``timeout_s``.
        """
        res = self._request('call', wait_s=2 * timeout_s + 30.0, type=type_name(srv_type),
                            name=name, request=plain(request or {}), timeout_s=timeout_s)
        self.poll()
        return Msg(res)

    def get_parameters(self, node: str, names: Sequence[str],
                       timeout_s: float = 10.0) -> list[Msg]:
        """Return the ParameterValue of each name (``node``: '/ns/name')."""
        values = self._request('get_parameters', wait_s=2 * timeout_s + 30.0, node=node,
                               names=list(names), timeout_s=timeout_s)
        self.poll()
        return _wrap(values)

    def set_parameters(self, node: str, parameters: dict, timeout_s: float = 10.0) -> list[Msg]:
        """Set parameters ({name: value}, the type from the value); return each result."""
        results = self._request('set_parameters', wait_s=2 * timeout_s + 30.0, node=node,
                                parameters=plain(parameters), timeout_s=timeout_s)
        self.poll()
        return _wrap(results)

    # -- the end --------------------------------------------------------------------------------
    def close(self, timeout_s: float = 30.0) -> None:
        """Quit the probe process; ProbeError with its exit and output if it does not end well.

        Killed by its process group if it does not end in ``timeout_s``. A probe that failed
        before (and raised then) is only cleaned up.
        """
        if self._closed:
            return
        if self._failed:
            self._closed = True
            self._finalizer()
            return
        reply = self._exchange('quit', timeout_s, {})
        self._closed = True
        try:
            rc = self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self._finalizer()
            self._fail('probe process did not exit after quit (killed)')
        self._finalizer()
        if not reply['ok'] or rc != 0:
            self._failed = True
            why = '' if reply['ok'] else f'{reply["error"]}\n{reply.get("traceback", "")}'
            raise ProbeError(f'probe process {self.proc.pid} quit with {_describe_exit(rc)} '
                             f'{why}\n--- probe output ({self.log_path}) ---\n'
                             f'{self.log()[-6000:]}')

    def __enter__(self) -> Probe:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
