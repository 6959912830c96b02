"""Scheduling stalls of a 2 kHz Python loop on the host, with and without SCHED_FIFO.

    scripts/in-env python bench/stalls.py [--seconds 20] [--conditions fifo_idle,fifo_busy,...]

The loop is the follow node's (``ladrc_follow.node.loops.run_deadline``, ``loop: deadline``):
sleep until the next 0.5 ms deadline, take from a loop reader (``ladrc_contract.loop_io``, no
executor), publish one pre-serialized message, skipping ahead (no burst) after a stall longer
than a period. Its process applies the follow node's real-time settings with the follow node's
own function (``ladrc_contract.realtime.apply_realtime``: SCHED_FIFO 50 for the loop thread, 51
for the middleware threads, timer slack 1 ns, ``mlockall``; or priority 0 = the normal
scheduler, memory still locked),
then ``gc.collect(); gc.freeze()`` as the node does. Four conditions, each a fresh process,
run one after the other:

* ``fifo_idle``    SCHED_FIFO 50, nothing else started by this script
* ``fifo_busy``    SCHED_FIFO 50, two busy loops (``python3 -c 'while True: pass'``)
* ``normal_idle``  the normal scheduler (SCHED_OTHER, nice 0)
* ``normal_busy``  the normal scheduler, two busy loops

The busy loops are started before and killed (by their process group) after each condition.
Per condition: wake-up lateness (tick start minus its deadline) p50/p99/p99.9/max, ticks later
than 2/5/10/50 ms, the largest tick period, and for every tick later than 2 ms where the loop
thread's time went (``/proc/<tid>/schedstat``, read before and after the stall): running on a
CPU (this process' own work: a collection, Python), runnable but waiting for a CPU (preempted:
another process, or this process' middleware threads), or neither (asleep past its deadline:
a late timer wake-up, or the VM's vCPU not running; the guest's steal time is reported too),
plus whether a garbage collection overlapped it. Also: what ``apply_realtime`` granted, the
collections, involuntary context switches, the machine's steal time and the CPU used by other
processes on the machine during the condition (a shared machine: someone else's load shows).

Human lines go to stderr; the last stdout line is one JSON object: ``date``, ``cpus``,
``seconds``, ``stall_max_fifo_ms``, ``stall_max_normal_ms``, ``STALL_MAX_S``,
``STALL_MAX_NORMAL_S`` (null without a condition of that scheduler) and every condition's
figures under ``conditions``.

``STALL_MAX_S`` and ``STALL_MAX_NORMAL_S`` are what the real-time tests import as the stall they
must tolerate.
"""

from __future__ import annotations

import argparse
from array import array
import gc
import json
import math
import os
from pathlib import Path
import resource
import shutil
import signal
import subprocess
import sys
import threading
import time

# The stall the real-time tests must tolerate: at least twice the largest wake-up lateness of
# this bench's SCHED_FIFO conditions (docs/figures.md#stalls), rounded up to a millisecond. Twice,
# because a short run sees each rare event (a vCPU descheduled by the host, a kernel path that
# does not preempt) only a few times while a test session runs for minutes, and the largest
# stall grows with the run length.
STALL_MAX_S = 0.012
# The same for the normal scheduler (what a loop meets when SCHED_FIFO is refused).
STALL_MAX_NORMAL_S = 0.036

PERIOD_NS = 500_000
WARMUP_S = 1.0
THRESHOLDS_MS = (2, 5, 10, 50)
CONDITIONS = ('fifo_idle', 'fifo_busy', 'normal_idle', 'normal_busy')
BUSY_LOOPS = 2
ROOT = Path(__file__).resolve().parents[1]


# ---- the machine ----------------------------------------------------------------------------
def cpu_jiffies() -> dict[str, int]:
    """Return the machine's CPU time so far (USER_HZ ticks): busy, steal, total."""
    with open('/proc/stat', encoding='ascii') as f:
        v = [int(x) for x in f.readline().split()[1:]]
    user, nice, system, idle, iowait, irq, softirq, steal = v[:8]
    return {'busy': user + nice + system + irq + softirq, 'steal': steal,
            'total': user + nice + system + idle + iowait + irq + softirq + steal}


def proc_cpu_jiffies(pid: int) -> int:
    """Return utime + stime of a process and its waited-for children (USER_HZ ticks)."""
    try:
        with open(f'/proc/{pid}/stat', encoding='ascii') as f:
            fields = f.read().rsplit(')', 1)[1].split()
    except OSError:
        return 0
    return sum(int(x) for x in fields[11:15])  # utime stime cutime cstime


