"""QoS profiles of the contract topics (docs/interfaces.md, "QoS").

* High-rate publishers (sensor, feedback, command, status, truth): BEST_EFFORT, VOLATILE,
  KEEP_LAST 100. Measured here (docs/follow-node.md): with RELIABLE writers and a recorder on a
  loaded 2-core machine, the reliability protocol (heartbeats, acknacks, repairs for two readers
  per topic at 2 kHz) cost enough CPU that the writers' keep-last history overflowed and the
  recorder lost 7-50 % of the samples; best effort lost 0-0.1 %. Every sample carries a seq
  counter, so a loss is measured, never silent.
* Control-path subscriptions (the controller's inputs, the drive's command input): BEST_EFFORT,
  KEEP_LAST 1. A control loop wants the freshest sample: with a deeper queue a reader that falls
  behind works through old samples (input age grew to depth x 0.5 ms), and a late sample is
  useless to a zero-order hold. Samples superseded before use are counted from the seq gaps.
* The recorder subscribes best effort with a deep reader history (docs/bags-and-reports.md).
* Events (follow commands and parameter sets as applied): RELIABLE, TRANSIENT_LOCAL, KEEP_LAST
  100, so a recorder started late still gets the parameter set in force.
* run/parameters, run/scenario (std_msgs/String): RELIABLE, TRANSIENT_LOCAL, KEEP_LAST 1: the
  parameter set in force and the scenario text, for self-describing bags.
* /diagnostics: the ROS default (RELIABLE, VOLATILE, KEEP_LAST 10).
* Lock step (sim node and follow node with ``lockstep`` / ``loop: lockstep``, docs/follow-node.md):
  the 2 kHz topics and ``sim/lockstep`` RELIABLE, VOLATILE; writers KEEP_LAST 20000 (10 s of
  history for a recorder that falls behind: reliable repairs, nothing lost; 1000, half a
  second, lost 18 samples of a 4 s run while the machine ran two other node sets),
  control inputs KEEP_LAST 1 (the sim publishes step k+1 only after the answer to step k, so
  nothing is superseded).

A driver for the real axis uses the same profiles (ladrc_sim's sim node defines the same ones
on its side: the sim must not import this package).
"""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

HIGH_RATE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                       reliability=ReliabilityPolicy.BEST_EFFORT,
                       durability=DurabilityPolicy.VOLATILE)
CONTROL_INPUT = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
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
LOCKSTEP_HIGH_RATE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=20000,
                                reliability=ReliabilityPolicy.RELIABLE,
                                durability=DurabilityPolicy.VOLATILE)
LOCKSTEP_INPUT = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                            reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.VOLATILE)
