"""The stability gate of a parameter set changed at run time, in a process of its own.

The gate analyses a set's linear loops (~25 ms here, numpy and LAPACK). In the follow node's
process it held the interpreter lock for up to 10 ms at a stretch whichever thread ran it, and
the loop thread waits for that lock: measured with the gate on the parameter thread, the loop
stalled 45-91 ms while five sets were checked, and the drive's watchdog quick-stopped the axis
(a valid ``law.kp`` change while following). A process has a lock of its own, so the gate runs
in one, started with the node (:meth:`GateProcess.start`, before the loop's real-time settings:
it runs at the normal scheduler), via ``concurrent.futures.ProcessPoolExecutor``.

A set is accepted only with the gate's verdict: no answer within ``timeout_s``, or a worker
that died, rejects the set with that reason (the running values stay); a new worker is started
for the next set. Start-up sets are gated in the node's own process, before the loop runs.
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from concurrent.futures.process import BrokenProcessPool
import multiprocessing
import os
import signal

from ladrc_contract.node_entry import ignore_stop_signals
from ladrc_contract.realtime import schedule_this_thread

from ..analysis.gate import check_gate
from ..control.params import ControllerParams, ParameterError

GATE_TIMEOUT_S = 10.0
"""The longest a set's verdict may take (a loaded machine; the gate itself takes ~25 ms)."""


def gate_reasons(params: ControllerParams) -> list[str]:
    """Return why ``params`` fails the stability gate (the worker's function; empty: passes)."""
    try:
        check_gate(params)
    except ParameterError as exc:
        return list(exc.reasons)
    return []


def _worker_setup() -> None:
    """Worker initializer: the normal scheduler, and Ctrl-C is the node's to handle.

    The worker shares the node's process group, so a terminal's or launch's SIGINT reaches it
    too; the node ends it (:meth:`GateProcess.close`).
    """
    ignore_stop_signals((signal.SIGINT,))
    schedule_this_thread(0)


class GateProcess:
    """One worker process that gates parameter sets (see the module docstring)."""

    def __init__(self, timeout_s: float = GATE_TIMEOUT_S) -> None:
        self.timeout_s = timeout_s
        self._pool: ProcessPoolExecutor | None = None

    def start(self) -> None:
        """Start the worker and let it load the analysis (a first verdict, on the defaults)."""
        self._pool = ProcessPoolExecutor(
            max_workers=1, mp_context=multiprocessing.get_context('spawn'),
            initializer=_worker_setup)
        self._pool.submit(gate_reasons, ControllerParams())

    def reasons(self, params: ControllerParams) -> list[str]:
        """Return the gate's reasons against ``params`` (a set that cannot be judged fails)."""
        if self._pool is None:
            self.start()
        try:
            return self._pool.submit(gate_reasons, params).result(timeout=self.timeout_s)
        except FutureTimeout:
            why = f'no verdict within {self.timeout_s:g} s'
        except BrokenProcessPool:
            why = 'the gate process ended'
        except Exception as exc:  # noqa: BLE001 - a set that cannot be judged is rejected
            why = f'{type(exc).__name__}: {exc}'
        self.close()  # a new worker for the next set
        return [f'stability gate: the set could not be judged ({why}); rejected, the running '
                'values stay']

    def close(self) -> None:
        """End the worker: killed, not waited for (it may be stuck in a computation)."""
        pool, self._pool = self._pool, None
        if pool is None:
            return
        workers = list(getattr(pool, '_processes', None) or {})  # pids (CPython's executor)
        pool.shutdown(wait=False, cancel_futures=True)
        for pid in workers:
            try:
                os.kill(pid, 9)
            except OSError:
                pass  # already gone
