"""LinuxCNC as a process of a run: its configuration rendered for the run, started, stopped.

One LinuxCNC runs per machine (its ``/tmp/linuxcnc.lock``, its NML and HAL shared memory), so:

* **one at a time**: :class:`LinuxCnc` takes the lock file :data:`LOCK_PATH` (``flock``, waited
  for) before it starts LinuxCNC and holds it until LinuxCNC is down and cleaned; the lock file
  names the run (its session, its INI), so a run whose owner died (SIGKILL) is found and ended
  by the next one, by its process ids. A LinuxCNC that is not one of ours is never touched: the
  start is refused in one line;
* **ended by process id**: :meth:`LinuxCnc.stop` asks the display to exit (LinuxCNC's own
  shutdown then runs: its ``Cleanup`` stops HAL and removes its shared memory); what is still
  there after ``timeout_s`` is SIGKILLed by PID (the session's processes and the ones naming
  the run's INI: ``linuxcncsvr`` leaves the session), then the shared memory is removed
  (:func:`clean_shared_memory`: LinuxCNC 2.9's ``realtime stop`` keys and its NML file's);
* **as root** (CI): ``rtapi_app`` refuses to run as root without ``RTAPI_UID`` (a non-root
  uid: nobody's) and ``RTAPI_FIFO_PATH`` (its socket, in a folder that uid may write:
  a private 0777 folder under /tmp; the default in root's home is not writable by it).

The run's configuration (:func:`render_run_config`) is the shipped machine configuration
(``config/ladrc_xy.ini``, ``.hal``, ``.tbl``, ``.var``, ``.nml``) with the keys of a run set:
the absolute paths of the display, the filter, the HAL component and its socket, the program,
the subroutines (``config/subroutines``: ``[RS274NGC]SUBROUTINE_PATH``), the home position (the
job's start), the G54 work offset (where the program's origin lies on the sheet: ``#5221``,
``#5222`` of the parameter file) and the job's rapid feed and acceleration. It is written into
the run's folder with everything LinuxCNC writes back (the parameter file).

Plain standard library (the venv's Python): the LinuxCNC side runs on the system's Python.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import fcntl
import json
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from typing import Any

PACKAGE_DIR = Path(__file__).resolve().parent
LOCK_PATH = Path('/tmp/ladrc-linuxcnc.lock')
LINUXCNC_LOCK = Path('/tmp/linuxcnc.lock')
SYSTEM_PYTHON = os.environ.get('LADRC_LINUXCNC_PYTHON', '/usr/bin/python3')
"""The interpreter LinuxCNC's Python modules are built for (Debian's own python3)."""
HAL_KEYS = ('0x48414c32', '0x90280A48', '0x48484c34')
"""HAL, RTAPI and UUID shared memory keys (LinuxCNC 2.9's ``realtime stop`` removes them)."""
NOBODY_UID = 65534
RUN_MARK = 'LADRC_LINUXCNC_RUN'
"""The environment variable that marks every process of a run (its INI's path)."""


class LinuxCncError(RuntimeError):
    """LinuxCNC cannot run or did not come up; the message is one line."""


def config_dir() -> Path:
    """Return the shipped machine configuration (install space, else the source tree)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        path = Path(get_package_share_directory('ladrc_linuxcnc')) / 'config'
        if (path / 'ladrc_xy.ini').is_file():
            return path
    except (ImportError, LookupError, ValueError):
        pass
    return PACKAGE_DIR.parent / 'config'


def missing() -> str:
    """Return why LinuxCNC cannot run here ('' when it can)."""
    for prog in ('linuxcnc', 'halcmd'):
        if shutil.which(prog) is None:
            return (f'{prog} is not on PATH: LinuxCNC is not installed (Debian: apt-get install '
                    '-y --no-install-recommends linuxcnc-uspace)')
    try:
        r = subprocess.run([SYSTEM_PYTHON, '-c', 'import linuxcnc, hal, gcode'],
                           capture_output=True, text=True, timeout=30, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f'{SYSTEM_PYTHON}: {exc}'
    if r.returncode != 0:
        last = (r.stderr.strip().splitlines() or ['?'])[-1]
        return (f"{SYSTEM_PYTHON} cannot import LinuxCNC's modules ({last}): they are built "
                'for the system Python (set LADRC_LINUXCNC_PYTHON to it)')
    return ''


# ---- the run's configuration -----------------------------------------------------------------
def set_ini_keys(text: str, values: dict[tuple[str, str], Any]) -> str:
    """Return INI ``text`` with ``(section, key) -> value`` set (the first occurrence of each).

    A key not in its section is added at the section's end; a section not in the text is
    added at the end. Comments and the order of the rest stay.
    """
    lines = text.splitlines()
    todo = dict(values)
    out: list[str] = []
    section = ''

    def flush(sec: str) -> None:
        for (s, k) in [sk for sk in todo if sk[0] == sec]:
            out.append(f'{k} = {todo.pop((s, k))}')

    for line in lines:
        stripped = line.strip()
        if stripped.startswith('[') and stripped.endswith(']'):
            flush(section)
            section = stripped[1:-1]
        elif '=' in stripped and not stripped.startswith(('#', ';')):
            key = stripped.split('=', 1)[0].strip()
            if (section, key) in todo:
                out.append(f'{key} = {todo.pop((section, key))}')
                continue
        out.append(line)
    flush(section)
    for sec in sorted({s for s, _ in todo}):
        out.append(f'[{sec}]')
        flush(sec)
    return '\n'.join(out) + '\n'


@dataclass(frozen=True)
class RunSettings:
    """What a run sets in the machine configuration (mm, mm/s, mm/s², s)."""

    program: Path
    home_xy_mm: tuple[float, float] = (0.0, 0.0)
    work_offset_mm: tuple[float, float] = (0.0, 0.0)  # G54: the program's origin on the sheet
    rapid_mm_s: float = 500.0
    accel_mm_s2: float = 2000.0
    exit_at_end: bool = False
    ready_timeout_s: float = 120.0
    component_priority: int = 0   # SCHED_FIFO of the bridge's HAL component (0: normal)
    servo_priority: int = 0       # SCHED_FIFO of LinuxCNC's servo thread (0: as LinuxCNC runs it)
    watchdog_s: float = 0.5
    extra: dict[tuple[str, str], Any] = field(default_factory=dict)


def _wrapper(path: Path, script: Path) -> Path:
    """Write an executable that runs ``script`` on the system Python (LinuxCNC runs it)."""
    path.write_text(f'#!/bin/sh\nexec {SYSTEM_PYTHON} {script} "$@"\n', encoding='utf-8')
    path.chmod(0o755)
    return path


def render_run_config(run_dir: Path, s: RunSettings) -> Path:
    """Write the run's machine configuration into ``run_dir``; return its INI."""
    run_dir = Path(run_dir).resolve()
    run_dir.mkdir(parents=True, exist_ok=True)
    src = config_dir()
    for name in ('ladrc_xy.tbl', 'ladrc_xy.nml'):
        shutil.copyfile(src / name, run_dir / name)
    # the parameter file: the G54 offset (#5221 X, #5222 Y, machine units: mm; ascending)
    ox, oy = (float(v) for v in s.work_offset_mm)
    (run_dir / 'ladrc_xy.var').write_text(f'5221\t{ox:.6f}\n5222\t{oy:.6f}\n',
                                          encoding='utf-8')
    display = _wrapper(run_dir / 'ladrc-headless-display', PACKAGE_DIR / 'display.py')
    zfilter = _wrapper(run_dir / 'ladrc-z-filter', PACKAGE_DIR / 'z_filter.py')
    socket_dir = Path(tempfile.mkdtemp(prefix='ladrc-lcnc-', dir='/tmp'))  # short: AF_UNIX
    x, y = s.home_xy_mm
    v, a = float(s.rapid_mm_s), float(s.accel_mm_s2)
    values: dict[tuple[str, str], Any] = {
        ('EMC', 'NML_FILE'): run_dir / 'ladrc_xy.nml',
        ('DISPLAY', 'DISPLAY'): display,
        ('FILTER', 'ngc'): zfilter, ('FILTER', 'nc'): zfilter, ('FILTER', 'tap'): zfilter,
        ('RS274NGC', 'PARAMETER_FILE'): run_dir / 'ladrc_xy.var',
        ('RS274NGC', 'SUBROUTINE_PATH'): src / 'subroutines',
        ('EMCIO', 'TOOL_TABLE'): run_dir / 'ladrc_xy.tbl',
        ('HAL', 'HALFILE'): src / 'ladrc_xy.hal',
        ('TRAJ', 'MAX_LINEAR_VELOCITY'): v, ('TRAJ', 'MAX_LINEAR_ACCELERATION'): a,
        ('TRAJ', 'DEFAULT_LINEAR_ACCELERATION'): a,
        ('LADRC', 'COMPONENT'): PACKAGE_DIR / 'hal_component.py',
        ('LADRC', 'SOCKET'): socket_dir / 'bridge.sock',
        ('LADRC', 'PRIORITY'): int(s.component_priority),
        ('LADRC', 'WATCHDOG_S'): float(s.watchdog_s),
        ('LADRC', 'SERVO_PRIORITY'): int(s.servo_priority),
        ('LADRC', 'PROGRAM'): Path(s.program).resolve(),
        ('LADRC', 'STATUS_FILE'): run_dir / 'display.jsonl',
        ('LADRC', 'READY_TIMEOUT_S'): float(s.ready_timeout_s),
        ('LADRC', 'EXIT_AT_END'): int(bool(s.exit_at_end)),
        ('JOINT_0', 'HOME'): float(x), ('JOINT_1', 'HOME'): float(y),
    }
    for axis, joint in (('AXIS_X', 'JOINT_0'), ('AXIS_Y', 'JOINT_1')):
        values.update({(axis, 'MAX_VELOCITY'): v, (axis, 'MAX_ACCELERATION'): a,
                       (joint, 'MAX_VELOCITY'): v, (joint, 'MAX_ACCELERATION'): a})
    values.update(s.extra)
    text = set_ini_keys((src / 'ladrc_xy.ini').read_text(encoding='utf-8'), values)
    ini = run_dir / 'ladrc_xy.ini'
    ini.write_text(text, encoding='utf-8')
    return ini


def ini_value(ini: Path, section: str, key: str) -> str:
    """Return the first value of ``[section] key`` in an INI file ('' if none)."""
    current = ''
    for line in Path(ini).read_text(encoding='utf-8').splitlines():
        t = line.strip()
        if t.startswith('[') and t.endswith(']'):
            current = t[1:-1]
        elif current == section and '=' in t and not t.startswith(('#', ';')):
            k, v = t.split('=', 1)
            if k.strip() == key:
                return v.strip()
    return ''


# ---- processes -------------------------------------------------------------------------------
def _proc_stat(pid: int) -> tuple[int, int] | None:
    """Return (pgid, sid) of a live, non-zombie process, or None."""
    try:
        text = Path(f'/proc/{pid}/stat').read_text()
    except OSError:
        return None
    rest = text[text.rindex(')') + 2:].split()
    if rest[0] == 'Z':
        return None
    return int(rest[2]), int(rest[3])


def _cmdline(pid: int) -> str:
    try:
        return Path(f'/proc/{pid}/cmdline').read_bytes().replace(b'\0', b' ').decode(
            errors='replace')
    except OSError:
        return ''


def _marked(pid: int, marker: bytes) -> bool:
    """Return whether a process's environment holds ``marker`` (its run's)."""
    try:
        return marker in Path(f'/proc/{pid}/environ').read_bytes().split(b'\0')
    except OSError:
        return False


def run_processes(session: int, ini: str) -> list[int]:
    """Return the live processes of a run.

    Its session's, those naming its INI, and those whose environment carries the run's mark
    (:data:`RUN_MARK`): ``rtapi_app`` and ``linuxcncsvr`` leave the session and name no INI.
    """
    marker = f'{RUN_MARK}={ini}'.encode() if ini else b''
    out = []
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit():
            continue
        pid = int(entry.name)
        st = _proc_stat(pid)
        if st is None or pid == os.getpid():
            continue
        if st[1] == session or (ini and (ini in _cmdline(pid) or _marked(pid, marker))):
            out.append(pid)
    return sorted(out)


def _running_named(name: str) -> bool:
    """Return whether a process with this command name exists (nothing is done to it)."""
    for entry in Path('/proc').iterdir():
        if entry.name.isdigit():
            try:
                if (entry / 'comm').read_text().strip() == name and _proc_stat(
                        int(entry.name)) is not None:
                    return True
            except OSError:
                continue
    return False


def clean_shared_memory(nml: Path | None) -> list[str]:
    """Remove LinuxCNC's shared memory segments when no rtapi_app runs; return the keys gone."""
    if _running_named('rtapi_app'):
        return []
    keys = list(HAL_KEYS)
    try:
        for line in Path(nml or '/usr/share/linuxcnc/linuxcnc.nml').read_text().splitlines():
            f = line.split()
            if len(f) >= 10 and f[0] == 'B' and f[2] == 'SHMEM':
                keys.append(f[9])
    except OSError:
        pass
    gone = []
    for key in keys:
        r = subprocess.run(['ipcrm', '-M', key], capture_output=True, check=False)
        if r.returncode == 0:
            gone.append(key)
    return gone


def rtapi_env(run_dir: Path, ini: Path | None = None) -> dict[str, str]:
    """Return the environment LinuxCNC runs in (root: RTAPI_UID and RTAPI_FIFO_PATH).

    With ``ini``, the run's mark (:data:`RUN_MARK`), which every process inherits.
    """
    env = dict(os.environ)
    if ini is not None:
        env[RUN_MARK] = str(ini)
    if os.geteuid() == 0:
        # rtapi_app runs as RTAPI_UID: its socket's folder must be one that uid can reach
        # (/tmp/ladrc-rtapi-*, 0777; a run's folder may sit under a private one, e.g. pytest's)
        link = Path(run_dir) / 'rtapi'
        if link.is_symlink():
            fifo_dir = link.resolve()
        else:
            fifo_dir = Path(tempfile.mkdtemp(prefix='ladrc-rtapi-', dir='/tmp'))
            link.unlink(missing_ok=True)
            link.symlink_to(fifo_dir)
        fifo_dir.chmod(0o777)
        env['RTAPI_UID'] = env.get('RTAPI_UID', str(NOBODY_UID))
        env['RTAPI_FIFO_PATH'] = str(fifo_dir / 'rtapi_fifo')
    return env


class LinuxCnc:
    """One LinuxCNC run (module docstring): ``start()``, ``stop()``, ``kill()``."""

    def __init__(self, ini: Path, log_path: Path | None = None) -> None:
        self.ini = Path(ini).resolve()
        self.run_dir = self.ini.parent
        self.status_file = Path(ini_value(self.ini, 'LADRC', 'STATUS_FILE')
                                or self.run_dir / 'display.jsonl')
        self.socket_path = ini_value(self.ini, 'LADRC', 'SOCKET')
        self.log_path = log_path or self.run_dir / 'linuxcnc.log'
        self.env = rtapi_env(self.run_dir, self.ini)
        self.proc: subprocess.Popen | None = None
        self._lock_fd: int | None = None
        self.cleaned: list[str] = []
        self.servo_threads: list[str] = []

    # ---- the lock ------------------------------------------------------------------------------
    def _take_lock(self, wait_s: float) -> None:
        fd = os.open(LOCK_PATH, os.O_RDWR | os.O_CREAT, 0o644)
        end = time.monotonic() + wait_s
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > end:
                    os.close(fd)
                    raise LinuxCncError(f'another run holds {LOCK_PATH} (one LinuxCNC per '
                                        f'machine) for more than {wait_s:g} s') from None
                time.sleep(0.5)
        self._lock_fd = fd
        try:
            previous = json.loads(os.pread(fd, 4096, 0).decode() or '{}')
        except (ValueError, OSError):
            previous = {}
        self._end_orphan(previous)
        if LINUXCNC_LOCK.exists():
            if _running_named('rtapi_app') or _running_named('milltask'):
                self._release_lock()
                raise LinuxCncError(f"a LinuxCNC that is not this project's runs "
                                    f'({LINUXCNC_LOCK} and its processes): stop it first')
            LINUXCNC_LOCK.unlink(missing_ok=True)  # left by a LinuxCNC that is gone
        self.cleaned += clean_shared_memory(None)

    def _end_orphan(self, previous: dict) -> None:
        """End the LinuxCNC of a run of ours whose owner died (its lock was released)."""
        session, ini = int(previous.get('session', 0) or 0), str(previous.get('ini', ''))
        if session <= 0:
            return
        pids = run_processes(session, ini)
        if pids:
            print(f'ladrc_linuxcnc: ending a LinuxCNC left by a run that died ({ini}): '
                  f'pids {pids}', file=sys.stderr)
            for pid in pids:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            self._wait_gone(session, ini, 10.0)
        LINUXCNC_LOCK.unlink(missing_ok=True)
        self.cleaned += clean_shared_memory(Path(previous.get('nml') or '') or None)

    def _write_lock(self) -> None:
        if self._lock_fd is None or self.proc is None:
            return
        record = json.dumps({'session': self.proc.pid, 'ini': str(self.ini),
                             'nml': ini_value(self.ini, 'EMC', 'NML_FILE'),
                             'owner': os.getpid()}).encode()
        os.ftruncate(self._lock_fd, 0)
        os.pwrite(self._lock_fd, record, 0)

    def _release_lock(self) -> None:
        if self._lock_fd is not None:
            try:
                os.ftruncate(self._lock_fd, 0)
            except OSError:
                pass
            fcntl.flock(self._lock_fd, fcntl.LOCK_UN)
            os.close(self._lock_fd)
            self._lock_fd = None

    # ---- start -----------------------------------------------------------------------------
    def start(self, timeout_s: float = 120.0, lock_wait_s: float = 900.0) -> None:
        """Start LinuxCNC and wait until its display has the program open (``ready``).

        Raises :class:`LinuxCncError` (one line; LinuxCNC stopped again) if it does not come up.
        """
        why = missing()
        if why:
            raise LinuxCncError(why)
        self._take_lock(lock_wait_s)
        self.status_file.unlink(missing_ok=True)
        log = open(self.log_path, 'ab')  # noqa: SIM115 (the child keeps it)
        try:
            self.proc = subprocess.Popen(['linuxcnc', str(self.ini)], cwd=self.run_dir,
                                         env=self.env, stdin=subprocess.DEVNULL, stdout=log,
                                         stderr=subprocess.STDOUT, start_new_session=True)
        except OSError as exc:
            self._release_lock()
            raise LinuxCncError(f'cannot start linuxcnc: {exc}') from None
        finally:
            log.close()
        self._write_lock()
        try:
            self.wait_event('ready', timeout_s)
        except LinuxCncError:
            self.stop()
            raise
        prio = int(ini_value(self.ini, 'LADRC', 'SERVO_PRIORITY') or 0)
        self.servo_threads = self.set_servo_priority(prio) if prio > 0 else []

    def set_servo_priority(self, priority: int) -> list[str]:
        """Run LinuxCNC's real-time threads (``rtapi_app:T#n``) at SCHED_FIFO ``priority``.

        Without a PREEMPT_RT kernel LinuxCNC 2.9 runs them at the normal scheduler ("POSIX
        non-realtime"); beside SCHED_FIFO loops on two cores its servo thread then waits for
        them. Returns what was set (``name tid``), or why not.
        """
        out = []
        for pid in self.pids():
            for task in Path(f'/proc/{pid}/task').glob('*'):
                try:
                    name = (task / 'comm').read_text().strip()
                except OSError:
                    continue
                if name.startswith('rtapi_app:T#'):
                    from ladrc_contract.realtime import schedule_task

                    why = schedule_task(int(task.name), priority)
                    out.append(f'{name} {task.name}: {why}' if why else
                               f'{name} {task.name} SCHED_FIFO {priority}')
        return out

    def events(self) -> list[dict]:
        """Return the display's events so far (its status file)."""
        try:
            text = self.status_file.read_text(encoding='utf-8')
        except OSError:
            return []
        out = []
        for line in text.splitlines():
            try:
                out.append(json.loads(line))
            except ValueError:
                continue
        return out

    def wait_event(self, name: str, timeout_s: float) -> dict:
        """Wait for the display's event ``name``; raise LinuxCncError on an error or exit."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            for ev in self.events():
                if ev.get('event') == name:
                    return ev
                if ev.get('event') == 'error':
                    raise LinuxCncError(f'LinuxCNC: {ev.get("text", "")}')
            if self.proc is not None and self.proc.poll() is not None:
                raise LinuxCncError(f'linuxcnc exited ({self.proc.returncode}) before '
                                    f'{name!r}: {self.log_tail()}')
            time.sleep(0.1)
        raise LinuxCncError(f'LinuxCNC: no {name!r} within {timeout_s:g} s: {self.log_tail()}')

    def log_tail(self, n: int = 600) -> str:
        """Return the end of LinuxCNC's output, one line."""
        text = ''
        for path in [self.log_path, *sorted(Path('/tmp').glob('linuxcnc.print.*'))]:
            try:
                text += Path(path).read_text(errors='replace')[-n:]
            except OSError:
                continue
        return ' '.join(text.split())[-n:]

    # ---- inside ------------------------------------------------------------------------------
    def pids(self) -> list[int]:
        """Return the live processes of this LinuxCNC."""
        if self.proc is None:
            return []
        return run_processes(self.proc.pid, str(self.ini))

    def halcmd(self, *args: str, timeout_s: float = 10.0) -> subprocess.CompletedProcess:
        """Run ``halcmd ARGS`` against this LinuxCNC's HAL."""
        return subprocess.run(['halcmd', *args], env=self.env, capture_output=True, text=True,
                              timeout=timeout_s, check=False)

    # ---- the end -------------------------------------------------------------------------------
    def _wait_gone(self, session: int, ini: str, timeout_s: float) -> list[int]:
        end = time.monotonic() + timeout_s
        while True:
            left = run_processes(session, ini)
            if not left or time.monotonic() > end:
                return left
            time.sleep(0.1)

    def kill(self) -> list[int]:
        """SIGKILL every process of this LinuxCNC at once (a crash); return their pids."""
        pids = self.pids()
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        return pids

    def stop(self, timeout_s: float = 30.0) -> dict[str, Any]:
        """Shut LinuxCNC down (display first, LinuxCNC's own clean-up), then by PID; clean.

        Returns what it took: ``orderly`` (LinuxCNC's own shutdown ended it), ``killed`` (pids
        SIGKILLed after ``timeout_s``), ``shm_removed`` (keys removed here).
        """
        out: dict[str, Any] = {'orderly': False, 'killed': [], 'shm_removed': []}
        try:
            if self.proc is None:
                return out
            session = self.proc.pid
            if self.proc.poll() is None:
                display = next((ev.get('pid') for ev in self.events()
                                if ev.get('event') == 'start'), None)
                if display and display in self.pids():
                    os.kill(display, signal.SIGTERM)  # the display ends, linuxcnc cleans up
                else:
                    os.kill(session, signal.SIGTERM)  # its trap runs Cleanup
                try:
                    self.proc.wait(timeout=timeout_s)
                    out['orderly'] = True
                except subprocess.TimeoutExpired:
                    pass
            left = self._wait_gone(session, str(self.ini), 2.0 if out['orderly'] else 0.0)
            for pid in left:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            out['killed'] = left
            if self.proc.poll() is None:
                self.proc.wait(timeout=10)
            self._wait_gone(session, str(self.ini), 10.0)
            nml = ini_value(self.ini, 'EMC', 'NML_FILE')
            out['shm_removed'] = clean_shared_memory(Path(nml) if nml else None)
            if not _running_named('milltask'):
                LINUXCNC_LOCK.unlink(missing_ok=True)
            if self.socket_path:
                shutil.rmtree(Path(self.socket_path).parent, ignore_errors=True)
            fifo = self.env.get('RTAPI_FIFO_PATH')
            if fifo and Path(fifo).parent.name.startswith('ladrc-rtapi-'):
                shutil.rmtree(Path(fifo).parent, ignore_errors=True)
            return out
        finally:
            self._release_lock()


def read_program(path: str | Path, ini: str | Path | None = None,
                 timeout_s: float = 120.0) -> dict[str, Any]:
    """Return a program's path as LinuxCNC's own interpreter reads it (:mod:`.gcode_path`).

    Runs on the system Python (LinuxCNC's ``gcode`` module); ``ini``: a running LinuxCNC's
    INI (its tool table: a program with T words needs it). Raises :class:`LinuxCncError`, one
    line, when the interpreter cannot run or crashes.
    """
    env = dict(os.environ)
    env['INI_FILE_NAME'] = str(ini) if ini else '/dev/null'
    if ini:
        env.update({k: v for k, v in rtapi_env(Path(ini).parent).items()
                    if k.startswith('RTAPI_')})
    try:
        # the interpreter writes its parameter file (rs274ngc.var) where it runs: not here
        with tempfile.TemporaryDirectory(prefix='ladrc-gcode-') as scratch:
            r = subprocess.run([SYSTEM_PYTHON, str(PACKAGE_DIR / 'gcode_path.py'),
                                str(Path(path).resolve())], capture_output=True, text=True,
                               timeout=timeout_s, env=env, check=False, cwd=scratch)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise LinuxCncError(f"LinuxCNC's interpreter on {path}: {exc}") from None
    if r.returncode != 0 or not r.stdout.strip():
        how = (f'signal {-r.returncode}' if r.returncode < 0 else f'exit {r.returncode}')
        raise LinuxCncError(f"LinuxCNC's interpreter on {path}: {how} "
                            f"{' '.join(r.stderr.split())[-300:]}".rstrip())
    return json.loads(r.stdout.strip().splitlines()[-1])
