"""QoS profiles of the contract topics (docs/interfaces.md, "QoS").

* High-rate publishers (sensor, feedback, command, status, truth): RELIABLE, VOLATILE,
  KEEP_LAST 100. Reliable so that the recorder, which subscribes reliably, can keep every
  message (its loss count from the seq counters must be 0); depth 100 (50 ms at 2 kHz) rides
  out a scheduling hiccup of the subscriber without dropping.
* Control-path subscriptions (the controller's inputs, the drive's command input): BEST_EFFORT,
  KEEP_LAST 10. A control loop wants the freshest sample: a reliable reader that lost a sample
  would hold newer ones back until the repair arrives, adding latency exactly when things go
  wrong, and a late sample is useless to a zero-order hold. A best-effort reader matches a
  reliable writer; loss is measured from the seq counters and reported in /diagnostics.
* Events (follow commands and parameter sets as applied): RELIABLE, TRANSIENT_LOCAL, KEEP_LAST
  100, so a recorder started late still gets the parameter set in force.
* run/parameters, run/scenario (std_msgs/String): RELIABLE, TRANSIENT_LOCAL, KEEP_LAST 1: the
  parameter set in force and the scenario text, for self-describing bags.
* /diagnostics: the ROS default (RELIABLE, VOLATILE, KEEP_LAST 10).

A driver for the real axis uses the same profiles (ladrc_sim's sim node defines the same ones
on its side: the sim must not import this package).
"""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

HIGH_RATE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
CONTROL_INPUT = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                           reliability=ReliabilityPolicy.BEST_EFFORT,
                           durability=DurabilityPolicy.VOLATILE)
EVENTS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                    reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL)
# run/parameters, run/scenario: the texts that make a bag self-describing (latched, last one).
RUN_TEXT = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
DIAGNOSTICS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
