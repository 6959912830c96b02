"""Sheet edge (边缘): the nozzle leaving the sheet, seen before it closes in.

A nozzle partly off the sheet reads a wider gap than it has (notes §5.3 item 3: half off the
sheet, a 4 mm height step moved the encoder only 3 mm; the notes call the ratio of the two
travels the feedback gain, 反馈系数, 1 over a whole sheet). A controller that holds the reading
at the target then dives toward the part of the sheet still under it. At the instant it
happens, a reading that widens because the nozzle leaves the sheet looks exactly like a sheet
that falls away; the two differ only once the axis moves: over a whole sheet the reading
shrinks by the axis travel, at an edge by more (gain > 1). So:

* **Closing in is measured.** :class:`TravelGain` is the feedback gain of the last fast
  stretch of axis travel (reading travel / encoder travel, at least ``gain_travel_mm`` at
  ``judge_mm_s`` or faster, so that the sheet's own motion adds little). It runs through
  every approach until followed (the approach is the excitation) and after every fast fall
  of the apparent surface. A gain above ``gain_max`` is an edge: held (below).
* **A fast fall is not followed down.** The apparent surface ``encoder − gap`` (low-passed
  over ``fall_tau_s``) falling faster than ``fall_mm_s``, faster than a flat sheet falls, is
  held (no command toward the sheet) by the void lock (void_lock.py: locked after
  ``void_lock_ticks`` ticks beyond, unlocked after ``void_unlock_ticks`` within; the same lock
  holds a one-sample jump for the input gate). Closing in afterwards is capped at
  ``probe_mm_s`` until :class:`TravelGain` has seen ``gain_travel_mm`` of travel and found a
  sheet (gain ≤ ``gain_max``); a gain above it faults as above.
* **A far drop** of the apparent surface below its slow reference (``drop_mm``, the seed's
  ``CheckForOutPanelEdge`` in ``Follow_OnStep``, which faults there) is held as an edge.
* **A slow sink is verified.** While following, the axis barely moves against the sheet, so
  the gain has no excitation: an apparent surface that sinks ``verify_sink`` × target below
  the lowest level verified within ``verify_memory_s`` is verified before it is followed
  further: a short move up (the safe direction) with the law's output overridden, and
  :func:`fitted_gain` fits the reading against the encoder with the sheet's own motion as a
  cubic in time. A sink too fast to fit holds; a fit that cannot tell holds and is retried;
  ``verify_confirm`` gains significantly above ``verify_gain_max`` in a row are an edge.
  A follow that starts less than ``verify_start_mm`` above its target, and a level reached
  without any judged gain, are verified the same way before they are followed.
* **An edge is held, not latched** (a FAULT that needs a reset is for collisions and the
  hardware): nothing moves toward the sheet, the law runs on under the hold (its observer fed
  the applied command), and the hold ends by itself once the nozzle is over the sheet again:
  the apparent surface back within half the sink budget of the level last verified over the
  sheet (a reading that narrows back as the nozzle returns; not while closing in, where the
  narrowing is the edge's own signature), or a verification, repeated after ``hold_retry_s``
  with the wait doubling each time (each lifts the nozzle a little), that finds the gain of
  a sheet. Closing in after it is probed as after a fast fall.

What it cannot see: a slide that the sheet's own rise hides (the apparent surface does not
sink), and a sensor too noisy to fit (it holds instead); docs/safety.md gives the figures.
Plain Python scalars, one tick at a time (numpy for the fit at the end of a verification).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math
from math import isnan

from ladrc_contract.schema import Section, param
import numpy as np

from .void_lock import VoidLock

_EDGE = 'notes §5.3 item 3 (边缘, 反馈系数)'

OK, FALLING, EDGE, VERIFY, HOLD = 0, 1, 2, 3, 4
"""Verdicts of :meth:`EdgeGuard.update`."""


@dataclass(frozen=True)
class EdgeParams(Section):
    """Edge detection (``ControllerParams.edge``)."""

    PREFIX = 'edge.'

    enabled: bool = param(True, '', 'the feedback-gain and fast-fall checks (false: as the seed '
                          'firmware, which has neither; drop_mm is separate)', seed=_EDGE)
    drop_mm: float = param(2.0, 'mm', 'apparent surface drop (encoder − gap below its '
                           'reference) that means out of panel edge; 0 = off', ge=0.0, le=50.0,
                           seed='notes Follow_OnStep CheckForOutPanelEdge')
    ref_tau_s: float = param(0.2, 's', 'time constant of the apparent-surface reference',
                             gt=0.0, le=10.0)
    fall_mm_s: float = param(30.0, 'mm/s', 'an apparent surface falling faster than this is '
                             'not followed down (held) until its fall ends', gt=0.0,
                             le=10000.0, seed=_EDGE)
    fall_tau_s: float = param(0.004, 's', 'time constant of the apparent-surface speed',
                              gt=0.0, le=1.0)
    void_lock_ticks: int = param(1, 'ticks', 'void lock: ticks in a row with the apparent '
                                 'surface falling faster than fall_mm_s before it locks '
                                 '(plasmac voidlock_on_cycles; the fall_tau_s low-pass already '
                                 'smooths the reading)', ge=1, le=100,
                                 seed='plasmac voidlock_on_cycles')
    void_unlock_ticks: int = param(1, 'ticks', 'void lock: ticks in a row at or below '
                                   'fall_mm_s before it unlocks (plasmac voidlock_off_cycles); '
                                   'closing in after it is probed (probe_mm_s)', ge=1, le=1000,
                                   seed='plasmac voidlock_off_cycles')
    gain_max: float = param(1.35, '1', 'feedback gain (reading travel per axis travel, 1 over '
                            'a whole sheet) above which the nozzle is leaving the sheet',
                            gt=1.0, le=5.0, seed=_EDGE)
    gain_travel_mm: float = param(0.1, 'mm', 'axis travel over which the feedback gain is '
                                  'measured (approach; closing in after a fast fall)',
                                  ge=0.01, le=1.0)
    judge_mm_s: float = param(12.0, 'mm/s', 'the gain is judged only over travel at least this '
                              'fast (gain_travel_mm within gain_travel_mm / judge_mm_s): a sheet '
                              'moving during a slow move would bias it', ge=1.0, le=1000.0)
    probe_mm_s: float = param(20.0, 'mm/s', 'speed cap toward the sheet after a fast fall, '
                              'until the feedback gain has found a sheet', gt=0.0, le=1000.0)
    verify_sink: float = param(0.25, '1', 'while following, an apparent surface that sinks '
                               'this fraction of the target gap below the level last verified '
                               'over the sheet is verified again by a short move up before it is '
                               'followed further down; 0 = off', ge=0.0, le=1.0, seed=_EDGE)
    verify_start_mm: float = param(2.0, 'mm', 'a follow that starts with the reading less than '
                                   'this above the target (an approach too short to judge the '
                                   'gain) verifies the gain first; 0 = never', ge=0.0, le=50.0,
                                   seed=_EDGE)
    verify_mm_s: float = param(20.0, 'mm/s', 'speed of the verification move up', gt=0.0,
                               le=100.0)
    verify_move_s: float = param(0.005, 's', 'duration of the verification move up (it lifts '
                                 'the nozzle about verify_mm_s x verify_move_s)', gt=0.0,
                                 le=0.1)
    verify_pre_s: float = param(0.02, 's', 'the verification holds (command 0, the law not '
                                'stepped) this long before the move: the fit starts on an axis '
                                'that moves by the command alone', ge=0.0, le=0.2)
    verify_settle_s: float = param(0.03, 's', 'held after the move, still fitted: the reading is '
                                   "fitted against the encoder with the sheet's own motion as "
                                   'a quadratic in time over the whole window', ge=0.005,
                                   le=0.2)
    verify_speed_mm_s: float = param(5.0, 'mm/s', 'a verification starts only while the '
                                     'apparent surface moves slower than this (low-passed over '
                                     'verify_settle_s): faster sheet motion is no cubic over '
                                     'the window', gt=0.0, le=1000.0)
    verify_memory_s: float = param(1.0, 's', 'a level verified over the sheet stays verified '
                                   'this long after the surface was last within verify_sink of '
                                   'it: a sheet that oscillates within verified levels is not '
                                   'verified again each time it falls', ge=0.0, le=10.0,
                                   seed=_EDGE)
    verify_gain_max: float = param(1.2, '1', 'a verification that measures a feedback gain '
                                   'above this (or none) holds, and verify_confirm of them in a '
                                   'row are an edge', gt=1.0, le=5.0, seed=_EDGE)
    verify_fit_noise: float = param(2.0, '1', 'a verification whose fit leaves residuals of '
                                    "more than this many times the reading's own noise (the "
                                    'sheet moved other than a cubic, the sensor gain changed) '
                                    'cannot tell an edge: it holds instead', gt=1.0, le=100.0)
    noise_tau_s: float = param(0.1, 's', "time constant of the reading's noise estimate (its "
                               'second differences, low-passed)', gt=0.0, le=10.0)
    noise_floor_mm: float = param(0.002, 'mm', 'the reading noise the residual check assumes at '
                                  'least (a quieter or noise-free reading, e.g. quantized to '
                                  'its resolution, still leaves the fit that much)', gt=0.0,
                                  le=1.0)
    verify_retry_s: float = param(0.1, 's', 'a verification that could not tell is repeated '
                                  'this long after it while the surface stays sunk (a passing '
                                  'disturbance, a tube ridge, is then over)', gt=0.0, le=10.0)
    verify_retries: int = param(2, '1', 'repetitions in a row of a verification that could '
                                'not tell (each lifts the nozzle again); after them only a '
                                'further verify_sink sink verifies again', ge=0, le=10)
    verify_confirm: int = param(2, '1', 'verifications in a row above verify_gain_max that '
                                'make an edge (held until over the sheet again); the first '
                                'ones hold and verify again', ge=1, le=10)
    probe_s: float = param(0.1, 's', 'the probe after a fast fall ends after this time without '
                           'closing in (nothing left to close)', gt=0.0, le=10.0)
    hold_retry_s: float = param(0.25, 's', 'while held at an edge, the feedback gain is verified '
                                'again after this time, the wait doubling after each (each '
                                'verification lifts the nozzle about verify_mm_s x '
                                'verify_move_s: 7 of them in a minute); the hold also ends when '
                                'the reading comes back to the level last verified over the '
                                'sheet', gt=0.0, le=10.0, seed=_EDGE)


class TravelGain:
    """Feedback gain of the last fast axis travel (module docstring).

    Reading travel over encoder travel between now and ``window`` ticks ago, each end the mean
    of ``_AVG`` samples (the reading's noise enters only at the two ends): judged only when the
    axis travelled at least ``travel_mm`` in that window, i.e. moved at ``judge_mm_s`` or faster,
    so that a slowly moving sheet adds little (sheet speed / ``judge_mm_s`` at most).
    ``update(z, r)`` takes one tick's encoder position and reading (mm) and returns the gain,
    NaN when not judged.
    """

    def __init__(self, travel_mm: float, judge_mm_s: float, h_s: float) -> None:
        self._len = travel_mm
        self.window = max(2, int(math.ceil(travel_mm / (judge_mm_s * h_s))))
        self.reset()

    def reset(self) -> None:
        """Forget the travel so far."""
        n = self.window + 1
        self._z = [0.0] * n   # end means, a ring of window + 1
        self._r = [0.0] * n
        self._i = 0
        self._count = 0
        self._last: list[tuple[float, float]] = []
        self.gain = math.nan

    def update(self, z_mm: float, r_mm: float) -> float:
        """Take one tick's encoder position and reading; return the gain (NaN: not judged)."""
        last = self._last
        last.append((z_mm, r_mm))
        if len(last) > _AVG:
            del last[0]
        zm = sum(v[0] for v in last) / len(last)
        rm = sum(v[1] for v in last) / len(last)
        i = self._i
        n = self.window + 1
        j = i + 1 if i + 1 < n else 0  # the oldest entry: window ticks ago
        self._z[i], self._r[i] = zm, rm
        self._i = j
        self._count += 1
        self.gain = math.nan
        if self._count > n + _AVG:
            dz = zm - self._z[j]
            if abs(dz) >= self._len:
                self.gain = (rm - self._r[j]) / dz
        return self.gain


_AVG = 4
"""Samples averaged at each end of the travel (reading noise / 2)."""


def fitted_gain(t_s: list[float], z_mm: list[float],
                r_mm: list[float]) -> tuple[float, float, float]:
    """Fit the feedback gain ``k`` of ``r = k z + a + b t + c t² + d t³``: ``(k, se, rms)``.

    The cubic in time takes the sheet's own motion out (the sheet moves the reading, not the
    encoder); only the axis' own move, a step through the axis' lag, determines ``k``. A
    quadratic would leave a 6 Hz, 0.5 mm plate's motion biasing ``k`` by up to 0.6 over the
    window, the cubic by 0.1. The standard error is the residual's (noise and whatever of the
    sheet's motion is no cubic), ``rms`` the residual's RMS (mm). NaNs: too few samples or no
    move to judge.
    """
    n = len(t_s)
    if n < 8:
        return math.nan, math.nan, math.nan
    t = np.asarray(t_s) - t_s[0]
    t = t / max(float(t[-1]), 1e-9)
    z = np.asarray(z_mm) - z_mm[0]
    a = np.column_stack((z, np.ones(n), t, t * t, t * t * t))
    # one SVD gives the least-squares solution and (A^T A)^-1's first entry
    u, sv, vt = np.linalg.svd(a, full_matrices=False)
    if sv[-1] <= sv[0] * 1e-12:
        return math.nan, math.nan, math.nan  # no move to judge (rank < 5)
    coef = vt.T @ ((u.T @ (np.asarray(r_mm) - r_mm[0])) / sv)
    inv00 = float(np.sum((vt[:, 0] / sv) ** 2))
    res = a @ coef - (np.asarray(r_mm) - r_mm[0])
    ss = float(res @ res)
    var = ss / (n - 5)
    # residuals that are not white (band-limited gain noise, the sheet's motion) carry fewer
    # independent samples: the larger of the AR(1) factor (1 + rho) / (1 - rho) and a
    # Newey-West (Bartlett) sum over a tenth of the window (the fit's own detrending makes
    # longer sums fall back towards 1), so a doubtful fit errs towards "cannot tell"
    rho = min(max(float(res[1:] @ res[:-1]) / max(ss, 1e-30), 0.0), 0.95)
    lags = max(1, n // 10)
    nw = 1.0 + 2.0 * sum((1.0 - j / (lags + 1)) * float(res[j:] @ res[:-j])
                         for j in range(1, lags + 1)) / max(ss, 1e-30)
    factor = max((1.0 + rho) / (1.0 - rho), nw)
    se = math.sqrt(max(var * inv00 * max(factor, 1.0), 0.0))
    return float(coef[0]), se, math.sqrt(float(res @ res) / n)


_WARM: list[bool] = []


def warm_up() -> None:
    """Make the first :func:`fitted_gain` call here, not in the loop (once per process).

    LAPACK's first call starts its thread pool and workspaces, tens of times slower than a
    later call: done once at start-up, off the tick path.
    """
    if not _WARM:
        t = [i * 0.0005 for i in range(40)]
        fitted_gain(t, [math.sin(40.0 * x) for x in t], [math.cos(30.0 * x) for x in t])
        _WARM.append(True)


class EdgeGuard:
    """The edge checks of one follow: ``update(t, enc, gap, approaching, target)`` gives a verdict.

    OK: go on; FALLING: hold (no command toward the sheet, the law not stepped); HOLD: the law
    runs, only its upward commands pass; VERIFY: the law runs with its output overridden by
    ``verify_velocity_mm_s``; EDGE: held at an edge (``reason`` says how it was measured), as
    HOLD, until :meth:`update` returns OK or VERIFY again (``held``).
    ``down_cap_mm_s`` is the speed limit toward the sheet it asks for (inf when none).
    """

    def __init__(self, p: EdgeParams, h_s: float, void: VoidLock | None = None) -> None:
        self.params = p
        self._h = h_s
        if void is None:  # a guard alone (no input gate): a void lock of its own for the fall
            void = VoidLock({'jump': 0, 'void_lock': 0})
            void.configure(math.inf, 0.0, p.fall_mm_s, p.fall_tau_s, p.void_lock_ticks,
                           p.void_unlock_ticks, h_s)
        self.void = void  # the controller's void lock: judges the fall (its memory is its own)
        self._c_slow = h_s / (p.verify_settle_s + h_s)
        self._c_noise = h_s / (p.noise_tau_s + h_s)
        self._probe_max = max(1, int(round(p.probe_s / h_s)))
        self._n_pre = int(round(p.verify_pre_s / h_s))
        self._n_move = max(1, int(round(p.verify_move_s / h_s)))
        self._n_settle = max(1, int(round(p.verify_settle_s / h_s)))
        self.travel = TravelGain(p.gain_travel_mm, p.judge_mm_s, h_s)
        self._found: deque[tuple[float, float]] = deque()  # (t, level): window minimum
        self._t = 0.0
        self._r1 = self._r2 = math.nan  # the last two fresh readings
        self._d2_ms = math.nan  # low-passed square of their second difference
        self._d2_n = 0
        self._c_ref = h_s / (p.ref_tau_s + h_s)  # backward-Euler low-pass, as pid.py
        self.surface_ref_mm = 0.0  # the far drop's slow reference of the apparent surface
        warm_up()
        self._forget()

    def reset(self, start_above_mm: float = math.nan) -> None:
        """Forget the history and any pending probe (a new approach).

        ``start_above_mm``: the reading minus the target at the start of a follow; closing in
        by less than ``verify_start_mm`` (too short to judge the gain on the way) verifies the
        gain first. (A follow that starts at or below its target closes in on nothing; its
        level is verified once followed, as every level reached without a judged gain.)
        """
        self.void.clear_slope()
        self._forget(start_above_mm)

    def _restart_surface_speed(self) -> None:
        """Restart the apparent surface's speed: the void lock's slope and its slow low-pass."""
        self.void.clear_slope()
        self._slow_mm_s = 0.0

    def _forget(self, start_above_mm: float = math.nan) -> None:
        """:meth:`reset` but the void lock (a new guard for a parameter set keeps it)."""
        self._z = self._r = math.nan
        self._slow_mm_s = 0.0  # the apparent surface's speed low-passed over verify_settle_s
        self.probing = False
        self.verified_mm = math.nan  # apparent surface last found over a sheet
        self._probe_ticks = 0
        self.travel.reset()
        self._found.clear()
        self.verifying = False
        self._at_start = False  # the verification runs before the approach closes in
        self._ticks = 0
        self._t_last = math.nan
        self._fit: list[tuple[float, float, float]] = []
        self._z_start = self._r_start = math.nan
        self._strikes = 0
        self._doubt_mm = math.inf  # level of a verification that could not tell
        self._doubt_t = 0.0  # and its time
        self._doubt_n = 0  # such verifications in a row
        self.doubts = 0  # such verifications in this follow
        self.aborted = 0  # verifications given up for a sheet coming up
        self.gain = self.gain_se = self.fit_rms_mm = math.nan  # the last verification's fit
        self.reason = ''
        self.held = False  # at an edge: held until the nozzle is over the sheet again
        self._held_approach = False  # held before the follow closed in (only a fit ends it)
        self._held_t = 0.0  # the hold's start or its last verification
        self._held_n = 0  # verifications during this hold (each doubles the wait)
        self.holds = 0  # edge holds in this follow
        p = self.params
        if p.enabled and 0.0 < start_above_mm < p.verify_start_mm:
            self._start_verify(at_start=True)

    def carry_over(self, old: EdgeGuard) -> None:
        """Keep what ``old`` found during this follow (new parameters while following).

        The levels verified, the doubts and strikes stay; a verification in progress starts
        again under the new parameters (its window is theirs).
        """
        for name in ('_z', '_r', '_t', '_r1', '_r2', '_d2_ms', '_d2_n', '_slow_mm_s', 'probing',
                     'verified_mm', '_probe_ticks', '_strikes', '_doubt_mm', '_doubt_t',
                     '_doubt_n', 'doubts',
                     'aborted', '_at_start', 'gain', 'gain_se', 'fit_rms_mm', 'reason',
                     'surface_ref_mm', 'held', '_held_approach', '_held_t', '_held_n',
                     'holds'):
            setattr(self, name, getattr(old, name))
        self._found = deque(old._found)
        self.verifying = False
        if old.verifying:
            self._start_verify(at_start=old._at_start)

    def far_drop(self, enc_mm: float, gap_mm: float) -> str:
        """Return why the apparent surface fell too far ('' if not): seed ``CheckForOutPanelEdge``.

        The apparent surface ``encoder − gap`` more than ``drop_mm`` below its reference (a
        low-pass over ``ref_tau_s``, set where the PID takes over) is out of the panel; 0 turns
        the check off. The reference follows the surface on every tick that passes.
        """
        drop = self.params.drop_mm
        if drop > 0.0 and not self.held:  # the reference stays where it was during a hold
            sf = enc_mm - gap_mm
            ref = self.surface_ref_mm
            if sf < ref - drop:
                return self.hold_edge(
                    f'out of panel edge: apparent sheet surface fell {ref - sf:.2f} mm '
                    f'below its reference (limit {drop:g} mm); holding', approaching=False)
            self.surface_ref_mm = ref + self._c_ref * (sf - ref)
        return ''

    def hold_edge(self, reason: str, approaching: bool) -> str:
        """Hold at an edge from now on (module docstring); return ``reason``."""
        if not self.held:
            self.held = True
            self.holds += 1
            self._held_approach = approaching
            self._held_t = self._t
            self._held_n = 0
        self.reason = reason
        return reason

    @property
    def down_cap_mm_s(self) -> float:
        """Speed limit toward the sheet: ``probe_mm_s`` until a fall is confirmed as a sheet."""
        return self.params.probe_mm_s if self.probing else math.inf

    @property
    def verify_velocity_mm_s(self) -> float:
        """Command during a verification: 0, up for ``verify_move_s``, 0 (all of it fitted).

        The law is not followed for the whole window, so the axis' motion in it is the
        command's alone, not the loop's answer to the reading's noise (which would bias the
        fit: the regressor would correlate with the residual).
        """
        k = self._ticks - 1 - self._n_pre  # _ticks counts this tick already
        return self.params.verify_mm_s if 0 <= k < self._n_move else 0.0

    def _start_verify(self, at_start: bool = False) -> None:
        self.verifying = True
        self._at_start = at_start
        self._z_start = self._z  # where the move up starts (NaN before the first tick)
        self._r_start = self._r  # the reading there
        self._ticks = 0
        self._t_last = math.nan
        self._fit = []

    def update(self, t_s: float, enc_mm: float, gap_mm: float, approaching: bool,
               target_mm: float, fresh: bool = True) -> int:
        """Judge one tick with a usable reading at controller time ``t_s`` (module docstring).

        ``fresh``: the reading is a new sample (not the encoder prediction, which has gain 1
        by construction and is left out of the verification fit).
        """
        dz, dr = enc_mm - self._z, gap_mm - self._r
        self._z, self._r = enc_mm, gap_mm
        self._t = t_s
        p = self.params
        if not p.enabled:
            return OK
        if fresh:
            # the reading's noise: the second difference of white noise has 6 x its variance;
            # the axis' and the sheet's curvature add < 0.1 µm per tick at 2 kHz
            d2 = gap_mm - 2.0 * self._r1 + self._r2
            if not isnan(d2):
                # a running mean until noise_tau_s worth of samples, then a low-pass
                self._d2_n += 1
                c = max(1.0 / self._d2_n, self._c_noise)
                ms = self._d2_ms
                self._d2_ms = d2 * d2 if isnan(ms) else ms + c * (d2 * d2 - ms)
            self._r2, self._r1 = self._r1, gap_mm
        if isnan(dz):
            # first tick
            if self.held:
                return EDGE
            return self._verify_tick(enc_mm, gap_mm, fresh) if self.verifying else OK
        # the apparent surface (encoder − gap) moves by dz − dr
        ds = (dz - dr) / self._h
        falling = self.void.slope(ds)
        self._slow_mm_s += self._c_slow * (ds - self._slow_mm_s)
        if self.held:
            return self._held_tick(enc_mm, gap_mm, fresh, target_mm)
        if self.verifying:
            # no fall hold inside a verification: the move up itself makes the apparent surface
            # fall at an edge (by (k - 1) x the lift), and a real sheet step leaves the fit a
            # residual no cubic explains (it cannot tell: it holds)
            return self._verify_tick(enc_mm, gap_mm, fresh)
        if falling:
            self.probing = True
            self._probe_ticks = 0
            self.travel.reset()
            return FALLING
        s = enc_mm - gap_mm
        if approaching:
            if self._at_start and self._doubt_mm < math.inf:
                # the verification before the approach could not tell: not closing in yet
                return self._retry_or(HOLD, at_start=True)
            k = self.travel.update(enc_mm, gap_mm)
            if k > p.gain_max:
                return self._edge_travel(k, True)
            if not isnan(k):
                self._verified(s)
            return OK
        if self.probing:
            # after a fall, the closing in (downward travel) is what is judged
            k = self.travel.update(enc_mm, gap_mm)
            self._probe_ticks += 1
            if not isnan(k) and dz < 0.0:
                if k > p.gain_max:
                    return self._edge_travel(k, False)
                self.probing = False  # a sheet under the nozzle: full speed again
                self._verified(s)
            elif self._probe_ticks >= self._probe_max:
                self.probing = False  # nothing left to close in
            return OK
        ver = self.verified_mm
        if p.verify_sink <= 0.0:
            if isnan(ver) or s > ver:
                self.verified_mm = s  # no verification: the level is taken as it comes
            return OK
        if isnan(ver):
            # followed without a judged gain (an approach too slow to judge): verify first
            if self._doubt_mm == math.inf:
                self._start_verify()
                return self._verify_tick(enc_mm, gap_mm, False)
            return self._retry_or(HOLD, give_up=True)
        if s > ver:
            self.verified_mm = ver = s  # a rising surface is safe
        found = self._found
        sink = p.verify_sink * target_mm
        while found and found[0][0] < t_s - p.verify_memory_s:
            found.popleft()
        if found and found[0][1] < ver:
            ver = found[0][1]  # the lowest level verified within verify_memory_s
            if s - ver < sink:
                # a surface that keeps coming back to it (an oscillating sheet) keeps it
                # verified: it is forgotten only verify_memory_s after the last visit
                found[0] = (t_s, ver)
        if ver - s > sink:
            if abs(self._slow_mm_s) >= p.verify_speed_mm_s:
                return HOLD  # sunk too far to follow unverified, too fast to verify
            if s > self._doubt_mm - sink:
                return self._retry_or(HOLD)  # a verification here could not tell
            self._start_verify()
            return self._verify_tick(enc_mm, gap_mm, False)
        if ver - s < 0.5 * sink:  # back well within the budget (not the reading's noise)
            self._doubt_mm = math.inf
            self._doubt_n = 0
        return OK

    def _retry_or(self, verdict: int, at_start: bool = False, give_up: bool = False) -> int:
        """After a verification that could not tell: repeat it when due, else ``verdict``.

        Before closing in (``at_start``) and at a level nothing has verified (``give_up``),
        the retries used up are an EDGE: nothing else would ever let the follow go on.
        """
        p = self.params
        if self._doubt_n <= p.verify_retries and self._t - self._doubt_t >= p.verify_retry_s:
            self._start_verify(at_start)
            return self._verify_tick(self._z, self._r, False)
        if (at_start or give_up) and self._doubt_n > p.verify_retries:
            where = 'before closing in' if at_start else 'at the level the follow reached'
            self.hold_edge(f'edge: the feedback gain could not be verified {where} '
                           f'({self._doubt_n} verifications: {self._fit_text()}); holding',
                           approaching=at_start or isnan(self.verified_mm))
            return EDGE
        return verdict

    @property
    def noise_mm(self) -> float:
        """The reading's noise (RMS, mm) from its second differences, at least noise_floor_mm."""
        return max(math.sqrt(self._d2_ms / 6.0), self.params.noise_floor_mm)

    def _fit_text(self) -> str:
        p = self.params
        return (f'last gain {self.gain:.2f} ± {self.gain_se:.2f}, residual '
                f'{self.fit_rms_mm * 1e3:.1f} µm against a reading noise of '
                f'{self.noise_mm * 1e3:.1f} µm (limits {p.verify_gain_max:g}, '
                f'{p.verify_fit_noise:g}x)')

    def _verify_tick(self, enc_mm: float, gap_mm: float, fresh: bool) -> int:
        """One tick of a verification: hold, move up, hold, then fit the gain over the window.

        Over the sheet (``k`` + its standard error <= ``verify_gain_max``, from a fit that can
        tell, after a real move) the level is verified. A gain above the limit by more than
        twice its standard error is a strike, and ``verify_confirm`` strikes in a row are an
        edge (between them it verifies again at once). Anything else (a fit that cannot tell,
        a tick the guard did not see) holds: nothing further down; it is retried after
        ``verify_retry_s``.
        """
        t = self._t
        if fresh:
            self._fit.append((t, enc_mm, gap_mm))
        if isnan(self._z_start):
            self._z_start, self._r_start = enc_mm, gap_mm  # a verification's first tick
        skipped = not isnan(self._t_last) and t - self._t_last > 1.5 * self._h
        self._t_last = t
        self._ticks += 1
        p = self.params
        lift_mm = p.verify_mm_s * p.verify_move_s
        if not self._at_start and gap_mm < self._r_start - lift_mm:
            # the sheet comes up faster than the move lifts: give way, the law follows it. The
            # level is not verified by it (a nozzle coming back over a ragged edge narrows the
            # reading too); a sheet that keeps rising is a rising surface, which is safe
            self.verifying = False
            self.aborted += 1
            self._restart_surface_speed()
            return OK
        if self._ticks < self._n_pre + self._n_move + self._n_settle and not skipped:
            return VERIFY
        ts, z, r = zip(*self._fit, strict=True) if self._fit else ((), (), ())
        k, se, rms = fitted_gain(list(ts), list(z), list(r)) if not skipped else (
            math.nan, math.nan, math.nan)
        self.gain, self.gain_se, self.fit_rms_mm = k, se, rms
        self.verifying = False
        self._restart_surface_speed()  # after the move
        level = enc_mm - gap_mm
        lifted = bool(z) and max(z) - self._z_start >= 0.5 * lift_mm
        # a sheet: the gain one standard error above the fit still under the limit, from a fit
        # that can tell (the residual within verify_fit_noise x the reading's noise, the
        # nozzle really lifted)
        fits = rms <= p.verify_fit_noise * self.noise_mm
        can_tell = fits and lifted
        if k + se <= p.verify_gain_max and can_tell:  # (NaN fails this)
            self._strikes = self._doubt_n = 0
            self._doubt_mm = math.inf
            self._at_start = False
            self._verified(level)
            return OK
        if not (k - 2.0 * se > p.verify_gain_max and can_tell):
            self.doubts += 1
            self._doubt_n += 1
            self._doubt_mm, self._doubt_t = level, t
            return HOLD
        self._strikes += 1
        if self._strikes >= p.verify_confirm:
            lift_um = (max(z) - self._z_start) * 1e3
            self.hold_edge(f'edge: a move up of {lift_um:.0f} µm '
                           f'found the nozzle leaving the sheet (feedback gain {k:.2f} ± '
                           f'{se:.2f} in {self._strikes} verification(s) in a row, limit '
                           f'{p.verify_gain_max:g}); holding',
                           approaching=self._at_start or isnan(self.verified_mm))
            return EDGE
        self._start_verify(self._at_start)  # verify again: one measurement is not an edge yet
        return VERIFY

    def _verified(self, level_mm: float) -> None:
        """Take a level found over the sheet (gain judged) as the reference from now on."""
        if self.held:
            self._release(level_mm)
        self.verified_mm = level_mm
        found = self._found
        while found and found[-1][1] >= level_mm:
            found.pop()  # never the window's minimum again
        found.append((self._t, level_mm))

    def _edge_travel(self, k: float, approaching: bool) -> int:
        self.hold_edge(f'edge: the nozzle is leaving the sheet (feedback gain {k:.2f}: the '
                       f'reading moved {k:.2f} mm per mm of axis travel over the last '
                       f'{self.travel.window * self._h * 1e3:.3g} ms, limit '
                       f'{self.params.gain_max:g}); holding', approaching)
        return EDGE

    def _held_tick(self, enc_mm: float, gap_mm: float, fresh: bool, target_mm: float) -> int:
        """One tick held at an edge: EDGE (hold), VERIFY, or OK once over the sheet again."""
        p = self.params
        if self.verifying:
            v = self._verify_tick(enc_mm, gap_mm, fresh)  # a sheet found: _verified releases
            return v if v == VERIFY or not self.held else EDGE
        s = enc_mm - gap_mm
        ver = self.verified_mm
        if (not self._held_approach and not isnan(ver)
                and s >= ver - 0.5 * p.verify_sink * target_mm):
            # the reading narrowed back to a level verified over the sheet: over it again
            self._release(s)
            return OK
        due = p.hold_retry_s * 2.0 ** self._held_n
        if self._t - self._held_t >= due and abs(self._slow_mm_s) < p.verify_speed_mm_s:
            self._held_t = self._t
            self._held_n += 1
            self._strikes = p.verify_confirm - 1  # one move up per retry, not verify_confirm
            self._start_verify(at_start=self._held_approach)
            return self._verify_tick(enc_mm, gap_mm, False)
        return EDGE

    def _release(self, level_mm: float) -> None:
        """End an edge hold: closing in from here is probed as after a fast fall."""
        self.held = False
        self.reason = ''
        self._strikes = self._doubt_n = 0
        self._doubt_mm = math.inf
        self._at_start = False
        self._restart_surface_speed()
        self.surface_ref_mm = level_mm  # the far drop's reference restarts here
        self.probing = True
        self._probe_ticks = 0
        self.travel.reset()
