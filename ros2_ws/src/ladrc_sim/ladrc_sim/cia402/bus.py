"""A CAN bus between processes without root: python-can-remote's server on 127.0.0.1.

The server (``python -m can_remote``) shares python-can's ``virtual`` bus over websockets; its
default host is 0.0.0.0, so it is always started with ``-H 127.0.0.1``: nothing outside
loopback. Clients open ``can.Bus('ws://127.0.0.1:PORT/', interface='remote')``. On a machine
with socketcan (``can0``, or ``vcan0`` where the kernel has the module and one is root) the same
nodes run on that instead.

:func:`start_bus_server` starts it on a free port as a subprocess, returns once it accepts a
connection; :meth:`BusServer.stop` ends it by its PID. Plain Python and the standard library, so
the tests and a bring-up can both use it (the machine-side packages do not import it).
"""

from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
import signal
import socket
import subprocess
import sys
import time

from ladrc_contract.realtime import fifo_preexec

HOST = '127.0.0.1'


@dataclass
class BusServer:
    """A running python-can-remote server: its process and the URL clients connect to."""

    process: subprocess.Popen
    port: int
    log_path: Path | None = None

    @property
    def url(self) -> str:
        """``ws://127.0.0.1:PORT/``."""
        return f'ws://{HOST}:{self.port}/'

    @property
    def pid(self) -> int:
        """The server's process id."""
        return self.process.pid

    def stop(self, timeout_s: float = 10.0) -> int | None:
        """End the server by its PID (SIGTERM, then SIGKILL); return its exit code."""
        if self.process.poll() is None:
            try:
                os.kill(self.process.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                os.kill(self.process.pid, signal.SIGKILL)
                self.process.wait(timeout_s)
        return self.process.returncode


def free_port() -> int:
    """Return a TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


def _accepts(port: int) -> bool:
    try:
        with socket.create_connection((HOST, port), timeout=1.0):
            return True
    except OSError:
        return False


def start_bus_server(log_path: Path | str | None = None, timeout_s: float = 60.0,
                     attempts: int = 3, fifo_priority: int = 51) -> BusServer:
    """Start python-can-remote on a free port of 127.0.0.1; return when it accepts.

    Its log (it logs at INFO) goes to ``log_path`` or is discarded. A port taken between the
    choice and the bind (the server exits) is retried with another, ``attempts`` times.
    ``fifo_priority``: the server (every thread: it relays each frame) runs at SCHED_FIFO, as
    the drive's and the driver's receive threads (the loops' 50 + 1), so loops at real-time
    priority elsewhere do not hold up the bus; 0 or a refusal: the normal scheduler.
    """
    last = ''
    for _ in range(attempts):
        port = free_port()
        out = open(log_path, 'ab') if log_path else subprocess.DEVNULL  # noqa: SIM115
        try:
            proc = subprocess.Popen(
                [sys.executable, '-m', 'can_remote', '-i', 'virtual', '-c', '0', '-H', HOST,
                 '-p', str(port)], stdout=out, stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                preexec_fn=fifo_preexec(fifo_priority) if fifo_priority > 0 else None)
        finally:
            if out is not subprocess.DEVNULL:
                out.close()
        server = BusServer(proc, port, Path(log_path) if log_path else None)
        limit = time.monotonic() + timeout_s
        while time.monotonic() < limit:
            if proc.poll() is not None:
                last = f'the server exited with {proc.returncode} (port {port})'
                break
            if _accepts(port):
                return server
            time.sleep(0.05)
        else:
            server.stop()
            raise TimeoutError(f'python-can-remote did not accept on {HOST}:{port} within '
                               f'{timeout_s:g} s')
    raise RuntimeError(f'python-can-remote did not start: {last}')
