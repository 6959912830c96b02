"""The contract's QoS profiles, as data (docs/interfaces.md, "QoS").

One definition: the nodes turn a profile into an rclpy ``QoSProfile`` with :func:`to_rclpy`,
the bag writer into the ``offered_qos_profiles`` it stores (``ladrc_bags``), and
tests/test_contract_once.py fails when a QoS profile is made anywhere else.

* High-rate publishers (sensor, feedback, command, status, truth): BEST_EFFORT, VOLATILE,
  KEEP_LAST 100. Measured here (docs/follow-node.md): with RELIABLE writers and a recorder on a
  loaded 2-core machine, the reliability protocol (heartbeats, acknacks, repairs for two readers
  per topic at 2 kHz) cost enough CPU that the writers' keep-last history overflowed and the
  recorder lost 7-50 % of the samples; best effort lost 0-0.1 %. Every sample carries a seq
  counter, so a loss is measured, never silent.
* Control-path inputs (the controller's samples): BEST_EFFORT, KEEP_LAST 1. A control loop
  wants the freshest sample: with a deeper queue a reader that falls behind works through old
  samples (input age grew to depth x 0.5 ms), and a late sample is useless to a zero-order
  hold. Samples superseded before use are counted from the seq gaps.
* The drive's command input: BEST_EFFORT, KEEP_LAST 10 (5 ms at 2 kHz, one watchdog). The drive
  takes every command that arrived since its last cycle, oldest first, and holds the latest one
  its commander lock admits: with depth 1 all writers share one slot, so a commander's command
  arriving after a foreign one in the same cycle would erase it (the foreign commander seen
  cycles late) and a second commander's first command would erase the first's release (a
  handover seen as a foreign command).
* The recorder reads best effort with a deep history (5 s: it takes in batches).
* Events (follow commands and parameter sets as applied): RELIABLE, TRANSIENT_LOCAL, KEEP_LAST
  100, so a recorder started late still gets the parameter set in force.
* run/parameters, run/scenario: RELIABLE, TRANSIENT_LOCAL, KEEP_LAST 1 (latched texts).
* /diagnostics: the ROS default (RELIABLE, VOLATILE, KEEP_LAST 10).
* Lock step (docs/follow-node.md, "Lock step"): the 2 kHz topics and ``sim/lockstep`` RELIABLE;
  writers KEEP_LAST 20000 (10 s of history for a recorder that falls behind: repaired, not
  lost; 1000 lost 18 samples of a 4 s run next to two other node sets); the loop's inputs
  KEEP_LAST 1 (the sim publishes step k+1 only after the answer to k); the drive's command
  input KEEP_LAST 100, so that a foreign command (refused by the commander lock) cannot
  supersede the commander's answer. A lock-step writer's node does not go down before its
  readers have acknowledged every message (:func:`wait_acknowledged`): a reliable writer
  repairs only while it exists, so a sim that exited at the end of its scenario while the
  recorder lagged (a loaded machine) would take the run's last samples with it.

A driver for the real axis uses the same profiles.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from .topics import (
    COMMAND_TOPIC,
    DIAGNOSTICS_TOPIC,
    EVENTS_TOPIC,
    FEEDBACK_TOPIC,
    GAP_TOPIC,
    PARAMETERS_TOPIC,
    SCENARIO_TOPIC,
    SEQ_FIELD,
    STATUS_TOPIC,
    TRUTH_TOPIC,
)


@dataclass(frozen=True)
class Qos:
    """A keep-last QoS profile: reliability, durability and history depth."""

    reliable: bool
    transient_local: bool
    depth: int

    def with_depth(self, depth: int) -> Qos:
        """Return the same profile with another history depth (not part of matching)."""
        return Qos(self.reliable, self.transient_local, depth)


HIGH_RATE = Qos(reliable=False, transient_local=False, depth=100)
CONTROL_INPUT = Qos(reliable=False, transient_local=False, depth=1)
DRIVE_COMMAND_INPUT = Qos(reliable=False, transient_local=False, depth=10)
RECORDER_READER = Qos(reliable=False, transient_local=False, depth=10000)  # 5 s at 2 kHz
EVENTS = Qos(reliable=True, transient_local=True, depth=100)
RUN_TEXT = Qos(reliable=True, transient_local=True, depth=1)
DIAGNOSTICS = Qos(reliable=True, transient_local=False, depth=10)
LOCKSTEP_HIGH_RATE = Qos(reliable=True, transient_local=False, depth=20000)
LOCKSTEP_INPUT = Qos(reliable=True, transient_local=False, depth=1)
LOCKSTEP_COMMAND_INPUT = Qos(reliable=True, transient_local=False, depth=100)

TOPIC_QOS: dict[str, Qos] = {
    **{t: HIGH_RATE for t in SEQ_FIELD},
    EVENTS_TOPIC: EVENTS,
    DIAGNOSTICS_TOPIC: DIAGNOSTICS,
    PARAMETERS_TOPIC: RUN_TEXT,
    SCENARIO_TOPIC: RUN_TEXT,
}
"""The publishers' profile of each recorded topic (what a bag stores as offered)."""
assert {GAP_TOPIC, FEEDBACK_TOPIC, COMMAND_TOPIC, STATUS_TOPIC, TRUTH_TOPIC} <= set(TOPIC_QOS)


def wait_acknowledged(publishers: Any, timeout_s: float) -> list[str]:
    """Wait until every reader acknowledged all of the ``publishers``' messages; return the late.

    Reliable publishers only wait (rclpy ``Publisher.wait_for_all_acked``; best effort returns
    at once); at most ``timeout_s`` (wall clock) for all of them together. Returns the topics
    not acknowledged in time (a reader gone or stalled), for the caller's one log line.
    """
    import time

    from rclpy.duration import Duration

    end = time.monotonic() + timeout_s
    late = []
    for pub in publishers:
        left_ns = max(0, int((end - time.monotonic()) * 1e9))
        if not pub.wait_for_all_acked(Duration(nanoseconds=left_ns)):
            late.append(pub.topic_name)
    return late


def to_rclpy(q: Qos) -> Any:
    """Return the rclpy ``QoSProfile`` of ``q`` (keep last ``depth``)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=q.depth,
        reliability=ReliabilityPolicy.RELIABLE if q.reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if q.transient_local
                    else DurabilityPolicy.VOLATILE))
