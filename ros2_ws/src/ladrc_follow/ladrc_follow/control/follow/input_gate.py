"""The input gate: what of a tick's inputs may reach the control law, as a verdict with its reason.

Trust no sensor's own claims beyond what the encoder confirms (docs/follow-state-machine.md,
"Faults"): the drive's state, the stamps' age and direction, finite values, the sensor's status
and validity, then the reading itself against the encoder: a tick without a new sample runs on
the encoder-predicted gap (notes §4, the Kalman predict step), a run of bit-identical samples
while the encoder moves is a frozen sensor, and a reading that widens faster than a sheet can
fall (``follow.jump_mm``) is held by the void lock (control/void_lock.py) until it persists for
``follow.jump_confirm_s``.

The gate never changes the follow state: it returns a verdict (:data:`USABLE`, :data:`HOLD`,
:data:`FAULT`, :data:`COLLISION`, :data:`DRIVE`) and, for the last three, ``reason``; the state
machine acts on it.
"""

from __future__ import annotations

import math

from ladrc_contract.codes import FaultCode

from ..void_lock import VoidLock
from .states import GAP_STATUS_COLLISION, GAP_STATUS_FAULT, GAP_STATUS_OUT_OF_RANGE

USABLE, HOLD, FAULT, COLLISION, DRIVE = 0, 1, 2, 3, 4
_STALE, _SENSOR, _ENCODER, _COLLISION_CODE = (int(c) for c in (
    FaultCode.STALE_INPUT, FaultCode.SENSOR, FaultCode.ENCODER, FaultCode.COLLISION))
"""Verdicts: the (possibly predicted) gap may be used; hold (nothing further down, the law not
stepped); fault; fault and retract (collision evidence); the drive faulted or disabled."""


