"""The inputs of one controller tick: what a driver publishes, as plain values.

One definition for the controller (``FollowController.step``), the headless runner that steps
it, and the follow node that builds it from the samples it took.
"""

from __future__ import annotations

from typing import NamedTuple


class TickInput(NamedTuple):
    """Inputs of one controller tick.

    ``gap_status`` is ``CapacitiveHeight.status`` (:class:`~ladrc_contract.codes.GapStatus`);
    it is the last field and has a default, so an 8-field tuple is accepted too: a status of 0
    with ``gap_valid`` false means "not reported" and the controller infers the cause from the
    reading (at or below its collision gap: collision; otherwise out of range / miss-panel).
    """

    t_s: float
    gap_mm: float
    gap_valid: bool
    gap_stamp_s: float
    encoder_mm: float
    encoder_stamp_s: float
    drive_enabled: bool
    drive_fault: bool
    gap_status: int = 0


class CncInput(NamedTuple):
    """The CNC's motion sample a tick used (``ladrc_msgs/CncMotion``, docs/interfaces.md).

    ``stamp_s`` is its receive time on the tick's clock (``TickInput.t_s``), not the CNC's own
    stamp; ``seq`` 0 means none was ever received: the controller then runs without CNC
    features, as before the CNC interface. ``FollowStatus.cnc_*`` records it for replay.
    """

    seq: int
    stamp_s: float
    segment: int
    beam_on: bool
    contour: int
    commanded_feed_mm_s: float
    actual_feed_mm_s: float
    segment_left_mm: float
    edge_ahead_mm: float


NO_CNC = CncInput(0, float('nan'), 0, False, 0, float('nan'), float('nan'), float('nan'),
                  float('nan'))
"""No CNC motion received (``FollowStatus.cnc_seq`` 0)."""
