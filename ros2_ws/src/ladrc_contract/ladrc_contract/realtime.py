"""Real-time settings of a 2 kHz loop process, as ``ros2_control_node`` offers them.

``thread_priority`` (SCHED_FIFO priority of the loop thread, its middleware threads one above;
0 = the normal scheduler; timer slack 1 ns for every thread either way, see
:func:`apply_realtime`),
``cpu_affinity`` (CPUs the process may run on; empty = all) and ``lock_memory`` (``mlockall``:
no page fault on the tick path), and always: no transparent huge pages for numpy's arrays
(:func:`no_huge_pages`). Each setting that the system refuses (no CAP_SYS_NICE, an
RLIMIT_RTPRIO of 0, a missing CPU) is reported as a warning and the loop runs without it: a
controller that cannot get real-time priority still runs, and says so.

One implementation for the follow node, the sim node and the tools' commanders (calibration,
conformance prober); the simulator stands in for a drive and may not import the controller, so
it lives here.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import threading

MCL_CURRENT, MCL_FUTURE = 1, 2


def _each_thread(fn) -> None:
    for tid in sorted(int(t) for t in os.listdir('/proc/self/task')):
        try:
            fn(tid)
        except ProcessLookupError:
            pass  # the thread ended meanwhile


def schedule_this_thread(fifo_priority: int) -> bool:
    """Run the calling thread at SCHED_FIFO ``fifo_priority`` (0: the normal scheduler).

    Returns False when the system refuses (the thread keeps its scheduling). For the helper
    threads and processes of a loop process, which must not inherit the loop's priority.
    """
    try:
        if fifo_priority > 0:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(fifo_priority))
        else:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        return False
    return True


def schedule_task(tid: int, fifo_priority: int) -> str:
    """Run another process' thread ``tid`` at SCHED_FIFO ``fifo_priority``; '' or why not.

    For a process this one starts but does not run (LinuxCNC's real-time threads).
    """
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(fifo_priority))
    except OSError as exc:
        return exc.strerror or str(exc)
    return ''


def fifo_preexec(fifo_priority: int):
    """Return a ``preexec_fn`` that starts a child at SCHED_FIFO ``fifo_priority``.

    Every thread the child makes inherits it; a refusal leaves the child as it is.
    """
    def apply() -> None:
        schedule_this_thread(fifo_priority)
    return apply


def _no_timer_slack(tid: int) -> None:
    with open(f'/proc/{tid}/timerslack_ns', 'w', encoding='ascii') as f:
        f.write('1')


def no_huge_pages() -> bool:
    """Stop numpy from asking for transparent huge pages; return whether it could be set.

    numpy advises the kernel to back every array of 4 MB or more with huge pages
    (``madvise(MADV_HUGEPAGE)``), and with the kernel's default ``defrag`` setting (``madvise``)
    a page fault in such an array compacts memory on the spot until a 2 MB page is free. A job's
    sheet raster is such an array: compaction stalls the sim node's loop for milliseconds to
    tens of milliseconds at a time, the follow node faults on stale input and a free-running job
    stops (``bringup --job plate_holes`` with ``lock_memory``; with numpy's advice off, the job
    runs to its end). A loop process does not need huge pages: ordinary
    pages, locked or not, never stall on compaction. numpy's own switch (read from
    ``NUMPY_MADVISE_HUGEPAGE`` when numpy is imported, which is before any node's main runs).
    """
    import numpy as np

    core = getattr(np, '_core', None) or getattr(np, 'core', None)  # numpy 2.x / 1.26
    switch = getattr(getattr(core, 'multiarray', None), '_set_madvise_hugepage', None)
    if switch is None:
        return False
    switch(False)
    return True


def apply_realtime(thread_priority: int, cpu_affinity: list[int] | tuple[int, ...],
                   lock_memory: bool) -> tuple[list[str], list[str]]:
    """Apply the settings to the calling thread/process; return ``(applied, warnings)``."""
    applied: list[str] = []
    warnings: list[str] = []
    if no_huge_pages():
        applied.append('no huge pages for arrays')
    else:
        warnings.append('numpy has no switch for huge pages here: a large array may stall the '
                        'loop on memory compaction (set NUMPY_MADVISE_HUGEPAGE=0)')
    # Timer slack: Linux lets a sleep or timed wait of a normal-priority thread end up to
    # 50 us late (the default slack), so that wake-ups can be merged; a 0.5 ms loop then
    # ticks late by that and a lock-step round trip (four waits) took 0.2 ms longer. SCHED_FIFO
    # threads have none. 1 ns for every thread of the process (threads made later inherit it).
    try:
        _each_thread(_no_timer_slack)
        applied.append('timer slack 1 ns')
    except OSError as exc:
        warnings.append(f'timer slack not set: {exc}')
    # Both settings go to every thread of the process: the loop thread and the middleware's
    # receive and send threads, which carry the samples and commands (threads created later
    # inherit them from their creator).
    if cpu_affinity:
        try:
            cpus = set(int(c) for c in cpu_affinity)
            _each_thread(lambda tid: os.sched_setaffinity(tid, cpus))
            applied.append(f'CPU affinity {sorted(cpus)}')
        except (OSError, ValueError) as exc:
            warnings.append(f'CPU affinity {list(cpu_affinity)} not applied: {exc}')
    if thread_priority > 0:
        try:
            # The loop thread (the caller) at ``thread_priority``; the middleware's threads one
            # above, so that delivering a sample or a command (short bursts that then block)
            # is never held up by the loop, even when both share a CPU.
            loop_tid = threading.get_native_id()
            prio = int(thread_priority)
            io = os.sched_param(min(prio + 1, os.sched_get_priority_max(os.SCHED_FIFO)))
            _each_thread(lambda tid: os.sched_setscheduler(
                tid, os.SCHED_FIFO, os.sched_param(prio) if tid == loop_tid else io))
            applied.append(f'SCHED_FIFO priority {prio} (middleware threads {io.sched_priority})')
        except (OSError, ValueError) as exc:
            warnings.append(f'SCHED_FIFO priority {thread_priority} not permitted ({exc}); '
                            'the loop runs at normal priority and may be late under load '
                            '(grant CAP_SYS_NICE or an rtprio limit, docs/follow-node.md)')
    if lock_memory:
        libc = ctypes.CDLL(ctypes.util.find_library('c'), use_errno=True)
        if libc.mlockall(MCL_CURRENT | MCL_FUTURE) == 0:
            applied.append('memory locked')
        else:
            err = ctypes.get_errno()
            warnings.append(f'memory not locked: {os.strerror(err)} (raise the memlock limit '
                            'or grant CAP_IPC_LOCK)')
    return applied, warnings
