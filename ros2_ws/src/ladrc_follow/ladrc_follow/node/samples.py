"""The follow node's inputs: the samples its loop thread takes, as the plain values a tick uses.

The capacitive height, the axis feedback and (lock step) the sim's step are taken straight from
their readers as raw CDR (:mod:`ladrc_contract.loop_io`) and parsed without an rclpy message.
Per sample: its sequence bookkeeping (samples never received, a new one for the coming tick),
its receive time on the steady clock (the middleware's reception, so a late take does not age
it), the plausibility of its sender's stamp (``stamp_tolerance_s``), and for the capacitive
reading the raw -> gap table when one is configured (``sensor.table_file``). Safety: a reading
whose stamp is implausible is invalid; an encoder position whose stamp is implausible is NaN,
which the core turns into a FAULT (docs/follow-node.md, "Input freshness").
"""

from __future__ import annotations

import math
import time
from typing import Any

from ladrc_contract.cdr import CdrPacker
from ladrc_contract.codes import GapStatus
from ladrc_contract.loop_io import LoopReader
from ladrc_contract.tick import CncInput
from ladrc_contract.topics import CNC_MOTION_TOPIC, FEEDBACK_TOPIC, GAP_TOPIC

from ..control.cap_table import RawToGap


def sim_time_s(stamp_ns: int, period_ns: int, h_s: float) -> float:
    """Seconds of a lock-step stamp, exactly as the headless runner counts time (k * h_s).

    The sim's clock advances by whole periods: a stamp of step k (k * period_ns) gives
    ``k * h_s`` bit for bit (the runner's ``np.arange(n) * h_s``); a stamp between two steps
    adds its remainder.
    """
    k, rest_ns = divmod(stamp_ns, period_ns)
    return k * h_s + rest_ns * 1e-9 if rest_ns else k * h_s


