"""Evidence for the stall repros (bench/repro/*.py): what stalled, for how long, and why.

Three sources, all on one clock (CLOCK_MONOTONIC, shared by every process of the machine):

* **In-process trace** (:func:`site_dir`): a ``sitecustomize`` put on the ``PYTHONPATH`` of the
  commands the repros run (pytest, the node processes, the conformance kit) when
  ``LADRC_TRACE_DIR`` is set. The checkout's code is not edited: after a module of the product
  is imported, a few of its functions are wrapped, and each process appends JSON lines to
  ``<dir>/trace-<pid>.jsonl`` for rare events only (nothing on the 2 kHz path but a clock read
  and a comparison):
  - every garbage collection longer than 0.5 ms, and the collection counts (gc callbacks);
  - what ``apply_realtime`` granted, and each thread's scheduling policy right after;
  - follow node: a tick later than 3 ms after the one before (period), a tick or callback
    longer than 2 ms (parameter set callback, services, diagnostics), each state change with
    its fault reason;
  - sim node (and the broken driver built on it): a drive cycle later than 3 ms, a gap of
    more than 3 ms between two velocity commands received (with their ``seq``: none sent, or
    lost), each change of the drive's fault reason (the watchdog);
  - conformance kit: a gap of more than 2 ms between two commands sent, a ``poll`` longer than
    2 ms, the abort reason;
  - the test's probe (tests/support/rosnodes.py): each service call (a new client: DDS
    discovery of a new endpoint) with its start and end, each node process started.
* **Scheduler monitor** (:class:`Monitor`): every 50 ms, each thread of the processes of
  interest from ``/proc/<pid>/task/<tid>/schedstat`` (time on a CPU, time runnable but waiting
  for one) and ``stat`` (policy, priority). A window in which a loop thread waited for a CPU
  for more than 2 ms is kept with the CPU time every watched process used in it (who ran).
* **Machine**: steal time, load, the CPU used by processes the repro did not start.

:func:`timeline` merges the traces and the monitor's windows around a moment (a fault).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import threading
import time

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
from stalls import cpu_jiffies, start_busy_loops, stop_busy_loops  # noqa: E402,F401

# ---- clean environments ----------------------------------------------------------------------
_DROP = ('AMENT_PREFIX_PATH', 'CMAKE_PREFIX_PATH', 'COLCON_PREFIX_PATH', 'LADRC_ROOT',
         'LD_LIBRARY_PATH', 'PS1', 'PYTHONPATH', 'VIRTUAL_ENV', 'VIRTUAL_ENV_PROMPT',
         'ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_LOCALHOST_ONLY',
         '_ROS_WHEELS_BOOTSTRAP_COMPLETE')


def clean_env(**extra: str) -> dict[str, str]:
    """Return the environment without any checkout's venv/ROS set-up (in-env adds its own)."""
    env = {k: v for k, v in os.environ.items() if k not in _DROP}
    env['PATH'] = ':'.join(p for p in env.get('PATH', '').split(':')
                           if '/.venv/' not in p + '/' and '/ros2_ws/' not in p)
    env['PYTHONUNBUFFERED'] = '1'
    env.update(extra)
    return env


def in_env(checkout: Path, *cmd: str) -> list[str]:
    """Return the argv that runs ``cmd`` in ``checkout``'s environment (``scripts/in-env``)."""
    return [str(checkout / 'scripts' / 'in-env'), *cmd]


