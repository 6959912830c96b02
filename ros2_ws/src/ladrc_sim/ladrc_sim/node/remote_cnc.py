"""The sim node's link to a separate CNC: the job runner's CNC is the CNC node on the wire.

With ``separate_cnc`` the sim node plays the axis, the sheet and the sensor only; the CNC is
the CNC node (:mod:`.cnc_node`, or a bridge to a real CNC). :class:`RemoteCnc` stands in for
the CNC in :func:`ladrc_sim.job.runner.run_job`: ``step`` returns the CNC's motion sample taken
this tick (``cnc/motion``; the runner's world sees the CNC through it,
:class:`ladrc_sim.job.world.MotionView`), ``xy`` that sample's XY, and ``ended``/``log`` once
the CNC has published its job's end on ``cnc/job`` (its log as JSON: the job's figures take
the pierces, feed hold, finished and aborted from it).

Live: the newest sample that arrived. Lock step: the CNC node publishes ``cnc/lockstep`` k
(a ``LockStep`` naming its sample of step k, if its cycle has one) after stepping k; step k of
the sim waits for it and for that sample, and names the sample in its own ``sim/lockstep`` k
(the controller's tick waits for it): the headless runner's order with ``separate_cnc``.
"""

from __future__ import annotations

import json
import math
from typing import Any

from ladrc_contract.cdr import CdrPacker
from ladrc_contract.tick import CncInput

from ..job.cnc import CncLog

MOTION_FIELDS = ('header.stamp.sec', 'header.stamp.nanosec', 'seq', 'segment', 'beam_on',
                 'contour', 'commanded_feed_mm_s', 'actual_feed_mm_s', 'segment_left_mm',
                 'edge_ahead_mm', 'x_mm', 'y_mm')


def log_from_json(text: str) -> CncLog:
    """Return the CNC's log from the JSON the CNC node publishes on ``cnc/job``."""
    data = json.loads(text)
    return CncLog(pierces=int(data['pierces']), feed_hold_ticks=int(data['feed_hold_ticks']),
                  waits=[tuple(w) for w in data.get('waits', [])],
                  aborted=str(data['aborted']), finished=bool(data['finished']))


def log_to_json(log: CncLog) -> str:
    """Return the CNC's log as the JSON of ``cnc/job``."""
    return json.dumps({'pierces': log.pierces, 'feed_hold_ticks': log.feed_hold_ticks,
                       'waits': log.waits, 'aborted': log.aborted, 'finished': log.finished})


class RemoteCnc:
    """The job runner's CNC in the sim node when the CNC node plays it (module docstring)."""

    def __init__(self, node: Any, bridge: Any) -> None:
        """``node``: the sim node (``cnc_reader``, ``cnc_step_reader``, ``cnc_job_reader``)."""
        self.node = node
        self.bridge = bridge
        self.lockstep = bridge.lockstep
        self._motion = CdrPacker('ladrc_msgs/msg/CncMotion')
        self._fields = [self._motion.index[n] for n in MOTION_FIELDS]
        self._step_cdr = CdrPacker('ladrc_msgs/msg/LockStep')
        si = self._step_cdr.index
        self._step_fields = [si[n] for n in ('step', 'cnc_seq', 'cnc_fresh')]
        self._text = CdrPacker('std_msgs/msg/String')
        self.log = CncLog()
        self.ended = False
        self.xy = (math.nan, math.nan)
        self._samples: dict[int, tuple] = {}  # lock step: samples by seq, until their step
        self._steps: dict[int, tuple[int, bool]] = {}  # lock step: step -> (cnc_seq, fresh)
        self._newest: tuple | None = None  # live: the newest sample not taken yet

    def _take(self) -> None:
        for data, _ in iter(self.node.cnc_reader.take, None):
            try:
                values = self._motion.unpack(data)
            except ValueError:
                continue  # not a CncMotion: nobody's sample
            sample = tuple(values[i] for i in self._fields)
            if self.lockstep:
                self._samples[sample[2]] = sample
            else:
                self._newest = sample
        if self.lockstep:
            for data, _ in iter(self.node.cnc_step_reader.take, None):
                try:
                    values = self._step_cdr.unpack(data)
                except ValueError:
                    continue
                step, seq, fresh = (values[i] for i in self._step_fields)
                self._steps[step] = (seq, bool(fresh))

    def _end(self) -> bool:
        """Take the CNC's end of job (``cnc/job``) if it came; return whether it did."""
        for data, _ in iter(self.node.cnc_job_reader.take, None):
            try:
                self.log = log_from_json(self._text.unpack(data)[0])
            except (ValueError, KeyError, TypeError):
                continue  # not the CNC node's log: not an end
            self.ended = True
        return self.ended

    def _ready(self, step: int) -> bool:
        self._take()
        named = self._steps.get(step)
        if named is not None:
            return not named[1] or named[0] in self._samples
        return self._end()

    def step(self, answers: dict) -> CncInput | None:
        """Return the CNC's sample taken this tick (None: none); ``ended`` once the job ended."""
        if self.lockstep:
            k = self.bridge.seq
            self.bridge._await(lambda: self._ready(k), f'no CNC step {k} on cnc/lockstep')
            named = self._steps.pop(k, None)
            if named is None:  # the CNC ended its job instead of stepping
                return None
            seq, fresh = named
            self.node.cnc_seq, self.node.cnc_fresh = seq, fresh
            sample = self._samples.pop(seq) if fresh else None
        else:
            self._take()
            sample, self._newest = self._newest, None
            if sample is None and self._end():
                return None
        if sample is None:
            return None
        sec, nsec, seq, seg, beam, contour, cmd, act, left, ahead, x, y = sample
        self.xy = (x, y)
        return CncInput(seq, sec + nsec * 1e-9, seg, beam, contour, cmd, act, left, ahead)

    def refused(self, name: str, message: str) -> None:
        """Ignore: the CNC node sends the commands, nothing is refused here."""
