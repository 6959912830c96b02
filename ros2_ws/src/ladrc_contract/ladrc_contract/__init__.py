"""What the nodes of the set share besides ``ladrc_msgs``: the loop's I/O and its real-time set-up.

* :mod:`.cdr`: pre-serialized CDR of one message type, both ways (publish bytes, parse bytes);
* :mod:`.loop_io`: a loop node's readers, taken from straight by its loop thread, and the wait
  for a new sample;
* :mod:`.realtime`: SCHED_FIFO, CPU affinity, locked memory for a loop process.

Its own package because the drive (``ladrc_sim``, or a real driver) may import neither the
controller nor the tools, and both sides need these (docs/architecture.md).
"""
