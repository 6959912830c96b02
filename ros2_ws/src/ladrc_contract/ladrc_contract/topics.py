"""The contract's topics: names, message types and sequence counters (docs/interfaces.md)."""

from __future__ import annotations

GAP_TOPIC = 'axis/capacitive_height'
FEEDBACK_TOPIC = 'axis/feedback'
COMMAND_TOPIC = 'axis/velocity_command'
STATUS_TOPIC = 'follow/status'
EVENTS_TOPIC = 'follow/events'
TRUTH_TOPIC = 'sim/truth'
LOCKSTEP_TOPIC = 'sim/lockstep'
CNC_MOTION_TOPIC = 'cnc/motion'
# a separate CNC node (docs/job-world.md, "A separate CNC"): its lock steps and its job's end
CNC_LOCKSTEP_TOPIC = 'cnc/lockstep'
CNC_JOB_TOPIC = 'cnc/job'
DIAGNOSTICS_TOPIC = '/diagnostics'
PARAMETERS_TOPIC = 'run/parameters'
SCENARIO_TOPIC = 'run/scenario'

TOPIC_TYPES: dict[str, str] = {
    GAP_TOPIC: 'ladrc_msgs/msg/CapacitiveHeight',
    FEEDBACK_TOPIC: 'ladrc_msgs/msg/AxisFeedback',
    COMMAND_TOPIC: 'ladrc_msgs/msg/VelocityCommand',
    STATUS_TOPIC: 'ladrc_msgs/msg/FollowStatus',
    EVENTS_TOPIC: 'ladrc_msgs/msg/FollowEvent',
    TRUTH_TOPIC: 'ladrc_msgs/msg/SimTruth',
    DIAGNOSTICS_TOPIC: 'diagnostic_msgs/msg/DiagnosticArray',
    PARAMETERS_TOPIC: 'std_msgs/msg/String',
    SCENARIO_TOPIC: 'std_msgs/msg/String',
}
"""The topics a recorder records and the tools read (``sim/lockstep``, the lock-step protocol,
and ``cnc/motion``, whose values each tick used are in ``follow/status``, are not among
them)."""

SEQ_FIELD: dict[str, str] = {
    GAP_TOPIC: 'seq',
    FEEDBACK_TOPIC: 'seq',
    COMMAND_TOPIC: 'seq',
    STATUS_TOPIC: 'tick',
    TRUTH_TOPIC: 'seq',
}
"""2 kHz topics whose first field after the header is a +1-per-message counter."""
