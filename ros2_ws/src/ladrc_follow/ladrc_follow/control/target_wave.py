"""A test signal added to the follow target once followed (the seed's ``SIN_GEN``).

The firmware's sine test (notes §2.4 ``GeneratSinDistubance``, used in ``Follow_OnStep`` under
``#ifdef SIN_GEN``) adds a sine to the follow target while the LADRC runs (followed and not
machining) and logs the TD's outputs, for ten periods; then the target is the plain one
again. The firmware looks the sine up in a 99-entry table advanced every ``20/f`` ticks, so
its "5 Hz" is 2000/(99·4) = 5.05 Hz; here the sine is exact at ``freq_hz``. Besides the sine,
a linear chirp (``freq_hz`` → ``freq_end_hz``) and a square wave, for the notes' chirp and
square tests run on the target instead of the sheet.

The wave's clock runs only while it is applied (the seed advances its table index only when
it is called), and the wave ends after ``duration_s`` of applied time.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

KINDS = ('sine', 'chirp', 'square')
MAX_AMP_MM = 2.0
MAX_FREQ_HZ = 100.0
MIN_FREQ_HZ = 0.01
MAX_DURATION_S = 600.0
SEED_PERIODS = 10  # GeneratSinDistubance: "测试10周期"


@dataclass(frozen=True)
class TargetWave:
    """``amp_mm`` · wave(t) added to the target; ``duration_s`` 0 = ten periods of ``freq_hz``."""

    kind: str = 'sine'
    amp_mm: float = 0.1
    freq_hz: float = 5.0
    freq_end_hz: float = 0.0   # chirp only: the frequency at the end
    duration_s: float = 0.0

    def problems(self) -> list[str]:
        """Return why this wave cannot run (empty when it can)."""
        out = []
        if self.kind not in KINDS:
            out.append(f'kind must be one of {", ".join(KINDS)}, got {self.kind!r}')
        for name, top in (('amp_mm', MAX_AMP_MM), ('freq_hz', MAX_FREQ_HZ),
                          ('freq_end_hz', MAX_FREQ_HZ), ('duration_s', MAX_DURATION_S)):
            v = getattr(self, name)
            try:
                ok = (isinstance(v, (int, float)) and not isinstance(v, bool)
                      and math.isfinite(float(v)) and 0.0 <= float(v) <= top)
            except OverflowError:  # an int beyond any float
                ok = False
            if not ok:
                out.append(f'{name} must be a number within 0..{top:g}, got {v!r:.40}')
        if not out and self.freq_hz < MIN_FREQ_HZ:
            out.append(f'freq_hz must be at least {MIN_FREQ_HZ:g} Hz')
        if not out and self.kind == 'chirp' and self.freq_end_hz < MIN_FREQ_HZ:
            out.append(f'a chirp needs freq_end_hz of at least {MIN_FREQ_HZ:g} Hz')
        if not out and self.length_s > MAX_DURATION_S:
            out.append(f'ten periods of {self.freq_hz:g} Hz last {self.length_s:g} s, more than '
                       f'{MAX_DURATION_S:g} s: give duration_s')
        return out

    @property
    def length_s(self) -> float:
        """Applied time after which the wave ends."""
        return self.duration_s if self.duration_s > 0.0 else SEED_PERIODS / self.freq_hz

    def value_mm(self, t_s: float) -> float:
        """Return the offset at ``t_s`` of applied time (0 after :attr:`length_s`)."""
        if t_s >= self.length_s:
            return 0.0
        if self.kind == 'chirp':
            # linear chirp: phase 2π (f0 t + (f1 − f0) t² / (2 T))
            f0, f1, dur = self.freq_hz, self.freq_end_hz, self.length_s
            return self.amp_mm * math.sin(2.0 * math.pi * (f0 * t_s
                                                           + 0.5 * (f1 - f0) * t_s * t_s / dur))
        s = math.sin(2.0 * math.pi * self.freq_hz * t_s)
        if self.kind == 'square':
            return self.amp_mm if s >= 0.0 else -self.amp_mm
        return self.amp_mm * s
