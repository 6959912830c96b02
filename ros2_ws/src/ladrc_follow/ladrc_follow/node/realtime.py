"""Real-time settings of a 2 kHz loop process, as ``ros2_control_node`` offers them.

``thread_priority`` (SCHED_FIFO priority of the process's threads, 0 = the normal scheduler),
``cpu_affinity`` (CPUs the process may run on; empty = all) and ``lock_memory`` (``mlockall``:
no page fault on the tick path). Each setting that the system refuses (no CAP_SYS_NICE, an
RLIMIT_RTPRIO of 0, a missing CPU) is reported as a warning and the loop runs without it: a
controller that cannot get real-time priority still runs, and says so.

The follow node (``ladrc_follow.node.realtime``) and the sim node (``ladrc_sim.node.realtime``)
carry this same file: the simulator stands in for a drive and must not import the controller
package. tests/test_layers.py checks that the two copies stay equal.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

MCL_CURRENT, MCL_FUTURE = 1, 2


def apply_realtime(thread_priority: int, cpu_affinity: list[int] | tuple[int, ...],
                   lock_memory: bool) -> tuple[list[str], list[str]]:
    """Apply the settings to the calling thread/process; return ``(applied, warnings)``."""
    applied: list[str] = []
    warnings: list[str] = []
    if cpu_affinity:
        try:
            os.sched_setaffinity(0, set(int(c) for c in cpu_affinity))
            applied.append(f'CPU affinity {sorted(set(cpu_affinity))}')
        except (OSError, ValueError) as exc:
            warnings.append(f'CPU affinity {list(cpu_affinity)} not applied: {exc}')
    if thread_priority > 0:
        try:
            # every thread of the process: the loop thread and the middleware's receive and
            # send threads, which carry the samples and commands (threads created later by a
            # FIFO thread inherit the policy)
            param = os.sched_param(int(thread_priority))
            for tid in sorted(int(t) for t in os.listdir('/proc/self/task')):
                try:
                    os.sched_setscheduler(tid, os.SCHED_FIFO, param)
                except ProcessLookupError:
                    pass  # the thread ended meanwhile
            applied.append(f'SCHED_FIFO priority {thread_priority}')
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
