"""Headless Chromium driven over its DevTools protocol (the HTML report's test and bench).

Why the DevTools protocol with ``websockets`` rather than selenium: ``websockets`` is one pure
Python package without dependencies, already a test dependency (requirements/dev.txt), and the
protocol gives what the test needs directly: the console (``Runtime.consoleAPICalled``,
``Runtime.exceptionThrown``, ``Log.entryAdded``), the requests the page makes
(``Network.requestWillBeSent``) and ``Runtime.evaluate`` awaiting a page's promise. selenium
brings trio, urllib3, certifi and more, and drives the browser through chromedriver, a process
more; its console log is DevTools' anyway.

Chromium is started with the flags below, a fresh ``--user-data-dir`` and
``--remote-debugging-port=0`` (it picks a free port on 127.0.0.1 and writes it to
``DevToolsActivePort`` in that folder: no race for a port). It is ended by its process
group's id (the group of the process started here: the browser and its children), SIGTERM
first, SIGKILL if it outlives the grace time; never by name.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import shutil
import signal
import subprocess
import time
from typing import Any

FLAGS = ('--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
         '--disable-background-networking', '--disable-component-update', '--disable-sync',
         '--disable-extensions', '--remote-debugging-address=127.0.0.1',
         '--remote-debugging-port=0')


class CdpError(RuntimeError):
    """The browser answered a command with an error, or a script threw."""


class Chromium:
    """One headless Chromium with one page; use as a context manager."""

    def __init__(self, user_data_dir: Path, width: int = 1400, height: int = 1000,
                 start_timeout_s: float = 120.0, program: str | None = None) -> None:
        self.user_data_dir = Path(user_data_dir)
        self.user_data_dir.mkdir(parents=True, exist_ok=True)
        self.program = program or shutil.which('chromium') or '/usr/bin/chromium'
        self.log_path = self.user_data_dir / 'chromium.log'
        self._log = open(self.log_path, 'wb')
        cmd = [self.program, *FLAGS, f'--user-data-dir={self.user_data_dir}',
               f'--window-size={width},{height}', 'about:blank']
        self.proc = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, start_new_session=True)
        self.events: list[dict[str, Any]] = []
        self._id = 0
        self._ws: Any = None
        try:
            self._connect(start_timeout_s)
        except BaseException:
            self.close()
            raise

    # ---- start and end --------------------------------------------------------------------
    def _connect(self, timeout_s: float) -> None:
        from websockets.sync.client import connect

        port_file = self.user_data_dir / 'DevToolsActivePort'
        deadline = time.monotonic() + timeout_s
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError(f'chromium exited {self.proc.returncode} at start: '
                                   f'{self.log_tail()}')
            try:
                port = int(port_file.read_text().split()[0])
                break
            except (OSError, ValueError, IndexError):
                if time.monotonic() > deadline:
                    raise RuntimeError(f'chromium wrote no DevToolsActivePort in {timeout_s} s: '
                                       f'{self.log_tail()}') from None
                time.sleep(0.1)
        browser = connect(f'ws://127.0.0.1:{port}{port_file.read_text().split()[1]}',
                          max_size=None, open_timeout=timeout_s)
        try:
            self._ws = browser
            target = self.call('Target.createTarget', {'url': 'about:blank'}, timeout_s)
        finally:
            browser.close()
        self._ws = connect(f'ws://127.0.0.1:{port}/devtools/page/{target["targetId"]}',
                           max_size=None, open_timeout=timeout_s)
        for domain in ('Runtime', 'Log', 'Network', 'Page'):
            self.call(f'{domain}.enable', timeout_s=timeout_s)

    def log_tail(self, n: int = 2000) -> str:
        """Return the end of the browser's own output (stdout and stderr)."""
        try:
            return self.log_path.read_bytes()[-n:].decode('utf-8', 'replace')
        except OSError:
            return ''

    def close(self, grace_s: float = 10.0) -> None:
        """End the browser: its process group by id, SIGTERM then SIGKILL."""
        if self._ws is not None:
            try:
                self._ws.close()
            except Exception:  # noqa: BLE001 (already gone)
                pass
            self._ws = None
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            try:
                self.proc.wait(grace_s)
            except subprocess.TimeoutExpired:
                pass
        try:  # the group's other processes (renderers, zygote), by the same group id
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        if self.proc.poll() is None:
            self.proc.wait()
        self._log.close()

    def __enter__(self) -> Chromium:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- the protocol -----------------------------------------------------------------------
    def call(self, method: str, params: dict[str, Any] | None = None,
             timeout_s: float = 120.0) -> dict[str, Any]:
        """Send one command; return its result (events arriving meanwhile are kept)."""
        self._id += 1
        my_id = self._id
        self._ws.send(json.dumps({'id': my_id, 'method': method, 'params': params or {}}))
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f'{method}: no answer in {timeout_s} s')
            msg = json.loads(self._ws.recv(timeout=left))
            if msg.get('id') == my_id:
                if 'error' in msg:
                    raise CdpError(f'{method}: {msg["error"]}')
                return msg.get('result', {})
            if 'method' in msg:
                self.events.append(msg)

    def wait_event(self, method: str, timeout_s: float = 120.0) -> dict[str, Any]:
        """Return the next event ``method`` (or one already received and not yet taken)."""
        for ev in self.events:
            if ev['method'] == method and not ev.get('_taken'):
                ev['_taken'] = True
                return ev
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f'no {method} in {timeout_s} s')
            msg = json.loads(self._ws.recv(timeout=left))
            if 'method' in msg:
                self.events.append(msg)
                if msg['method'] == method:
                    msg['_taken'] = True
                    return msg

    def navigate(self, url: str, timeout_s: float = 120.0) -> None:
        """Open ``url`` and wait for its load event."""
        self.call('Page.navigate', {'url': url}, timeout_s)
        self.wait_event('Page.loadEventFired', timeout_s)

    def evaluate(self, expression: str, timeout_s: float = 120.0) -> Any:
        """Return the value of a script (a promise is awaited); raise :class:`CdpError`."""
        r = self.call('Runtime.evaluate', {'expression': expression, 'awaitPromise': True,
                                           'returnByValue': True}, timeout_s)
        if 'exceptionDetails' in r:
            d = r['exceptionDetails']
            text = d.get('exception', {}).get('description') or d.get('text')
            raise CdpError(f'{expression[:80]}: {text}')
        return r['result'].get('value')

    # ---- what the page did ------------------------------------------------------------------
    def console_errors(self) -> list[str]:
        """Return the console's errors, uncaught exceptions and the log's errors (CSP, loads).

        Warnings are not errors (a browser's deprecation notes): :meth:`console_log` has them.
        """
        out = []
        for ev in self.events:
            m, p = ev['method'], ev.get('params', {})
            if m == 'Runtime.consoleAPICalled' and p.get('type') in ('error', 'assert'):
                out.append(f'console.{p["type"]}: ' + ' '.join(
                    str(a.get('value', a.get('description', ''))) for a in p.get('args', [])))
            elif m == 'Runtime.exceptionThrown':
                d = p.get('exceptionDetails', {})
                out.append('exception: ' + str(d.get('exception', {}).get('description')
                                               or d.get('text')))
            elif m == 'Log.entryAdded' and p.get('entry', {}).get('level') == 'error':
                e = p['entry']
                out.append(f'log.{e["level"]} ({e.get("source")}): {e.get("text")}')
        return out

    def console_log(self) -> list[str]:
        """Return every console message and log entry, as text (for failure messages)."""
        out = []
        for ev in self.events:
            m, p = ev['method'], ev.get('params', {})
            if m == 'Runtime.consoleAPICalled':
                out.append(f'console.{p.get("type")}: ' + ' '.join(
                    str(a.get('value', a.get('description', ''))) for a in p.get('args', [])))
            elif m == 'Log.entryAdded':
                out.append(f'log.{p["entry"].get("level")}: {p["entry"].get("text")}')
            elif m == 'Runtime.exceptionThrown':
                out.append(f'exception: {p.get("exceptionDetails", {}).get("text")}')
        return out

    def requests(self) -> list[str]:
        """Return the URLs the page requested (the page itself included)."""
        return [ev['params']['request']['url'] for ev in self.events
                if ev['method'] == 'Network.requestWillBeSent']
