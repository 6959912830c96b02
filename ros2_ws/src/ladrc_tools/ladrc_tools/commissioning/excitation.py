"""Excitation of the Z axis for identification: a bounded PRBS and a log chirp.

An :class:`Excitation` is a whole velocity-command profile, one value per controller tick
(``h_s``, 0.5 ms), meant to be played around a safe height (far above the sheet) by a driver
test, the conformance kit or the headless sim (:mod:`.player`). Each profile

* starts and ends with a zero command (first and last sample are exactly 0);
* never commands more than ``amplitude_mm_s``;
* integrates (ZOH: position ``p[k+1] = p[k] + h u[k]``, i.e. an axis with b0 = 1) to a path
  that never leaves ``±max_travel_mm`` around the start and returns to it at the end.

The real axis lags that integral: with ``b0/(s(T1 s + 1))`` its position is ``b0`` times the
integral minus ``b0 T1 v(t)``, so it stays within ``b0 (max_travel_mm + T1 amplitude_mm_s)``
(for T1 = 15 ms and 20 mm/s: 0.3 mm more), and a dead time only shifts it.

Kinds:

``prbs``
    Random binary velocity ``±amplitude``: a switching clock of ``1/(2 f_high)`` (whole ticks,
    at least one), at each clock edge the sign flips with probability 1/2 (seeded
    ``numpy.random.Generator``), a run longer than ``1/(2 f_low)`` is broken by a forced flip,
    and the sign flips at once whenever the next tick would leave the travel bound. Its
    spectrum is flat to about ``0.9 f_high`` (sinc² of the clock) and down to about ``f_low``.
    The last part of the run is a return segment at up to ``amplitude`` that lands exactly on
    the start position, then zeros.
``chirp``
    A logarithmic sweep ``f_low -> f_high`` of the position,
    ``p(t) = X(f(t)) w(t) sin(phi(t))`` with ``X(f) = min(max_travel, amplitude/(2 pi f))``
    (the position amplitude is capped by the travel at low frequencies and by the velocity
    amplitude at high ones), a raised-cosine fade ``w`` in and out so it starts and ends at
    rest; the command is the position's per-tick difference over ``h`` (so its ZOH integral
    is exactly ``p``), scaled down as a whole if a sample exceeds the amplitude.

The acceleration a flip asks of the axis is ``2 amplitude / T1`` (5 mm/s on T1 = 4 ms:
2 500 mm/s², half the simulator's limit); keep the amplitude low enough that the drive's
acceleration limit never clips, or the data stop being linear.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
import math
from typing import Any

import numpy as np

H_S = 0.0005
"""Controller tick (2 kHz, seed SAMPLE_PERIOD 2000)."""

KINDS = ('prbs', 'chirp')
MAX_AMPLITUDE_MM_S = 20.0
"""Highest command: a tenth of the sim's v_max; an identification runs near a sheet."""
MAX_TRAVEL_MM = 2.0
"""Largest excursion: a nozzle parked a few mm above the sheet stays off it."""
MIN_DURATION_S = 0.5
MAX_DURATION_S = 60.0


def _number(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, (bool, np.bool_))


