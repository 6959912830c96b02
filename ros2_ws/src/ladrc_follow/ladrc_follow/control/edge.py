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
  of the apparent surface. A gain above ``gain_max`` is an edge: FAULT, nothing moves toward
  the sheet.
* **A fast fall is not followed down.** The apparent surface ``encoder − gap`` (low-passed
  over ``fall_tau_s``) falling faster than ``fall_mm_s``, faster than a flat sheet falls, is
  held (no command toward the sheet) while it lasts. Closing in afterwards is capped at
  ``probe_mm_s`` until :class:`TravelGain` has seen ``gain_travel_mm`` of travel and found a
  sheet (gain ≤ ``gain_max``); a gain above it faults as above.
* **A far drop** of the apparent surface below its slow reference (``drop_mm``, the seed's
  ``CheckForOutPanelEdge`` in ``Follow_OnStep``) faults as before.

What it cannot see: a nozzle that slides off the sheet slowly while the sheet may also be
falling slowly; docs/safety.md gives the figures. Plain Python scalars, one tick at a time.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

from .schema import Section, param

_EDGE = 'notes §5.3 item 3 (边缘, 反馈系数)'

OK, FALLING, EDGE, VERIFY, UNVERIFIED = 0, 1, 2, 3, 4
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
    verify_drop_mm: float = param(0.0, 'mm', 'while following, an apparent surface this far '
                                  'below its last verified level is verified again by a short '
                                  'move up (gain_travel_mm at probe_mm_s, the safe direction) '
                                  'before it is followed further down; 0 = off', ge=0.0,
                                  le=50.0, seed=_EDGE)
    verify_mm_s: float = param(5.0, 'mm/s', 'a verification starts only while the apparent '
                               'surface moves slower than this (a sheet in faster motion would '
                               'bias the move up)', gt=0.0, le=1000.0)
    probe_s: float = param(0.1, 's', 'the probe after a fast fall ends after this time without '
                           'closing in (nothing left to close)', gt=0.0, le=10.0)


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


class EdgeGuard:
    """The edge checks of one follow: ``update(enc, gap, approaching)`` returns a verdict.

    OK: go on; FALLING: hold (no command toward the sheet); VERIFY: move up at ``probe_mm_s``
    (the law is not stepped); EDGE: the gain says edge; UNVERIFIED: the move up could not be
    judged within ``probe_s``. ``down_cap_mm_s`` is the speed limit toward the sheet it asks
    for (inf when none).
    """

    def __init__(self, p: EdgeParams, h_s: float) -> None:
        self.params = p
        self._h = h_s
        self._c = h_s / (p.fall_tau_s + h_s)  # backward-Euler low-pass, as pid.py
        self._probe_max = max(1, int(round(p.probe_s / h_s)))
        self.travel = TravelGain(p.gain_travel_mm, p.judge_mm_s, h_s)
        self.reset()

    def reset(self) -> None:
        """Forget the history and any pending probe (a new approach)."""
        self._z = self._r = math.nan
        self.surface_mm_s = 0.0
        self.probing = False
        self.verifying = False
        self.verified_mm = math.nan  # apparent surface last found over a sheet
        self._trend_mm_s = 0.0
        self._probe_ticks = 0
        self.travel.reset()

    @property
    def down_cap_mm_s(self) -> float:
        """Speed limit toward the sheet: ``probe_mm_s`` until a fall is confirmed as a sheet."""
        return self.params.probe_mm_s if self.probing else math.inf

    def update(self, enc_mm: float, gap_mm: float, approaching: bool) -> int:
        """Judge one tick with a usable reading (see the module docstring)."""
        dz, dr = enc_mm - self._z, gap_mm - self._r
        self._z, self._r = enc_mm, gap_mm
        p = self.params
        if not (dz == dz and p.enabled):
            return OK  # first tick, or the guard is off
        # the apparent surface (encoder − gap) moves by dz − dr
        v = self.surface_mm_s = self.surface_mm_s + self._c * ((dz - dr) / self._h
                                                               - self.surface_mm_s)
        if v < -p.fall_mm_s:
            self.probing = True
            self._probe_ticks = 0
            self.travel.reset()
            return FALLING
        s = enc_mm - gap_mm
        if self.verifying:
            # the move up: judged on upward travel, where nothing can be hit; the surface's
            # own trend before the move is taken out of the reading (a slowly falling sheet
            # and a slowly sliding edge alike)
            self._probe_ticks += 1
            k = self.travel.update(enc_mm, gap_mm + self._trend_mm_s * self._probe_ticks * self._h)
            if k == k and dz > 0.0:
                if k > p.gain_max:
                    return EDGE
                self.verifying = False
                self.verified_mm = s
                return OK
            return UNVERIFIED if self._probe_ticks >= self._probe_max else VERIFY
        if approaching:
            k = self.travel.update(enc_mm, gap_mm)
            if k > p.gain_max:
                return EDGE
            if k == k:
                self.verified_mm = s
        elif self.probing:
            # after a fall, the closing in (downward travel) is what is judged
            k = self.travel.update(enc_mm, gap_mm)
            self._probe_ticks += 1
            if k == k and dz < 0.0:
                if k > p.gain_max:
                    return EDGE
                self.probing = False  # a sheet under the nozzle: full speed again
                self.verified_mm = s
            elif self._probe_ticks >= self._probe_max:
                self.probing = False  # nothing left to close in
        else:
            ver = self.verified_mm
            if not ver == ver or s > ver:
                self.verified_mm = s  # a rising surface (or the first followed tick) is safe
            elif (p.verify_drop_mm > 0.0 and ver - s > p.verify_drop_mm
                  and -p.verify_mm_s < v < p.verify_mm_s):
                self.verifying = True
                self._trend_mm_s = v
                self._probe_ticks = 0
                self.travel.reset()
                self.travel.update(enc_mm, gap_mm)
                return VERIFY
        return OK
