"""The follow node's loop thread: when it ticks (``loop``, docs/follow-node.md "The loop").

The thread takes the sensor samples straight from the readers (:mod:`.samples`,
:mod:`ladrc_contract.loop_io`) and spins no executor; the housekeeping thread serves the rest.

* ``deadline``: sleep until the next 0.5 ms deadline, take what arrived, tick, advance the
  deadline by one period (a tick more than one period late skips ahead, counted as an overrun).
  One wake-up per period, whatever the senders do.
* ``sync``: one tick per new pair of sensor samples, as soon as the pair is complete (the
  thread waits on the readers), at the latest one period plus ``sync_wait_s`` after the
  previous tick: then on its own deadline with what it has.
* ``lockstep``: one tick per ``sim/lockstep`` step, when the samples it names are here; no
  own deadline (the sim's clock stands still until this node answers).

Each wait is on the reader whose sample is still missing, and while both are missing on the
one that came last in the previous cycle (the sim publishes the gap, then the feedback, then
the step): a wake-up costs tens of microseconds on a VM, and waiting on all readers would
wake the thread once per sample instead of once per tick.

An exception on the tick path publishes the zero command and faults the controller
(:meth:`FollowNode.on_tick_exception`); the thread keeps running.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Protocol

from ladrc_contract.codes import FaultCode
from ladrc_contract.loop_io import SampleWait
from ladrc_contract.node_entry import NodeRun

from ..control.follow import FollowController, FollowState
from .samples import SampleInputs


class FollowNode(Protocol):
    """What the loop thread uses of the follow node (``node/follow_node.py``)."""

    loop_mode: str
    period_ns: int
    sync_wait_ns: int
    context: Any
    samples: SampleInputs
    controller: FollowController
    node_params: Any
    _lock: threading.Lock

    def tick(self) -> None: ...  # noqa: D102
    def tick_sync(self) -> None: ...  # noqa: D102
    def tick_step(self) -> None: ...  # noqa: D102
    def step_ready(self) -> bool: ...  # noqa: D102
    def on_tick_exception(self, exc: BaseException) -> None: ...  # noqa: D102
    def publish_zero(self, reason: str) -> None: ...  # noqa: D102


LOCKSTEP_POLL_NS = 50_000_000  # lock step: how long one wait for a step lasts (the hang check)


def run_loop(node: FollowNode, run: NodeRun) -> None:
    """Drive the node's ticks until a stop is requested (``run.stop_requested``)."""
    loops = {'deadline': run_deadline, 'sync': run_sync, 'lockstep': run_lockstep}
    loops[node.loop_mode](node, run)


def _guarded(node: FollowNode, tick) -> None:
    try:
        tick()
    except Exception as exc:  # noqa: BLE001 - the process keeps running, in FAULT
        node.on_tick_exception(exc)


def run_deadline(node: FollowNode, run: NodeRun) -> None:
    """Sleep to the deadline, take the samples that arrived, tick; skip ahead when late."""
    period = node.period_ns
    mono = time.monotonic_ns
    next_ns = mono() + period
    while not run.stop_requested:
        remaining = next_ns - mono()
        if remaining > 0:
            time.sleep(remaining * 1e-9)
            continue
        _guarded(node, node.samples.take)
        _guarded(node, node.tick)
        next_ns += period
        if mono() - next_ns > period:
            next_ns = mono() + period


def run_sync(node: FollowNode, run: NodeRun) -> None:
    """Tick when both inputs have a new sample; at the latest one period + sync_wait_s on."""
    limit = node.period_ns + node.sync_wait_ns
    mono = time.monotonic_ns
    s = node.samples
    wait_gap = SampleWait(node.context, (s.gap_reader,))
    wait_fb = SampleWait(node.context, (s.fb_reader,))
    last = mono()
    feedback_last = True  # which input completed the previous pair
    while not run.stop_requested:
        had_gap, had_fb = s.new_gap, s.new_feedback
        _guarded(node, s.take)
        if s.new_gap and s.new_feedback:
            if had_gap != had_fb:  # the one missing before this take completed the pair
                feedback_last = had_gap
        else:
            remaining = last + limit - mono()
            if remaining > 0:
                missing_fb = not s.new_feedback and (s.new_gap or feedback_last)
                (wait_fb if missing_fb else wait_gap).wait(remaining)
                continue
        last = mono()
        _guarded(node, node.tick_sync)


def run_lockstep(node: FollowNode, run: NodeRun) -> None:
    """Tick once per ``sim/lockstep`` step, when its samples are here.

    The wall clock only guards the sim: no step for ``lockstep_timeout_s`` after the first is
    a FAULT (the core's stale limit cannot see it, its clock being the sim's).
    """
    timeout_ns = int(node.node_params.lockstep_timeout_s * 1e9)
    s = node.samples
    wait_step = SampleWait(node.context, (s.step_reader,))
    wait_samples = SampleWait(node.context, (s.gap_reader, s.fb_reader, s.cnc_reader))
    while not run.stop_requested:
        _guarded(node, s.take)
        if node.step_ready():
            _guarded(node, node.tick_step)
            continue
        # the step names its samples; they are published before it, but on other topics
        (wait_step if s.step is None else wait_samples).wait(LOCKSTEP_POLL_NS)
        if (s.step_wall_ns and s.step is None
                and time.monotonic_ns() - s.step_wall_ns > timeout_ns
                and node.controller.state != FollowState.FAULT):
            with node._lock:
                node.controller.fail(f'lock step: no step from the sim for '
                                     f'{node.node_params.lockstep_timeout_s:g} s (wall clock)',
                                     FaultCode.LOOP_TIMING)
            node.publish_zero('lock step: the sim stopped')
