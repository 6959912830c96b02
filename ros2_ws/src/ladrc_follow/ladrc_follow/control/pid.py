"""PID follow baseline: the firmware's "3.0 algorithm" the notes compare LADRC with.

The notes (§5.3 item 5) compare LADRC against the existing follow controller
("3.0算法": suppression level 3 or 5, feed-forward coefficient 20, proportional
gain 2); ``Follow_OnStep`` (notes §3.5) shows its interface: ``SetFollowTarget``,
``SetPreOutUnitV`` (bumpless start from the interpolator), ``EnableFeedForward``
after an enable delay once followed, ``SetSuppressMode`` (vibration suppression
while machining), ``HasFollowed``. Its source is not in the notes, so this is a
careful PID with that interface — the yardstick of every comparison:

* error e = target − gap (mm); a positive error commands upward motion.
* suppression (抑振) when enabled: level L scales kp and kd by
  ``SUPPRESS_GAIN_SCALE[L]`` and shrinks the error by a continuous deadband
  ``SUPPRESS_DEADBAND_MM[L]`` (e' = e − clip(e, −db, db)), so small residual
  vibration near the target is not chased;
* P on the (deadbanded) error, D on the MEASUREMENT (−kd·ġap, no derivative
  kick on target changes) through a first-order filter of time constant
  ``d_filter_s``;
* optional I (``ki_1_s2``) with conditional integration: the integrator holds
  while the output is limited in the direction the error pushes (anti-windup);
* velocity feed-forward, active ``ff_delay_s`` after ``enable_feed_forward``:
  ``ff_ref_gain``·ṙ (filtered target rate: gradient follow / height
  compensation) + ``ff_surface_gain``·ṡ, ṡ the sheet-surface velocity estimated
  from the encoder and the gap (surface = nozzle − gap), filtered with
  ``ff_filter_s``. ṡ is what the axis has to match to hold the gap; gain 1 would
  cancel a constant surface velocity exactly, lower gains trade that against
  the noise of a differentiated capacitive reading;
* output saturation ±v_max and per-tick change limit a_max·h (same function as
  the LADRC, :func:`law.apply_limits`).

Arithmetic uses ``ops`` functions only, so the class runs on floats or on numpy
arrays (a batch of baselines) alike.
"""

from __future__ import annotations

from dataclasses import dataclass

from ladrc_contract.ops import SCALAR
from ladrc_contract.schema import Section, param

from .law import apply_limits

# Suppression level → (gain scale, deadband). Level 0 = no suppression. The
# firmware's table is not in the notes; this mapping halves the loop gain at the
# top level and ignores residual error up to 0.05 mm (10 % of the smallest gap).
SUPPRESS_GAIN_SCALE = (1.0, 0.9, 0.8, 0.7, 0.6, 0.5)
SUPPRESS_DEADBAND_MM = (0.0, 0.005, 0.01, 0.02, 0.03, 0.05)