class SampleInputs:
    """The latest sample of each input (zero-order hold) and what the loop knows about them.

    ``readers``: the gap, feedback and (lock step) step readers; ``clock``: the node clock
    (ROS time); ``t0_ns``: the steady-clock start the tick times count from.
    """

    def __init__(self, gap_reader: LoopReader, fb_reader: LoopReader,
                 step_reader: LoopReader | None, *, clock: Any, system_clock: bool,
                 t0_ns: int, h_s: float, stamp_tolerance_s: float, sync: bool,
                 sample_period_tolerance: float, cnc_reader: LoopReader | None = None) -> None:
        self.gap_reader, self.fb_reader, self.step_reader = gap_reader, fb_reader, step_reader
        self.cnc_reader = cnc_reader
        self.lockstep = step_reader is not None
        self._clock, self._system_clock, self._t0_ns = clock, system_clock, t0_ns
        self.h_s = h_s
        self.period_ns = int(round(h_s * 1e9))
        self._stamp_tol_ns = int(stamp_tolerance_s * 1e9)
        self._sync = sync
        self._period_tolerance = sample_period_tolerance
        self.cap_table: RawToGap | None = None  # the node's sensor.table_file, when set
        self._gap_cdr = CdrPacker('ladrc_msgs/msg/CapacitiveHeight')
        self._fb_cdr = CdrPacker('ladrc_msgs/msg/AxisFeedback')
        self._step_cdr = CdrPacker('ladrc_msgs/msg/LockStep')
        self._cnc_cdr = CdrPacker('ladrc_msgs/msg/CncMotion')
        ci = self._cnc_cdr.index
        self._cnc_fields = [ci[n] for n in (
            'header.stamp.sec', 'header.stamp.nanosec', 'seq', 'segment', 'beam_on', 'contour',
            'commanded_feed_mm_s', 'actual_feed_mm_s', 'segment_left_mm', 'edge_ahead_mm')]
        self.cnc: CncInput | None = None  # the CNC's newest motion sample, until a tick takes it
        self._cnc_last_seq = -1
        gi, fi = self._gap_cdr.index, self._fb_cdr.index
        self._gap_fields = [gi[n] for n in ('header.stamp.sec', 'header.stamp.nanosec', 'seq',
                                            'gap_mm', 'raw_hz', 'valid', 'status')]
        self._fb_fields = [fi[n] for n in ('header.stamp.sec', 'header.stamp.nanosec', 'seq',
                                           'position_mm', 'drive_enabled', 'drive_fault')]
        # the latest samples, as the tick uses them
        self.gap_seq = 0
        self.gap_mm = math.nan
        self.gap_valid = False
        self.gap_status = int(GapStatus.FAULT)
        self.gap_stamp_s = -math.inf
        self.enc_seq = 0
        self.enc_mm = math.nan
        self.enc_stamp_s = -math.inf
        self.drive_enabled = False
        self.drive_fault = False
        self.last_reading: tuple[float, float, bool, int, bool] | None = None
        # counts for /diagnostics
        self.stamp_rejects = 0
        self.last_stamp_reject = ''  # the newest rejected stamp
        self.malformed_samples = 0  # samples whose bytes are not the contract's message
        self.missed_gap_samples = 0
        self.missed_feedback_samples = 0
        self._gap_last_seq = -1
        self._enc_last_seq = -1
        # loop 'sync': a sample of each input for the coming tick's cycle has arrived. Each tick
        # consumes one cycle of each input (the seq it waits for next), also a tick on the own
        # deadline: a sample that comes after its cycle was ticked without it is held for the
        # next tick and starts none of its own (two ticks within one period would integrate
        # the core's h_s twice).
        self.new_gap = False
        self.new_feedback = False
        self._gap_expect = 0
        self._fb_expect = 0
        self._rate_window: tuple[int, int] | None = None  # (first seq, its receive ns)
        self.sample_period_s = math.nan  # measured from the feedback seq (loop 'sync')
        self.period_fault = ''
        # lock step: the step waiting for its samples (step, gap seq, fresh, encoder seq, fresh,
        # stamp ns, CNC seq, fresh), and when the last one came (wall clock)
        self.step: tuple[int, int, bool, int, bool, int, int, bool] | None = None
        self.step_wall_ns = 0

    # ---- taking ---------------------------------------------------------------------------
    def take(self) -> None:
        """Take what waits in the readers (oldest first) into the latest-sample values."""
        for reader, on in ((self.gap_reader, self._on_gap), (self.fb_reader, self._on_feedback),
                           (self.step_reader, self._on_step),
                           (self.cnc_reader, self._on_cnc)):
            if reader is None:
                continue
            while (taken := reader.take()) is not None:
                on(*taken)

    def _parse(self, packer: CdrPacker, data: bytes) -> list[Any] | None:
        """Leaf values of a sample's CDR; None (counted) when the bytes are not the message."""
        try:
            return packer.unpack(data)
        except ValueError:
            self.malformed_samples += 1
            return None

    def _receive(self, topic: str, stamp_ns: int, received_ns: int) -> tuple[float, bool]:
        """Return the receive time (s since start, steady clock) and the stamp's plausibility.

        Plausible: the sender's stamp is within ``stamp_tolerance_s`` of the node clock at
        reception (ROS time: the middleware's reception stamp on the system clock, or /clock
        with ``use_sim_time``; not in the future, not delayed or skewed by more than that).
        The receive time is that reception, on the steady clock: a loop that takes the sample
        late does not make it look older than it is, nor fresher.

        Lock step: the sample time is the sender's stamp on the sim's clock
        (:func:`sim_time_s`); its age is judged by the core at the step's tick.
        """
        if self.lockstep:
            return sim_time_s(stamp_ns, self.period_ns, self.h_s), True
        mono = time.monotonic_ns()
        if self._system_clock:
            # how long ago it arrived (a clock step in between counts as now)
            ago_ns = min(max(time.time_ns() - received_ns, 0), 1_000_000_000)
            reference_ns = received_ns
        else:
            ago_ns, reference_ns = 0, self._clock.now().nanoseconds
        skew_ns = stamp_ns - reference_ns
        ok = -self._stamp_tol_ns <= skew_ns <= self._stamp_tol_ns
        if not ok:
            self.stamp_rejects += 1
            self.last_stamp_reject = (
                f'{topic} stamp {skew_ns * 1e-6:+.3f} ms from its reception on the node clock '
                f'(tolerance {self._stamp_tol_ns * 1e-6:g} ms)')
        return (mono - ago_ns - self._t0_ns) * 1e-9, ok

    def _on_gap(self, data: bytes, received_ns: int) -> None:
        values = self._parse(self._gap_cdr, data)
        if values is None:
            return
        sec, nsec, seq, gap_mm, raw_hz, valid, status = (values[i] for i in self._gap_fields)
        if self._gap_last_seq >= 0 and seq > self._gap_last_seq + 1:
            self.missed_gap_samples += seq - self._gap_last_seq - 1
        self._gap_last_seq = seq
        self.gap_seq = seq
        if seq >= self._gap_expect or seq + 64 < self._gap_expect:  # (a restarted sender)
            self.new_gap = True
        self.gap_stamp_s, stamp_ok = self._receive(GAP_TOPIC, sec * 1_000_000_000 + nsec,
                                                   received_ns)
        self.last_reading = (gap_mm, raw_hz, valid, status, stamp_ok)
        self.set_reading(*self.last_reading)

    def set_reading(self, gap_mm: float, raw_hz: float, valid: bool, status: int,
                    stamp_ok: bool) -> None:
        """Set the reading the tick uses: as sent, or converted by the node's table."""
        table = self.cap_table
        if table is None:
            self.gap_mm = gap_mm
            self.gap_valid = valid and stamp_ok
            self.gap_status = status if stamp_ok else int(GapStatus.FAULT)
        else:
            # the controller converts raw -> gap (docs/calibration.md); outside the table:
            # invalid, never extrapolated
            gap, ok, st = table.convert(raw_hz, valid, status)
            self.gap_mm = gap
            self.gap_valid = ok and stamp_ok
            self.gap_status = st if stamp_ok else int(GapStatus.FAULT)

    def _on_feedback(self, data: bytes, received_ns: int) -> None:
        values = self._parse(self._fb_cdr, data)
        if values is None:
            return
        sec, nsec, seq, position_mm, enabled, fault = (values[i] for i in self._fb_fields)
        if self._enc_last_seq >= 0 and seq > self._enc_last_seq + 1:
            self.missed_feedback_samples += seq - self._enc_last_seq - 1
        self._enc_last_seq = seq
        self.enc_seq = seq
        if seq >= self._fb_expect or seq + 64 < self._fb_expect:  # (a restarted sender)
            self.new_feedback = True
        if self._sync:
            self._check_sample_period(seq)
        self.enc_stamp_s, stamp_ok = self._receive(FEEDBACK_TOPIC, sec * 1_000_000_000 + nsec,
                                                   received_ns)
        self.enc_mm = position_mm if stamp_ok else math.nan  # not finite: a fault
        self.drive_enabled = enabled
        self.drive_fault = fault

    def _on_cnc(self, data: bytes, received_ns: int) -> None:
        """Take the CNC's motion sample: its values as sent, timed by its reception here.

        An implausible stamp makes it stale at once (receive time -inf): the core then holds
        the height, as for a CNC gone silent (control/follow/cnc.py).
        """
        values = self._parse(self._cnc_cdr, data)
        if values is None:
            return
        sec, nsec, seq, seg, beam, contour, cmd, act, left, ahead = (
            values[i] for i in self._cnc_fields)
        stamp_s, ok = self._receive(CNC_MOTION_TOPIC, sec * 1_000_000_000 + nsec, received_ns)
        self._cnc_last_seq = seq
        self.cnc = CncInput(max(seq, 1), stamp_s if ok else -math.inf, seg, beam, contour, cmd,
                            act, left, ahead)

    def _check_sample_period(self, seq: int) -> None:
        """Loop 'sync': the feedback's sample period (seq over receive time, 2 s) against h_s.

        The core is discretised at h_s: ticks on samples of another period would integrate the
        observer and the reference at the wrong rate. Counted from the sender's seq over this
        node's own receive clock, so neither the sender's stamps nor one late sample decide.
        """
        now = time.monotonic_ns()
        if self._rate_window is None or seq <= self._rate_window[0]:
            self._rate_window = (seq, now)
            return
        seq0, t0 = self._rate_window
        if now - t0 < 2_000_000_000:
            return
        self._rate_window = (seq, now)
        self.sample_period_s = (now - t0) * 1e-9 / (seq - seq0)
        deviation = self.sample_period_s / self.h_s - 1.0
        if abs(deviation) <= self._period_tolerance:
            self.period_fault = ''  # back within tolerance: a reset clears the fault
        elif not self.period_fault:
            self.period_fault = (
                f'sample period {self.sample_period_s * 1e3:.3f} ms of axis/feedback differs '
                f'from the controller period h_s {self.h_s * 1e3:g} ms by {deviation:+.0%} '
                f'(tolerance {self._period_tolerance:.0%}): the core is discretised at h_s')

    def _on_step(self, data: bytes, received_ns: int) -> None:
        """Lock step: the sim published step ``step``; tick once its samples are here."""
        values = self._parse(self._step_cdr, data)
        if values is None:
            return
        sec, nsec, _frame, step, gap_seq, gap_fresh, enc_seq, enc_fresh, cnc_seq, cnc_fresh = (
            values)
        self.step = (step, gap_seq, gap_fresh, enc_seq, enc_fresh, sec * 1_000_000_000 + nsec,
                     cnc_seq, cnc_fresh)
        self.step_wall_ns = time.monotonic_ns()

    # ---- what the loop asks ---------------------------------------------------------------
    def step_ready(self, topology_problem: bool) -> bool:
        """Lock step: a step is waiting and the samples it names have arrived.

        With a topology problem (another publisher may have superseded a sample) the step is
        answered without them: the tick faults and commands zero.
        """
        s = self.step
        return s is not None and (topology_problem or (
            (not s[2] or self._gap_last_seq == s[1]) and (not s[4] or self._enc_last_seq == s[3])
            and (not s[7] or self._cnc_last_seq == s[6])))

    def consume_cycle(self) -> bool:
        """Loop 'sync': this tick takes one cycle of each input; False if one was missing."""
        both = self.new_gap and self.new_feedback
        self._gap_expect = self.gap_seq + 1 if self.new_gap else self._gap_expect + 1
        self._fb_expect = self.enc_seq + 1 if self.new_feedback else self._fb_expect + 1
        self.new_gap = self.new_feedback = False
        return both