def rt_processes(exclude: set[int]) -> dict[int, str]:
    """Return user processes (not kernel threads) with a SCHED_FIFO/RR thread: pid -> name."""
    found = {}
    for name in os.listdir('/proc'):
        if not name.isdigit() or int(name) in exclude:
            continue
        try:
            if not Path(f'/proc/{name}/cmdline').read_bytes():
                continue  # a kernel thread
            for tid in os.listdir(f'/proc/{name}/task'):
                with open(f'/proc/{name}/task/{tid}/stat', encoding='utf-8',
                          errors='replace') as f:
                    fields = f.read().rsplit(')', 1)[1].split()
                if fields[38] in ('1', '2'):  # policy: SCHED_FIFO, SCHED_RR
                    cmd = Path(f'/proc/{name}/cmdline').read_bytes().split(b'\0')
                    found[int(name)] = ' '.join(c.decode(errors='replace')
                                                for c in cmd[:2])[-80:]
                    break
        except (OSError, IndexError):
            continue
    return found


class Census(threading.Thread):
    """Every 2 s: the other processes on the machine running real-time threads."""

    def __init__(self) -> None:
        super().__init__(daemon=True)
        self.exclude = {os.getpid()}
        self.seen: dict[int, str] = {}
        self.most = 0
        self._halt = threading.Event()

    def run(self) -> None:
        """Sample until stopped."""
        while not self._halt.wait(2.0):
            now = rt_processes(self.exclude)
            self.seen.update(now)
            self.most = max(self.most, len(now))

    def stop(self) -> None:
        """Stop sampling and wait for the thread."""
        self._halt.set()
        self.join()


def start_busy_loops(n: int) -> list[subprocess.Popen]:
    """Start ``n`` CPU-bound ``python3 -c 'while True: pass'``, each in its own group."""
    exe = shutil.which('python3') or sys.executable
    return [subprocess.Popen([exe, '-c', 'while True: pass'], start_new_session=True,
                             stdin=subprocess.DEVNULL) for _ in range(n)]


def stop_busy_loops(procs: list[subprocess.Popen]) -> None:
    """Kill the busy loops by their process groups (the pyenv shim may fork)."""
    for p in procs:
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        p.wait()


# ---- the loop (worker process) ----------------------------------------------------------------
def _schedstat(fd: int) -> tuple[int, int, int]:
    """Return (ns on a CPU, ns runnable waiting, timeslices) of a thread."""
    a, b, c = os.pread(fd, 96, 0).split()
    return int(a), int(b), int(c)


def percentiles_ms(x_ns: list[int] | array) -> dict[str, float]:
    """p50 / p99 / p99.9 / max in ms."""
    import numpy as np

    a = np.asarray(x_ns, dtype=np.float64) * 1e-6
    if a.size == 0:
        return {k: math.nan for k in ('p50', 'p99', 'p999', 'max')}
    return {'p50': float(np.percentile(a, 50)), 'p99': float(np.percentile(a, 99)),
            'p999': float(np.percentile(a, 99.9)), 'max': float(a.max())}