class InputGate:
    """Screens each tick's inputs (``screen``) and those of a follow that starts (``lock``).

    Its counters of rejected samples go into the controller's ``counts``; its memory of the
    samples (the last accepted reading and the encoder then, the frozen-value run, the
    low-passed share of invalid samples) survives parameter changes, as the controller's void
    lock (``void``), which judges a jump.
    """

    def __init__(self, counts: dict[str, int], void: VoidLock) -> None:
        self.counts = counts
        self.void = void
        self.reason = ''
        self.code = 0  # the FaultCode of a FAULT or COLLISION verdict
        self.gap_mm = math.nan  # the gap the law may use (USABLE): the reading or its prediction
        self.fresh = True       # this tick's gap is a new sample (not the encoder prediction)
        self._used_stamp_s = math.nan  # stamp of the sample used last
        self._accepted_gap_mm = math.nan  # the last reading accepted, and the encoder then
        self._accepted_enc_mm = math.nan
        self._same_count = 0
        self._same_enc0_mm = math.nan
        self._invalid_share = 0.0   # low-passed share of invalid samples
        self._invalid_ticks = 0
        self._miss_ticks = 0

    def configure(self, follow, h_s: float) -> None:
        """Take the limits of a parameter set (``ControllerParams.follow``, the tick ``h_s``)."""
        self._h = h_s
        self._stale_s = follow.stale_timeout_s
        self._collision_mm = follow.collision_gap_mm
        self._retract_mm = follow.retract_distance_mm
        self._share_rate = h_s / (follow.invalid_rate_tau_s + h_s)  # backward Euler, as pid.py
        self._share_tau_s = follow.invalid_rate_tau_s
        self._share_max = follow.invalid_rate_max
        self._invalid_max = max(1, int(round(follow.invalid_timeout_s / h_s)))
        self._miss_max = max(1, int(round(follow.miss_panel_s / h_s)))
        self._frozen_count = follow.frozen_ticks
        self._frozen_mm = follow.frozen_travel_mm

    def collision_evidence(self, gap_mm: float, valid: bool, status: int) -> bool:
        """Return whether the sensor reports contact or a reading is at or below the limit."""
        return status == GAP_STATUS_COLLISION or (
            math.isfinite(gap_mm) and gap_mm <= self._collision_mm and (valid or not status))

    def _verdict(self, verdict: int, reason: str, code: int = 0) -> int:
        self.reason = reason
        self.code = code if code else (_COLLISION_CODE if verdict == COLLISION else 0)
        return verdict

    def lock(self, tick: tuple) -> tuple[int, str]:
        """LOCKING: ``(USABLE, '')``, ``(HOLD, why not yet)`` or ``(COLLISION, reason)``."""
        t, gap, valid, gstamp, enc, estamp, den, dfault, status = tick
        s = self._stale_s
        if dfault:
            return HOLD, 'the drive reports a fault'
        if not den:
            return HOLD, 'the drive is not enabled'
        if not (t - gstamp <= s and t - estamp <= s):
            return HOLD, 'inputs are stale'
        if not (gstamp <= t + self._h and estamp <= t + self._h):
            return HOLD, 'inputs are stamped in the future'
        if not math.isfinite(enc):
            return HOLD, 'the encoder position is not finite'
        if self.collision_evidence(gap, valid, status):
            return COLLISION, (f'collision at start: gap reading {gap:.3f} mm (limit '
                               f'{self._collision_mm:g} mm); retracting {self._retract_mm:g} mm')
        if not valid or status:
            return HOLD, ('no sheet under the nozzle / reading out of range'
                          if status in (0, GAP_STATUS_OUT_OF_RANGE)
                          else 'the gap sensor reports a fault')
        if not math.isfinite(gap):
            return HOLD, 'the gap reading is not finite'
        return USABLE, ''

    def screen_axis(self, tick: tuple) -> int:
        """Screen a tick of a planned move (lift, leapfrog): the drive, the encoder, contact.

        The reading is not needed to move up or to hold (a rapid crosses holes and kerfs, a lift
        may leave the sensor's range); collision evidence still retracts.
        """
        t, gap, valid, _gstamp, enc, estamp, den, dfault, status = tick
        if dfault or not den:
            return DRIVE
        if not (t - estamp <= self._stale_s and estamp <= t + self._h):
            return self._verdict(FAULT, f'stale encoder: age {(t - estamp) * 1e3:.3g} ms '
                                        f'(limit {self._stale_s * 1e3:.3g} ms)', _STALE)
        if not math.isfinite(enc):
            return self._verdict(FAULT, f'encoder position not finite ({enc!r})', _ENCODER)
        if self.collision_evidence(gap, valid, status):
            return self._verdict(COLLISION, f'collision during a planned move: gap reading '
                                            f'{gap:.3f} mm, status {status}; retracting '
                                            f'{self._retract_mm:g} mm')
        self._miss_ticks = self._invalid_ticks = 0  # out of range up here is no miss-panel
        return USABLE

    def screen(self, tick: tuple) -> int:
        """Screen a following tick: the verdict; ``gap_mm`` and ``fresh`` when :data:`USABLE`."""
        t, gap, valid, gstamp, enc, estamp, den, dfault, status = tick
        if dfault or not den:
            return DRIVE
        s = self._stale_s
        if not (t - gstamp <= s and t - estamp <= s):
            return self._verdict(FAULT, f'stale input: gap age {(t - gstamp) * 1e3:.3g} ms, '
                                        f'encoder age {(t - estamp) * 1e3:.3g} ms '
                                        f'(limit {s * 1e3:.3g} ms)', _STALE)
        if not (gstamp <= t + self._h and estamp <= t + self._h):
            # a sample from the future: a clock the controller cannot trust
            return self._verdict(FAULT, f'input stamped in the future: gap '
                                        f'{(gstamp - t) * 1e3:.3g} ms, encoder '
                                        f'{(estamp - t) * 1e3:.3g} ms ahead of the tick',
                                 _STALE)
        if not math.isfinite(enc):
            return self._verdict(FAULT, f'encoder position not finite ({enc!r})', _ENCODER)
        if status == GAP_STATUS_COLLISION:
            return self._verdict(COLLISION, 'collision: the sensor reports nozzle contact; '
                                            f'retracting {self._retract_mm:g} mm')
        if not valid or status:
            return self._unusable(gap, status)
        if not math.isfinite(gap):
            return self._verdict(FAULT, f'gap reading not finite ({gap!r}) though marked valid',
                                 _SENSOR)
        if gap <= self._collision_mm:
            return self._verdict(COLLISION, f'collision: gap reading {gap:.3f} mm <= limit '
                                            f'{self._collision_mm:g} mm; retracting '
                                            f'{self._retract_mm:g} mm')
        self._invalid_ticks = self._miss_ticks = 0
        self._invalid_share -= self._share_rate * self._invalid_share
        return self._sample(t, gap, gstamp, enc)

    def _sample(self, t: float, gap: float, gstamp: float, enc: float) -> int:
        """Judge a valid reading against the encoder: new or predicted, frozen, jumped."""
        if gstamp == self._used_stamp_s and not math.isnan(self._accepted_gap_mm):
            # no new sample since the last tick: the law never runs twice on one reading; the
            # encoder increment predicts the gap (notes §4, the Kalman predict step)
            self.counts['predicted'] += 1
            self.fresh = False  # the Kalman filters only predict on this tick
            if self.void.jump_held:
                return self._verdict(HOLD, self.void.reason)  # still holding a jumped reading
            self.gap_mm = self._accepted_gap_mm + (enc - self._accepted_enc_mm)
            return USABLE
        self._used_stamp_s = gstamp
        self.fresh = True
        if gap == self._accepted_gap_mm:
            # bit-identical to the last new sample: a real reading has noise, so a run of
            # them while the encoder moves is a frozen sensor with fresh stamps
            self._same_count += 1
            moved = enc - self._same_enc0_mm
            if self._same_count >= self._frozen_count and abs(moved) > self._frozen_mm:
                self.counts['frozen'] += 1
                return self._verdict(FAULT, f'frozen gap reading: {self._same_count + 1} '
                                            f'identical samples ({gap:.4f} mm) while the '
                                            f'encoder moved {moved:+.3f} mm', _SENSOR)
        else:
            self._same_count, self._same_enc0_mm = 0, enc
        if self.void.sample(t, gap - (self._accepted_gap_mm + (enc - self._accepted_enc_mm))):
            # the reading widened by more than a sheet can fall away in one sample: not
            # followed down; a level that persists for jump_confirm_s is taken as real
            return self._verdict(HOLD, self.void.reason)
        self._accepted_gap_mm, self._accepted_enc_mm = gap, enc
        self.gap_mm = gap
        return USABLE

    def _unusable(self, gap: float, status: int) -> int:
        """Count an unusable reading; hold, or fault after the allowed time or share."""
        finite = math.isfinite(gap)
        # the share of invalid samples (low-passed): interleaved valid ones do not hide them
        share = self._invalid_share + self._share_rate * (1.0 - self._invalid_share)
        self._invalid_share = share
        if share > self._share_max:
            return self._verdict(FAULT, f'gap readings invalid too often: {share:.0%} of the '
                                        f'samples over the last {self._share_tau_s:g} s '
                                        f'(limit {self._share_max:.0%})', _SENSOR)
        if status == GAP_STATUS_OUT_OF_RANGE or (
                status == 0 and finite and gap > self._collision_mm):
            self.counts['out_of_range'] += 1
            self._miss_ticks += 1
            if self._miss_ticks >= self._miss_max:
                return self._verdict(FAULT, 'miss-panel: no sheet under the nozzle (gap reading '
                                            'out of range for '
                                            f'{self._miss_ticks * self._h * 1e3:.3g} ms)',
                                     _SENSOR)
        elif status == 0 and finite:
            return self._verdict(COLLISION, f'collision: invalid gap reading {gap:.3f} mm at or '
                                            f'below the limit {self._collision_mm:g} mm; '
                                            f'retracting {self._retract_mm:g} mm')
        else:
            self._invalid_ticks += 1
            self.counts['invalid'] += 1
            if self._invalid_ticks >= self._invalid_max:
                what = 'sensor fault status' if status == GAP_STATUS_FAULT else (
                    f'status {status}' if status else 'not finite')
                return self._verdict(FAULT, f'gap reading invalid ({what}) for '
                                            f'{self._invalid_ticks * self._h * 1e3:.3g} ms',
                                     _SENSOR)
            return self._verdict(HOLD, 'gap reading invalid: held (a FAULT after '
                                       f'{self._invalid_max * self._h * 1e3:.3g} ms)')
        return self._verdict(HOLD, 'no sheet under the nozzle (reading out of range): held (a '
                                   f'miss-panel after {self._miss_max * self._h * 1e3:.3g} ms)')