@dataclass(frozen=True)
class PIDParams(Section):
    """Parameters of the PID baseline (``ControllerParams.pid``)."""

    PREFIX = 'pid.'

    kp_1_s: float = param(20.0, '1/s', 'proportional gain (notes: "gain 2", firmware scale '
                          'unknown; see docs/control-law.md)', gt=0.0, le=1000.0,
                          seed='notes §5.3 item 5')
    kd: float = param(0.05, '1', 'derivative gain on the measured gap rate',
                      ge=0.0, le=10.0)
    d_filter_s: float = param(0.002, 's', 'derivative low-pass time constant',
                              ge=0.0, le=1.0)
    ki_1_s2: float = param(0.0, '1/s²', 'integral gain; 0 = PD (the plant integrates)',
                           ge=0.0, le=10000.0)
    ff_ref_gain: float = param(1.0, '1', 'reference-rate feed-forward gain', ge=0.0, le=2.0)
    ff_surface_gain: float = param(0.2, '1', 'sheet-surface-rate feed-forward gain '
                                   '("feed-forward 20" read as 20 %)', ge=0.0, le=2.0,
                                   seed='notes §5.3 item 5')
    ff_filter_s: float = param(0.005, 's', 'low-pass time constant of the feed-forward rates',
                               ge=0.0, le=1.0)
    ff_delay_s: float = param(0.1, 's', 'feed-forward enable delay after it is switched on',
                              ge=0.0, le=10.0, seed='notes §3.5 EnableFeedForward')
    suppress_level: int = param(3, '1', 'vibration suppression level while machining '
                                '(0 = off)', ge=0, le=5, seed='notes §5.3 item 5')
    v_max_mm_s: float = param(150.0, 'mm/s', 'output saturation', ge=0.1, le=1000.0)
    a_max_mm_s2: float = param(4000.0, 'mm/s²', 'acceleration limit of the output',
                               ge=10.0, le=1e6)
    followed_tol_mm: float = param(0.05, 'mm', '|gap − target| counted as in position',
                                   gt=0.0, le=5.0, seed='notes §3.5 HasFollowed')
    followed_hold_s: float = param(0.05, 's', 'in position this long → followed',
                                   ge=0.0, le=10.0, seed='notes §3.5 HasFollowed')


def _lowpass_coeff(tau_s: float, h_s: float) -> float:
    # backward-Euler first-order low-pass: y += c·(x − y), stable for every tau ≥ 0
    return h_s / (tau_s + h_s)