def worker(fifo: bool, seconds: float) -> dict:
    """Run the loop for ``seconds`` (after a warm-up); return its figures."""
    from ladrc_contract import qos
    from ladrc_contract.loop_io import LoopNode
    from ladrc_contract.qos import to_rclpy
    from ladrc_contract.realtime import apply_realtime
    import rclpy
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64

    context = rclpy.Context()
    rclpy.init(context=context)
    node = LoopNode('stalls_loop', context=context)
    pub = node.create_publisher(Float64, 'stalls/tick', to_rclpy(qos.HIGH_RATE))
    reader = node.create_loop_reader(Float64, 'stalls/input', to_rclpy(qos.CONTROL_INPUT))
    applied, warnings = apply_realtime(50 if fifo else 0, [], True)
    tid = threading.get_native_id()
    policy = os.sched_getscheduler(0)
    fd = os.open(f'/proc/self/task/{tid}/schedstat', os.O_RDONLY)
    gcs: list[tuple[str, int, int]] = []  # (phase, generation, monotonic ns)
    gc.callbacks.append(lambda phase, info: gcs.append((phase, info['generation'],
                                                        time.monotonic_ns())))
    gc.collect()
    gc.freeze()
    n_max = int((seconds + WARMUP_S) / (PERIOD_NS * 1e-9)) + 10
    late = array('q', bytes(8 * n_max))  # lateness per tick, ns
    starts = array('q', bytes(8 * n_max))  # tick start, monotonic ns
    stalls: list[dict] = []
    msg = Float64()
    mono = time.monotonic_ns
    t0 = mono()
    measure_from = t0 + int(WARMUP_S * 1e9)
    end = measure_from + int(seconds * 1e9)
    ru0 = cpu0 = None
    prev_ss = _schedstat(fd)
    prev_end = mono()
    next_ns = mono() + PERIOD_NS
    i = 0
    while True:
        remaining = next_ns - mono()
        if remaining > 0:
            time.sleep(remaining * 1e-9)
            continue
        reader.take()
        now = mono()
        if now >= end:
            break
        lateness = now - next_ns
        if now >= measure_from:
            if ru0 is None:
                ru0, cpu0 = resource.getrusage(resource.RUSAGE_SELF), cpu_jiffies()
                i = 0
            late[i] = lateness
            starts[i] = now
            i += 1
            if lateness > 2_000_000:
                ss = _schedstat(fd)
                interval = now - prev_end
                run, wait = ss[0] - prev_ss[0], ss[1] - prev_ss[1]
                gc_in = any(prev_end <= t <= now for _, _, t in gcs[-20:])
                stalls.append({'t_s': round((now - measure_from) * 1e-9, 4),
                               'late_ms': round(lateness * 1e-6, 3),
                               'interval_ms': round(interval * 1e-6, 3),
                               'on_cpu_ms': round(run * 1e-6, 3),
                               'runnable_waiting_ms': round(wait * 1e-6, 3),
                               'neither_ms': round((interval - run - wait) * 1e-6, 3),
                               'timeslices': ss[2] - prev_ss[2], 'gc_overlap': gc_in})
        msg.data = float(i)
        pub.publish(serialize_message(msg))
        next_ns += PERIOD_NS
        if mono() - next_ns > PERIOD_NS:
            next_ns = mono() + PERIOD_NS
        prev_end = mono()
        prev_ss = _schedstat(fd)
    ru1, cpu1 = resource.getrusage(resource.RUSAGE_SELF), cpu_jiffies()
    os.close(fd)
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    lat = late[:i]
    periods = [b - a for a, b in zip(starts[:i - 1], starts[1:i], strict=True)]
    p = percentiles_ms(lat)
    in_run = [g for g in gcs if g[2] >= measure_from]
    return {
        'fifo_requested': fifo, 'applied': applied, 'warnings': warnings,
        'loop_thread_policy': {os.SCHED_FIFO: 'SCHED_FIFO', os.SCHED_OTHER: 'SCHED_OTHER'}
        .get(policy, str(policy)),
        'ticks': i, 'rate_hz': i / seconds,
        'late_p50_ms': p['p50'], 'late_p99_ms': p['p99'], 'late_p999_ms': p['p999'],
        'late_max_ms': p['max'],
        **{f'over_{t}ms': sum(1 for x in lat if x > t * 1_000_000) for t in THRESHOLDS_MS},
        'period_max_ms': max(periods) * 1e-6 if periods else math.nan,
        'gc_collections': {str(g): sum(1 for ph, gen, _ in in_run if ph == 'start' and gen == g)
                           for g in (0, 1, 2)},
        'involuntary_ctx_switches': ru1.ru_nivcsw - ru0.ru_nivcsw,
        'voluntary_ctx_switches': ru1.ru_nvcsw - ru0.ru_nvcsw,
        'major_page_faults': ru1.ru_majflt - ru0.ru_majflt,
        'steal_ms': (cpu1['steal'] - cpu0['steal']) * 1000 / os.sysconf('SC_CLK_TCK'),
        'worker_cpu_s': (ru1.ru_utime + ru1.ru_stime) - (ru0.ru_utime + ru0.ru_stime),
        'stalls': sorted(stalls, key=lambda s: -s['late_ms'])[:20],
        'stalls_over_2ms': len(stalls),
    }


