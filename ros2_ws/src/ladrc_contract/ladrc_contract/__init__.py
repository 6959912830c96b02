"""The contract written once: what controller, drive and tools share besides ``ladrc_msgs``.

* :mod:`.topics`, :mod:`.qos`, :mod:`.codes`, :mod:`.events`, :mod:`.services`: the topics and
  types, the QoS profiles as data, the message codes, the follow-command <-> event codec, the
  follow services table;
* :mod:`.tick`: ``TickInput``, what one tick of the controller takes;
* :mod:`.schema`: the one declaration of a parameter (controller and simulator alike);
* :mod:`.ops`: scalar and array arithmetic, so each step function (controller and simulator
  models) is written once and runs on floats or on rows;
* :mod:`.cdr`: pre-serialized CDR of one message type, both ways (publish bytes, parse bytes);
* :mod:`.loop_io`: a loop node's readers, taken from straight by its loop thread, and the wait
  for a new sample; :mod:`.service_thread`: an executor on a thread of its own;
* :mod:`.realtime`: SCHED_FIFO, CPU affinity, locked memory, timer slack for a loop process.

Its own package because the drive (``ladrc_sim``, or a real driver) may import neither the
controller nor the tools, and both sides need these (docs/architecture.md).
"""