# ---- the in-process trace ------------------------------------------------------------------
SITECUSTOMIZE = r'''
"""bench/repro/_trace.py: trace rare events of the product's processes (LADRC_TRACE_DIR)."""
import os as _os
if _os.environ.get('LADRC_TRACE_DIR'):
    def _install():
        import gc, importlib.abc, importlib.machinery, json, sys, time, threading
        d = _os.environ['LADRC_TRACE_DIR']
        fd = _os.open(_os.path.join(d, 'trace-%d.jsonl' % _os.getpid()),
                      _os.O_WRONLY | _os.O_CREAT | _os.O_APPEND, 0o644)
        mono = time.monotonic_ns

        def log(kind, **kw):
            kw['t'] = mono() * 1e-9
            kw['wall'] = time.time()
            kw['kind'] = kind
            kw['pid'] = _os.getpid()
            try:
                _os.write(fd, (json.dumps(kw, default=str) + '\n').encode())
            except Exception:
                pass

        try:
            with open('/proc/self/cmdline', 'rb') as f:
                cmdline = f.read().replace(b'\0', b' ').decode(errors='replace')[:300]
        except Exception:
            cmdline = ''
        log('start', argv=sys.argv[:6], cmdline=cmdline)
        gcs = {'start': 0, 'n': [0, 0, 0], 'long': 0, 'dumped': mono()}

        def on_gc(phase, info):
            now = mono()
            if phase == 'start':
                gcs['start'] = now
                return
            g = info['generation']
            gcs['n'][g] += 1
            ms = (now - gcs['start']) * 1e-6
            if ms > 0.5:
                gcs['long'] += 1
                log('gc', generation=g, ms=round(ms, 3), collected=info.get('collected'))
            if now - gcs['dumped'] > 5e9:
                gcs['dumped'] = now
                log('gc_counts', counts=list(gcs['n']), long=gcs['long'])
        gc.callbacks.append(on_gc)
        import atexit
        atexit.register(lambda: log('gc_counts', counts=list(gcs['n']), long=gcs['long'],
                                    at_exit=True))

        def policies():
            out = {}
            for tid in sorted(_os.listdir('/proc/self/task')):
                try:
                    with open('/proc/self/task/%s/stat' % tid) as f:
                        s = f.read()
                    comm = s[s.index('(') + 1:s.rindex(')')]
                    fields = s.rsplit(')', 1)[1].split()
                    out[tid] = '%s:%s/%s' % (comm, {'0': 'OTHER', '1': 'FIFO', '2': 'RR'}.get(
                        fields[38], fields[38]), fields[37])
                except Exception:
                    pass
            return out

        def wrap_realtime(mod):
            orig = mod.apply_realtime

            def apply_realtime(*a, **k):
                res = orig(*a, **k)
                log('realtime', args=a, applied=res[0], warnings=res[1], threads=policies())
                return res
            mod.apply_realtime = apply_realtime

        def timed(cls, name, limit_ms, kind):
            orig = getattr(cls, name)

            def f(self, *a, **k):
                t0 = mono()
                try:
                    return orig(self, *a, **k)
                finally:
                    ms = (mono() - t0) * 1e-6
                    if ms > limit_ms:
                        log(kind, fn=name, ms=round(ms, 3))
            setattr(cls, name, f)

        def patch_follow(mod):
            wrap_realtime(mod)
            N = mod.FollowNode
            orig_tick = N.tick
            st = {'last': 0, 'state': None}

            def tick(self, *a, **k):
                t0 = mono()
                orig_tick(self, *a, **k)
                t1 = mono()
                last = st['last']
                st['last'] = t0
                if last and t0 - last > 3_000_000:
                    log('follow_late_tick', period_ms=round((t0 - last) * 1e-6, 3),
                        tick=self.tick_index, input_age_ms=round(
                            (t0 - self._t0_ns) * 1e-6 - 1e3 * min(self.gap_stamp_s,
                                                                  self.enc_stamp_s), 3))
                if t1 - t0 > 2_000_000:
                    log('follow_long_tick', ms=round((t1 - t0) * 1e-6, 3), tick=self.tick_index)
                c = self.controller
                if c.state is not st['state']:
                    st['state'] = c.state
                    log('follow_state', state=getattr(c.state, 'name', str(c.state)),
                        reason=c.fault_reason or '', tick=self.tick_index,
                        drive_fault=self.drive_fault, drive_enabled=self.drive_enabled)
            N.tick = tick
            orig_set = N._on_set_parameters

            def on_set(self, parameters):
                t0 = mono()
                res = orig_set(self, parameters)
                log('follow_set_parameters', ms=round((mono() - t0) * 1e-6, 3),
                    names=[p.name for p in parameters], ok=res.successful)
                return res
            N._on_set_parameters = on_set
            for name in dir(N):
                if name.startswith('_srv_'):
                    timed(N, name, 2.0, 'follow_long_callback')
            timed(N, '_publish_diagnostics', 2.0, 'follow_long_callback')

        def patch_sim(mod):
            wrap_realtime(mod)
            B = mod.DriveBridge
            orig_step, orig_cmd = B.step, B.on_command
            st = {'last': 0, 'reason': '', 'cmd_t': 0, 'cmd_seq': -1}

            def step(self, tick):
                u = orig_step(self, tick)
                now = self._last_tick_ns
                last = st['last']
                st['last'] = now
                if last and now - last > 3_000_000:
                    log('sim_late_cycle', period_ms=round((now - last) * 1e-6, 3),
                        seq=self.seq, late_ticks=self.late_ticks)
                if bool(self.fault_reason) != bool(st['reason']):
                    st['reason'] = self.fault_reason
                    log('sim_fault', reason=self.fault_reason, seq=self.seq,
                        ms_since_command=round((mono() - self.last_cmd_ns) * 1e-6, 3)
                        if self.last_cmd_ns else None, late_ticks=self.late_ticks)
                return u

            def on_command(self, msg):
                now = mono()
                last, lseq = st['cmd_t'], st['cmd_seq']
                st['cmd_t'], st['cmd_seq'] = now, msg.seq
                if last and now - last > 3_000_000:
                    log('sim_command_gap', ms=round((now - last) * 1e-6, 3),
                        seq_before=lseq, seq=msg.seq,
                        stamp_age_ms=round((time.time_ns() - msg.header.stamp.sec * 10**9
                                            - msg.header.stamp.nanosec) * 1e-6, 3))
                return orig_cmd(self, msg)
            B.step, B.on_command = step, on_command

        def patch_conform(mod):
            P = mod.ConformProbe
            orig_send = P._send
            st = {'last': 0}

            def send(self, v, enable):
                now = mono()
                last = st['last']
                st['last'] = now
                if last and now - last > 2_000_000:
                    log('kit_send_gap', ms=round((now - last) * 1e-6, 3), seq=self._cmd_seq)
                return orig_send(self, v, enable)
            P._send = send
            timed(P, 'poll', 2.0, 'kit_long_poll')
            orig_abort = P._abort

            def abort(self, reason):
                log('kit_abort', reason=reason)
                return orig_abort(self, reason)
            P._abort = abort

        def patch_rosnodes(mod):
            P = mod.Probe
            orig_call = P.call

            def call(self, srv_type, name, request, timeout_s=10.0):
                new = name not in self._clients
                log('probe_call_start', service=name, new_client=new)
                try:
                    return orig_call(self, srv_type, name, request, timeout_s)
                finally:
                    log('probe_call_end', service=name)
            P.call = call
            NP = mod.NodeProcesses
            orig_start = NP.start

            def start(self, name, *a):
                p = orig_start(self, name, *a)
                log('node_started', name=name, child=p.pid, logdir=str(self.logdir))
                return p
            NP.start = start

        def patch_realtime(mod):
            wrap_realtime(mod)

        patches = {'ladrc_follow.node.follow_node': patch_follow,
                   'ladrc_sim.node.sim_node': patch_sim,
                   'ladrc_tools.node.conform_node': patch_conform,
                   'ladrc_contract.realtime': patch_realtime,
                   'rosnodes': patch_rosnodes}

        class Finder(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path, target=None):
                if name not in patches:
                    return None
                for finder in sys.meta_path:
                    if finder is self:
                        continue
                    spec = finder.find_spec(name, path, target) if hasattr(
                        finder, 'find_spec') else None
                    if spec is not None and spec.loader is not None:
                        loader = spec.loader
                        orig_exec = loader.exec_module

                        def exec_module(module, _orig=orig_exec, _name=name):
                            _orig(module)
                            try:
                                patches[_name](module)
                                log('patched', module=_name)
                            except Exception as exc:
                                log('patch_failed', module=_name, error=repr(exc))
                        loader.exec_module = exec_module
                        return spec
                return None
        sys.meta_path.insert(0, Finder())
    try:
        _install()
    except Exception as _exc:  # never break the traced program
        print('sitecustomize trace: %r' % (_exc,), file=__import__('sys').stderr)
'''