# ---- the conditions --------------------------------------------------------------------------
def run_condition(name: str, seconds: float) -> dict:
    """Run one condition in a fresh process; return its figures."""
    busy = start_busy_loops(BUSY_LOOPS) if name.endswith('_busy') else []
    hz = os.sysconf('SC_CLK_TCK')
    try:
        time.sleep(0.5)  # the busy loops are up and running
        load = Path('/proc/loadavg').read_text().split()[0]
        j0, own0 = cpu_jiffies(), sum(proc_cpu_jiffies(p.pid) for p in busy)
        ch0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        census = Census()
        t0 = time.monotonic()
        proc = subprocess.Popen([sys.executable, __file__, '--worker', name.split('_')[0],
                                 '--seconds', str(seconds)], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        census.exclude.add(proc.pid)
        census.start()
        try:
            stdout, stderr = proc.communicate(timeout=seconds + 120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            census.stop()
        wall = time.monotonic() - t0
        j1, own1 = cpu_jiffies(), sum(proc_cpu_jiffies(p.pid) for p in busy)
        ch1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    finally:
        stop_busy_loops(busy)
    if proc.returncode != 0 or not stdout.strip():
        raise RuntimeError(f'{name}: worker failed ({proc.returncode}): {stderr[-2000:]}')
    r = json.loads(stdout.strip().splitlines()[-1])
    # CPUs' worth of time the rest of the machine used: everything busy minus the busy loops
    # and the worker (its whole life, start-up included: an upper bound of the foreign load)
    worker_cpu = ((ch1.ru_utime + ch1.ru_stime) - (ch0.ru_utime + ch0.ru_stime)) * hz
    foreign = max(0.0, (j1['busy'] - j0['busy']) - (own1 - own0) - worker_cpu) / hz / wall
    r.update({'condition': name, 'busy_loops': len(busy), 'loadavg_1min_before': float(load),
              'foreign_cpu': round(foreign, 3),
              'foreign_rt_processes_most': census.most,
              'foreign_rt_processes': sorted(set(census.seen.values())),
              'machine_busy_cpus': round((j1['busy'] - j0['busy']) / hz / wall, 3)})
    return r


def human(r: dict) -> str:
    """One line per condition."""
    granted = r['loop_thread_policy']
    return (f"{r['condition']:12s} {granted:11s} rate {r['rate_hz']:7.1f} Hz  late p50 "
            f"{r['late_p50_ms']:.3f} p99 {r['late_p99_ms']:.3f} p99.9 {r['late_p999_ms']:.3f} "
            f"max {r['late_max_ms']:.2f} ms  >2/5/10/50 ms: {r['over_2ms']}/{r['over_5ms']}/"
            f"{r['over_10ms']}/{r['over_50ms']}  gc {r['gc_collections']}  steal "
            f"{r['steal_ms']:.0f} ms  foreign cpu {r['foreign_cpu']:.2f}, foreign RT processes "
            f"{r['foreign_rt_processes_most']}")


def stall_line(s: dict) -> str:
    """One stall: where the loop thread's time went."""
    return (f"    t={s['t_s']:8.3f}s late {s['late_ms']:7.2f} ms: on cpu {s['on_cpu_ms']:.2f}, "
            f"runnable waiting {s['runnable_waiting_ms']:.2f}, neither {s['neither_ms']:.2f} ms"
            f"{', gc' if s['gc_overlap'] else ''}")


def round_up_ms(x_ms: float) -> float:
    """Round a stall up to the next whole millisecond, in seconds."""
    return math.ceil(x_ms) * 1e-3


def main() -> int:
    """Measure every condition; print the table and the constants; last line JSON."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--seconds', type=float, default=20.0, help='seconds per condition [20]')
    ap.add_argument('--conditions', default=','.join(CONDITIONS),
                    help='comma separated, of ' + ', '.join(CONDITIONS))
    ap.add_argument('--worker', choices=['fifo', 'normal'], help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker == 'fifo', args.seconds)))
        return 0
    results = {}
    for name in args.conditions.split(','):
        if name not in CONDITIONS:
            ap.error(f'unknown condition {name!r}')
        r = run_condition(name, args.seconds)
        results[name] = r
        print(human(r), file=sys.stderr)
        for w in r['warnings']:
            print(f'    warning: {w}', file=sys.stderr)
        for s in r['stalls'][:5]:
            print(stall_line(s), file=sys.stderr)
    fifo = [r['late_max_ms'] for k, r in results.items() if k.startswith('fifo')]
    normal = [r['late_max_ms'] for k, r in results.items() if k.startswith('normal')]
    out = {
        'date': time.strftime('%Y-%m-%d'), 'cpus': os.cpu_count(), 'seconds': args.seconds,
        'stall_max_fifo_ms': max(fifo) if fifo else None,
        'stall_max_normal_ms': max(normal) if normal else None,
        'STALL_MAX_S': 2 * round_up_ms(max(fifo)) if fifo else None,
        'STALL_MAX_NORMAL_S': 2 * round_up_ms(max(normal)) if normal else None,
        'conditions': results,
    }
    print(f"STALL_MAX_S = {out['STALL_MAX_S']}  STALL_MAX_NORMAL_S = "
          f"{out['STALL_MAX_NORMAL_S']}", file=sys.stderr)
    print(json.dumps(out))
    return 0


if __name__ == '__main__':
    sys.exit(main())