@dataclass(frozen=True)
class Excitation:
    """A bounded velocity excitation (see the module docstring for the kinds)."""

    kind: str = 'prbs'
    amplitude_mm_s: float = 4.7
    max_travel_mm: float = 0.5
    f_low_hz: float = 1.0
    f_high_hz: float = 100.0
    duration_s: float = 4.0
    seed: int = 0

    def as_dict(self) -> dict[str, Any]:
        """Return the fields as a JSON-friendly dict."""
        return asdict(self)

    # ---- bounds ------------------------------------------------------------------------
    def problems(self, h_s: float = H_S) -> list[str]:
        """Return every reason this excitation cannot be played at tick ``h_s`` (empty: ok)."""
        out: list[str] = []
        if self.kind not in KINDS:
            out.append(f'kind {self.kind!r} is not one of {", ".join(KINDS)}')
        names = ('amplitude_mm_s', 'max_travel_mm', 'f_low_hz', 'f_high_hz', 'duration_s')
        bad = [k for k in names if not (_number(getattr(self, k))
                                        and math.isfinite(getattr(self, k)))]
        for k in bad:
            out.append(f'{k} = {getattr(self, k)!r}: a finite number is required')
        if not (isinstance(self.seed, (int, np.integer)) and not isinstance(self.seed, bool)
                and self.seed >= 0):
            out.append(f'seed = {self.seed!r}: a non-negative integer is required')
        if not (_number(h_s) and math.isfinite(h_s) and 0.0 < h_s <= 0.01):
            out.append(f'h_s = {h_s!r}: the tick must be in (0, 0.01] s')
            return out
        if bad:
            return out
        a, tr = self.amplitude_mm_s, self.max_travel_mm
        if not 0.0 < a <= MAX_AMPLITUDE_MM_S:
            out.append(f'amplitude_mm_s = {a:g} must be in (0, {MAX_AMPLITUDE_MM_S:g}] mm/s '
                       '(an identification runs a few mm above the sheet)')
        if not 0.0 < tr <= MAX_TRAVEL_MM:
            out.append(f'max_travel_mm = {tr:g} must be in (0, {MAX_TRAVEL_MM:g}] mm (the '
                       'excursion around the parking height)')
        if not MIN_DURATION_S <= self.duration_s <= MAX_DURATION_S:
            out.append(f'duration_s = {self.duration_s:g} must be in [{MIN_DURATION_S:g}, '
                       f'{MAX_DURATION_S:g}] s')
        nyquist = 0.5 / h_s
        if not 0.0 < self.f_low_hz < self.f_high_hz:
            out.append(f'f_low_hz = {self.f_low_hz:g} and f_high_hz = {self.f_high_hz:g}: '
                       'need 0 < f_low < f_high')
        if self.f_high_hz > nyquist:
            out.append(f'f_high_hz = {self.f_high_hz:g} is above the Nyquist frequency '
                       f'{nyquist:g} Hz of the {h_s * 1e3:g} ms tick')
        if self.f_low_hz > 0.0 and self.f_low_hz * self.duration_s < 1.0:
            out.append(f'f_low_hz = {self.f_low_hz:g}: the run of {self.duration_s:g} s must '
                       f'hold one period of it (f_low >= {1.0 / self.duration_s:.3g} Hz)')
        if out:
            return out
        if tr < 2.0 * a * h_s:
            out.append(f'max_travel_mm = {tr:g} is below two ticks of travel at '
                       f'{a:g} mm/s ({2.0 * a * h_s:g} mm)')
        if tr / a > 0.25 * self.duration_s:
            out.append(f'returning from max_travel_mm = {tr:g} at {a:g} mm/s takes '
                       f'{tr / a:g} s, more than a quarter of duration_s = '
                       f'{self.duration_s:g} s')
        return out

    def _checked(self, h_s: float) -> int:
        reasons = self.problems(h_s)
        if reasons:
            raise ValueError('excitation: ' + '; '.join(reasons))
        return int(round(self.duration_s / h_s))

    # ---- the profile -----------------------------------------------------------------
    def velocity_mm_s(self, h_s: float = H_S) -> np.ndarray:
        """Return the command of every tick (mm/s); raise ValueError if :meth:`problems`."""
        n = self._checked(h_s)
        if self.kind == 'prbs':
            return self._prbs(n, h_s)
        return self._chirp(n, h_s)

    def position_mm(self, h_s: float = H_S) -> np.ndarray:
        """Return the ZOH integral (b0 = 1) at every tick boundary: ``n + 1`` values from 0."""
        u = self.velocity_mm_s(h_s)
        return np.concatenate(([0.0], np.cumsum(u) * h_s))

    def clock_ticks(self, h_s: float = H_S) -> int:
        """Return the PRBS switching clock in whole ticks: ``1/(2 f_high)``, at least one."""
        return max(1, int(round(1.0 / (2.0 * self.f_high_hz * h_s))))

    def _prbs(self, n: int, h_s: float) -> np.ndarray:
        a, bound = float(self.amplitude_mm_s), float(self.max_travel_mm)
        step = a * h_s
        clock = self.clock_ticks(h_s)
        max_run = max(clock, int(round(1.0 / (2.0 * self.f_low_hz * h_s))))
        n_return = int(math.ceil(bound / step)) + 2
        n_main = n - 1 - n_return  # ticks 1 .. n_main - 1 play the PRBS
        rng = np.random.default_rng(int(self.seed))
        flips = rng.random(n // clock + 2) < 0.5
        u = np.zeros(n)
        p = 0.0
        s = 1.0 if rng.random() < 0.5 else -1.0
        run = 0
        for k in range(1, n_main):
            if (k - 1) % clock == 0 and k > 1:
                if run >= max_run or flips[(k - 1) // clock]:
                    s, run = -s, 0
            if abs(p + s * step) > bound:  # the travel bound: turn back now
                s, run = -s, 0
            u[k] = s * a
            p += u[k] * h_s
            run += 1
        # the return segment: at up to the amplitude, landing exactly on the start
        k = max(n_main, 1)
        while p != 0.0 and k < n - 1:
            v = min(a, max(-a, -p / h_s))
            u[k] = v
            p = 0.0 if abs(v) < a else p + v * h_s
            k += 1
        return u

    def _chirp(self, n: int, h_s: float) -> np.ndarray:
        a, bound = float(self.amplitude_mm_s), float(self.max_travel_mm)
        f0, f1 = float(self.f_low_hz), float(self.f_high_hz)
        # positions at the tick boundaries 0..n; P[0] = P[1] = P[n-1] = P[n] = 0
        k = np.arange(n + 1)
        span = (n - 2) * h_s
        tau = np.clip((k - 1) * h_s, 0.0, span)
        r = f1 / f0
        f = f0 * r ** (tau / span)
        phi = 2.0 * math.pi * f0 * span / math.log(r) * (r ** (tau / span) - 1.0)
        amp = np.minimum(bound, a / (2.0 * math.pi * f))
        fade = min(0.1 * span, 1.0 / f0)
        w = np.ones(n + 1)
        rise = tau < fade
        w[rise] = 0.5 - 0.5 * np.cos(math.pi * tau[rise] / fade)
        fall = tau > span - fade
        w[fall] = 0.5 - 0.5 * np.cos(math.pi * (span - tau[fall]) / fade)
        p = amp * w * np.sin(phi)
        p[:2] = 0.0
        p[-2:] = 0.0
        u = np.diff(p) / h_s
        peak = float(np.max(np.abs(u)))
        if peak > a:
            u *= a / peak
        u[0] = 0.0
        u[-1] = 0.0
        return u