def site_dir(folder: Path) -> Path:
    """Write the tracing ``sitecustomize.py`` into ``folder/site``; return that folder."""
    d = folder / 'site'
    d.mkdir(parents=True, exist_ok=True)
    (d / 'sitecustomize.py').write_text(SITECUSTOMIZE, encoding='utf-8')
    return d


def trace_env(folder: Path, **extra: str) -> dict[str, str]:
    """Return a clean environment whose Python processes trace into ``folder``."""
    trace = folder / 'trace'
    trace.mkdir(parents=True, exist_ok=True)
    return clean_env(PYTHONPATH=str(site_dir(folder)), LADRC_TRACE_DIR=str(trace), **extra)


def read_traces(folder: Path) -> list[dict]:
    """Every traced event of the processes that wrote into ``folder/trace``, in time order."""
    events = []
    for path in sorted((folder / 'trace').glob('trace-*.jsonl')):
        for line in path.read_text(errors='replace').splitlines():
            try:
                events.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    names = {e['pid']: _label(e.get('cmdline', '')) for e in events if e['kind'] == 'start'}
    for e in events:
        e['proc'] = names.get(e['pid'], str(e['pid']))
    return sorted(events, key=lambda e: e['t'])


def _label(text: str) -> str:
    for label, rx in WATCH:
        if rx.search(text):
            return label
    return ' '.join(text.split()[:3])[-60:] or '?'