class FollowPID:
    """The PID follow baseline (firmware ``FollowPID``) on floats or numpy arrays.

    Interface as in ``Follow_OnStep``: :meth:`set_target`, :meth:`set_pre_out`,
    :meth:`enable_feed_forward`, :meth:`set_suppress`, :meth:`step`,
    :meth:`has_followed`. Terms of the last step are readable as attributes
    (``p_term``, ``d_term``, ``i_term``, ``ff_term``, ``u_unlimited``, ``u``,
    ``saturated``, ``rate_limited``).
    """

    def __init__(self, params: PIDParams | None = None, h_s: float = 0.0005,
                 ops=SCALAR) -> None:
        self.params = params or PIDParams()
        problems = self.params.problems()
        if not h_s > 0.0:
            problems.append(f'h_s must be > 0, got {h_s!r}')
        if problems:
            raise ValueError('invalid PID parameters: ' + '; '.join(problems))
        self.h_s = float(h_s)
        self.ops = ops
        p = self.params
        self._cd = _lowpass_coeff(p.d_filter_s, self.h_s)
        self._cf = _lowpass_coeff(p.ff_filter_s, self.h_s)
        self._du_max = p.a_max_mm_s2 * self.h_s
        self._hold_ticks = int(round(p.followed_hold_s / self.h_s))
        self._ff_delay_ticks = int(round(p.ff_delay_s / self.h_s))
        self._suppress = False
        self.reset(0.0, 0.0)

    def reset(self, gap_mm, target_mm, u_prev_mm_s=0.0, encoder_mm=None) -> None:
        """Start from a reading: no derivative history, integrator and feed-forward off."""
        self.target_mm = target_mm
        self._gap_prev = gap_mm
        self._target_prev = target_mm
        self._surface_prev = None if encoder_mm is None else encoder_mm - gap_mm
        self.gap_rate_mm_s = 0.0 * gap_mm
        self.ref_rate_mm_s = 0.0 * gap_mm
        self.surface_rate_mm_s = 0.0 * gap_mm
        self.i_term = 0.0 * gap_mm
        self.u = u_prev_mm_s + 0.0 * gap_mm
        self.p_term = self.d_term = self.ff_term = 0.0 * gap_mm
        self.u_unlimited = self.u
        self.saturated = self.rate_limited = False
        self._in_pos_ticks = 0 * gap_mm
        self._ff_enabled = False
        self._ff_count = 0

    def set_pre_out(self, u_mm_s) -> None:
        """Set the previous output (seed ``FollowPID_SetPreOutUnitV``): bumpless hand-over.

        The next step's acceleration limit starts from ``u_mm_s``, e.g. the
        interpolator's velocity when PREINTERPOLATE hands over; the integrator
        restarts from zero.
        """
        self.u = u_mm_s
        self.i_term = 0.0 * self.i_term

    def enable_feed_forward(self, on: bool) -> None:
        """Switch the feed-forward; it acts ``ff_delay_s`` after being switched on."""
        if on and not self._ff_enabled:
            self._ff_count = 0
        self._ff_enabled = bool(on)

    def is_feed_forward_enabled(self) -> bool:
        """Return True once enabled (seed ``FollowPID_IsEnableFeedForward``)."""
        return self._ff_enabled

    def set_suppress(self, on: bool) -> None:
        """Switch vibration suppression at ``params.suppress_level`` (seed SetSuppressMode)."""
        self._suppress = bool(on)

    def has_followed(self):
        """Return True once |gap − target| ≤ tol held for ``followed_hold_s`` (HasFollowed)."""
        return self._in_pos_ticks >= self._hold_ticks

    def step(self, gap_mm, encoder_mm=None, target_mm=None):
        """One tick: return the velocity command (mm/s, + = up)."""
        ops = self.ops
        p = self.params
        h = self.h_s
        if target_mm is not None:
            self.target_mm = target_mm
        target = self.target_mm
        level = p.suppress_level if self._suppress else 0
        g = SUPPRESS_GAIN_SCALE[level]
        db = SUPPRESS_DEADBAND_MM[level]

        e = target - gap_mm
        e_db = e - ops.clip(e, -db, db)
        # derivative on the measurement, filtered (no kick on target steps)
        gap_rate = self.gap_rate_mm_s + self._cd * ((gap_mm - self._gap_prev) / h
                                                    - self.gap_rate_mm_s)
        ref_rate = self.ref_rate_mm_s + self._cf * ((target - self._target_prev) / h
                                                    - self.ref_rate_mm_s)
        if encoder_mm is not None:
            surface = encoder_mm - gap_mm
            if self._surface_prev is None:
                self._surface_prev = surface
            surface_rate = self.surface_rate_mm_s + self._cf * (
                (surface - self._surface_prev) / h - self.surface_rate_mm_s)
            self._surface_prev = surface
        else:
            surface_rate = self.surface_rate_mm_s
        self._gap_prev = gap_mm
        self._target_prev = target
        self.gap_rate_mm_s = gap_rate
        self.ref_rate_mm_s = ref_rate
        self.surface_rate_mm_s = surface_rate

        if self._ff_enabled and self._ff_count < self._ff_delay_ticks:
            self._ff_count += 1
        ff_on = self._ff_enabled and self._ff_count >= self._ff_delay_ticks
        ff = (p.ff_ref_gain * ref_rate + p.ff_surface_gain * surface_rate) if ff_on \
            else 0.0 * e
        p_term = g * p.kp_1_s * e_db
        d_term = -g * p.kd * gap_rate
        i_prev = self.i_term
        u_unlim = p_term + d_term + i_prev + ff
        u, sat, rate = apply_limits(ops, u_unlim, self.u, p.v_max_mm_s, self._du_max)
        if p.ki_1_s2 > 0.0:
            # conditional integration: hold while the applied output is limited
            # in the direction the error pushes (anti-windup)
            limited_up = (u < u_unlim) & (e_db > 0.0)
            limited_down = (u > u_unlim) & (e_db < 0.0)
            self.i_term = ops.where(limited_up | limited_down, i_prev,
                                    i_prev + p.ki_1_s2 * h * e_db)
        self.p_term, self.d_term, self.ff_term = p_term, d_term, ff
        self.u_unlimited, self.u = u_unlim, u
        self.saturated, self.rate_limited = sat, rate
        in_pos = ops.abs(e) <= p.followed_tol_mm
        count = ops.minimum(self._in_pos_ticks + 1, self._hold_ticks)
        self._in_pos_ticks = ops.where(in_pos, count, 0)
        return u