# ---- the scheduler monitor -------------------------------------------------------------------
WATCH = (('pytest', re.compile(r'-m pytest')),
         ('kit', re.compile(r'ladrc_tools\.cli')),
         ('follow', re.compile(r'lib/ladrc_follow/follow_node')),
         ('driver', re.compile(r'broken_driver\.py')),
         ('sim', re.compile(r'lib/ladrc_sim/sim_node')),
         ('recorder', re.compile(r'lib/ladrc_tools/recorder')),
         ('bringup', re.compile(r'lib/ladrc_tools/bringup|ladrc_tools\.bringup')),
         ('busy', re.compile(r'while True: pass')),
         ('param_client', re.compile(r'param_client')))


def _cmdline(pid: str) -> str:
    try:
        return Path(f'/proc/{pid}/cmdline').read_bytes().replace(b'\0', b' ').decode(
            errors='replace')
    except OSError:
        return ''


def _ppid(pid: int) -> int:
    try:
        with open(f'/proc/{pid}/stat', encoding='utf-8', errors='replace') as f:
            return int(f.read().rsplit(')', 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return 0


def descendants(root: int | None = None) -> list[int]:
    """Every living process below ``root`` (default: this one)."""
    root = os.getpid() if root is None else root
    parent = {}
    for name in os.listdir('/proc'):
        if name.isdigit():
            parent[int(name)] = _ppid(int(name))
    out, frontier = [], {root}
    while frontier:
        nxt = {p for p, pp in parent.items() if pp in frontier}
        out += sorted(nxt)
        frontier = nxt
    return out


def become_subreaper() -> None:
    """Orphans of the processes this one starts stay below it (so they can be found, ended)."""
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(36, 1, 0, 0, 0)  # PR_SET_CHILD_SUBREAPER


def end_descendants() -> list[int]:
    """SIGKILL every process still below this one (by id), reap them; return their ids."""
    left = descendants()
    for pid in left:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            break
        if pid == 0:
            if not descendants():
                break
            time.sleep(0.05)
    return left


class Monitor(threading.Thread):
    """Sample the watched processes' threads every ``period_s`` (see the module docstring).

    Only processes below this one count (a shared machine runs other sessions' nodes too).
    """

    def __init__(self, period_s: float = 0.05, wait_ms: float = 2.0) -> None:
        super().__init__(daemon=True)
        self.period_s = period_s
        self.wait_ms = wait_ms
        self.windows: list[dict] = []
        self.policies: dict[str, dict] = {}
        self._prev: dict[tuple[int, int], tuple[int, int]] = {}
        self._halt = threading.Event()
        self._t_prev = 0.0
        self._labels: dict[int, str] = {}
        self._others: set[int] = set()
        self._cmds: dict[int, str] = {}
        self.foreign_rt: dict[str, int] = {}  # other sessions' RT processes: seconds seen
        # the loop threads' system call at each sample (what a stalled loop is blocked in):
        # (t, label, syscall line of /proc/<pid>/task/<pid>/syscall, wchan)
        self.syscalls: list[tuple[float, str, str, str]] = []
        self.maps: dict[str, list[tuple[int, int, str]]] = {}
        self.shm_mappings: dict[str, int] = {}  # most /dev/shm/fastrtps* mappings seen
        self._map_reads: dict[str, int] = {}
        self._me = os.getpid()

    def _mine(self, pid: int) -> bool:
        seen = 0
        while pid > 1 and seen < 64:
            if pid == self._me:
                return True
            pid = _ppid(pid)
            seen += 1
        return False

    def _procs(self) -> dict[int, str]:
        out = {}
        for name in os.listdir('/proc'):
            if not name.isdigit():
                continue
            pid = int(name)
            if pid in self._labels:
                if self._cmds.get(pid) == _cmdline(name):
                    out[pid] = self._labels[pid]
                    continue
                del self._labels[pid]  # it exec'd (a fork seen before its exec)
            if pid in self._others:
                continue
            cmd = _cmdline(name)
            if not cmd:
                continue
            for label, rx in WATCH:
                if rx.search(cmd):
                    if self._mine(pid):
                        self._labels[pid] = label
                        self._cmds[pid] = cmd
                        out[pid] = label
                    else:
                        self._others.add(pid)
                    break
        return out

    def run(self) -> None:
        """Sample until stopped; once a second, note other sessions' real-time processes."""
        from stalls import rt_processes

        n = 0
        while not self._halt.wait(self.period_s):
            self.sample()
            n += 1
            if n % int(1 / self.period_s) == 0:
                mine = set(self._labels) | {self._me}
                for pid, name in rt_processes(mine).items():
                    if not self._mine(pid):
                        self.foreign_rt[name] = self.foreign_rt.get(name, 0) + 1

    def sample(self) -> None:
        """One sample: per-thread deltas, policies; keep windows with a long wait."""
        now = time.monotonic()
        cur: dict[tuple[int, int], tuple[int, int]] = {}
        run_by: dict[str, float] = {}
        waits: dict[str, float] = {}
        for pid, label in self._procs().items():
            try:
                tids = os.listdir(f'/proc/{pid}/task')
            except OSError:
                self._labels.pop(pid, None)
                continue
            pol = self.policies.setdefault(f'{label}:{pid}', {})
            for t in tids:
                tid = int(t)
                try:
                    a, b, _ = Path(f'/proc/{pid}/task/{t}/schedstat').read_text().split()
                    with open(f'/proc/{pid}/task/{t}/stat', encoding='utf-8',
                              errors='replace') as f:
                        s = f.read()
                except (OSError, ValueError):
                    continue
                fields = s.rsplit(')', 1)[1].split()
                comm = s[s.index('(') + 1:s.rindex(')')]
                policy = {'0': 'OTHER', '1': 'FIFO', '2': 'RR'}.get(fields[38], fields[38])
                pol[comm if tid != pid else 'main'] = f'{policy}/{fields[37]}'
                cur[(pid, tid)] = (int(a), int(b))
                prev = self._prev.get((pid, tid))
                if prev is None:
                    continue
                d_run = (int(a) - prev[0]) * 1e-6
                d_wait = (int(b) - prev[1]) * 1e-6
                key = f'{label}:{pid}'
                run_by[key] = run_by.get(key, 0.0) + d_run
                if tid == pid:
                    waits[key] = d_wait
                    if label in ('follow', 'sim', 'driver', 'kit'):
                        self._syscall(now, key, pid)
        self._prev = cur
        window_ms = (now - self._t_prev) * 1e3
        self._t_prev = now
        long_waits = {k: round(v, 2) for k, v in waits.items() if v > self.wait_ms}
        if long_waits:
            self.windows.append({'t': now, 'window_ms': round(window_ms, 1),
                                 'main_thread_waited_ms': long_waits,
                                 'cpu_ms_by_process': {k: round(v, 1)
                                                       for k, v in sorted(run_by.items())}})

    def _syscall(self, now: float, key: str, pid: int) -> None:
        try:
            sc = Path(f'/proc/{pid}/task/{pid}/syscall').read_text().strip()
            wchan = Path(f'/proc/{pid}/task/{pid}/wchan').read_text().strip()
        except OSError:
            return
        self.syscalls.append((now, key, sc, wchan))
        n = self._map_reads.get(key, 0)
        self._map_reads[key] = n + 1
        if n % 100 == 0:  # now and every 5 s: the code mappings, and the shared memory in use
            try:
                rows, shm = [], 0
                for line in Path(f'/proc/{pid}/maps').read_text().splitlines():
                    f = line.split()
                    if len(f) >= 6 and 'x' in f[1]:
                        a, b = (int(x, 16) for x in f[0].split('-'))
                        rows.append((a, b, f[5]))
                    shm += len(f) >= 6 and f[5].startswith('/dev/shm/fastrtps')
                self.maps[key] = rows
                self.shm_mappings[key] = max(self.shm_mappings.get(key, 0), shm)
            except OSError:
                pass

    def where(self, key: str, syscall_line: str) -> str:
        """Return the system call's name and the library its user-space PC is in."""
        names = {'202': 'futex', '230': 'clock_nanosleep', '35': 'nanosleep', '7': 'poll',
                 '232': 'epoll_wait', '44': 'sendto', '46': 'sendmsg', '45': 'recvfrom',
                 '47': 'recvmsg', '0': 'read', '1': 'write', '281': 'epoll_pwait',
                 '271': 'ppoll', '23': 'select', '270': 'pselect6', '9': 'mmap',
                 '10': 'mprotect', '11': 'munmap', '149': 'mlock', '151': 'mlockall'}
        f = syscall_line.split()
        if not f or f[0] == 'running':
            return 'running'
        pc = int(f[-1], 16) if f[-1].startswith('0x') else 0
        lib = next((name for a, b, name in self.maps.get(key, []) if a <= pc < b), '?')
        return f'{names.get(f[0], "syscall " + f[0])} in {Path(lib).name}'

    def stop(self) -> None:
        """Stop sampling."""
        self._halt.set()
        self.join()


# ---- running a command under the evidence ------------------------------------------------
def run_traced(cmd: list[str], cwd: Path, env: dict[str, str], timeout_s: float,
               log_path: Path | None = None) -> tuple[int, str, float]:
    """Run ``cmd`` in its own session (killed as a group on timeout); return code, output, s."""
    out = open(log_path, 'w+b') if log_path else subprocess.PIPE  # noqa: SIM115
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, start_new_session=True)
    try:
        try:
            data, _ = proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                data, _ = proc.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                data, _ = proc.communicate()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    if log_path:
        out.seek(0)
        data = out.read()
        out.close()
    return proc.returncode, (data or b'').decode(errors='replace'), time.monotonic() - t0


def blocked_in(mon: Monitor, events: list[dict], kind: str = 'follow_long_tick',
               proc: str = 'follow', min_ms: float = 50.0) -> list[dict]:
    """Return, per stall of ``proc`` over ``min_ms``, what its loop thread was blocked in.

    A stall is a trace event ``kind`` with ``ms``; what the thread did: the monitor's samples
    inside the stall (system call, library of the user-space PC, kernel wait channel).
    """
    out = []
    for e in events:
        if e['kind'] != kind or e['proc'] != proc or e.get('ms', 0) < min_ms:
            continue
        t1, t0 = e['t'], e['t'] - e['ms'] * 1e-3
        seen = [(round(t - t0, 3), mon.where(k, sc), w) for t, k, sc, w in mon.syscalls
                if k.startswith(proc + ':') and t0 < t < t1]
        out.append({'t': e['t'], 'ms': e['ms'], 'samples': seen})
    return out


def timeline(events: list[dict], windows: list[dict], t_center: float,
             before_s: float = 0.5, after_s: float = 0.2, skip=('gc_counts',)) -> list[str]:
    """Human lines of what happened around ``t_center`` (traces and monitor windows)."""
    lines = []
    hidden = ('t', 'wall', 'kind', 'pid', 'proc', 'threads')
    items = [(e['t'], f"{e['proc']:8s} {e['kind']}: " + ', '.join(
        f'{k}={v}' for k, v in e.items() if k not in hidden))
        for e in events if e['kind'] not in skip]
    items += [(w['t'], f"monitor  waited for a CPU in the {w['window_ms']} ms window: "
               f"{w['main_thread_waited_ms']}; CPU ms used: {w['cpu_ms_by_process']}")
              for w in windows]
    for t, text in sorted(items):
        if t_center - before_s <= t <= t_center + after_s:
            lines.append(f'  {t - t_center:+8.4f} s  {text}')
    return lines


def machine_state() -> dict:
    """Load and the foreign real-time processes of the machine now."""
    from stalls import rt_processes

    return {'loadavg': Path('/proc/loadavg').read_text().split()[:3],
            'rt_processes_now': sorted(set(rt_processes({os.getpid()}).values()))}


# ---- summaries ---------------------------------------------------------------------------------
def _top(values: list[float], n: int = 5) -> list[float]:
    return sorted(values, reverse=True)[:n]


def summarize(events: list[dict]) -> dict:
    """Per process: what the traces say (late ticks, gaps, faults, collections, real time)."""
    by = {}
    for e in events:
        by.setdefault(e['proc'], []).append(e)
    out: dict[str, dict] = {}
    for proc, evs in by.items():
        s: dict = {}
        kinds = {}
        for e in evs:
            kinds.setdefault(e['kind'], []).append(e)
        for kind, field in (('follow_late_tick', 'period_ms'), ('sim_late_cycle', 'period_ms'),
                            ('sim_command_gap', 'ms'), ('kit_send_gap', 'ms'),
                            ('kit_long_poll', 'ms'), ('follow_long_tick', 'ms'),
                            ('gc', 'ms')):
            if kind in kinds:
                v = [e[field] for e in kinds[kind]]
                s[kind] = {'count': len(v), 'max_ms': max(v), 'top_ms': _top(v),
                           'over_10ms': sum(1 for x in v if x > 10),
                           'over_50ms': sum(1 for x in v if x > 50)}
        if 'follow_long_callback' in kinds:
            s['follow_long_callback'] = [(e['fn'], e['ms']) for e in kinds['follow_long_callback']]
        if 'follow_set_parameters' in kinds:
            s['follow_set_parameters_ms'] = [e['ms'] for e in kinds['follow_set_parameters']]
        if 'follow_state' in kinds:
            s['follow_states'] = [(round(e['t'], 4), e['state'], e['reason'])
                                  for e in kinds['follow_state']]
        if 'sim_fault' in kinds:
            s['sim_faults'] = [(round(e['t'], 4), e['reason'], e.get('ms_since_command'))
                               for e in kinds['sim_fault']]
        if 'kit_abort' in kinds:
            s['kit_aborts'] = [e['reason'] for e in kinds['kit_abort']]
        if 'gc_counts' in kinds:
            s['gc_counts'] = kinds['gc_counts'][-1]['counts']
        if 'realtime' in kinds:
            r = kinds['realtime'][-1]
            main = r['threads'].get(str(r['pid']), '')
            s['realtime'] = {'applied': r['applied'], 'warnings': r['warnings'],
                             'main_thread': main,
                             'fifo_threads': sum(1 for v in r['threads'].values()
                                                 if ':FIFO/' in v),
                             'threads': len(r['threads'])}
        if 'probe_call_start' in kinds:
            ends = kinds.get('probe_call_end', [])
            calls = []
            for st in kinds['probe_call_start']:
                end = next((e['t'] for e in ends if e['t'] >= st['t']
                            and e['service'] == st['service']), None)
                calls.append((round(st['t'], 4), st['service'], st['new_client'],
                              round((end - st['t']) * 1e3, 1) if end else None))
            s['probe_calls'] = calls
        if 'patch_failed' in kinds:
            s['patch_failed'] = [e['error'] for e in kinds['patch_failed']]
        out[proc] = s
    return out


def first(events: list[dict], kind: str, cond=lambda e: True) -> dict | None:
    """Return the first event of ``kind`` that satisfies ``cond``."""
    return next((e for e in events if e['kind'] == kind and cond(e)), None)
