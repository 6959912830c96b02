"""Excitation player: a "controller" that plays an :class:`.Excitation`.

It has the duck type the headless runner (``ladrc_sim.headless.runner.run``) and the sim node's
bridge take from a controller: ``step(tick) -> velocity_mm_s`` and ``command(name, **kw)``
(follow commands are ignored: nothing is followed). It commands zero for ``settle_s`` (the
axis and the sensor filter come to rest, the start position is taken), then the profile, one
sample per tick, then zero.

Safety (docs/safety.md): it stops for good, commanding zero with ``enable`` false, on any
surprise, and says why (``abort_reason``): the drive disabled or faulted, the encoder not
finite or stale, the sensor reporting contact, a valid reading below ``min_gap_mm``, or the
encoder further than the profile's travel plus ``excursion_margin_mm`` from the start (a gain
far from 1, a wrong sign, a runaway). ``internals()`` reports ``command_enable`` for the
bag writer (``bags.bag.write_run_bag``: the ``enable`` of ``axis/velocity_command``).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any

from ladrc_contract.codes import GapStatus
import numpy as np

from .excitation import H_S, Excitation

STATUS_COLLISION = int(GapStatus.COLLISION)


@dataclass(frozen=True)
class PlayerLimits:
    """When the player gives up (each a bound of the test, docs/identification.md)."""

    settle_s: float = 0.2
    min_gap_mm: float = 1.0
    excursion_margin_mm: float = 0.5
    stale_s: float = 0.01

    def problems(self) -> list[str]:
        """Return why these limits cannot be used (empty: fine)."""
        out = []
        for name, lo, hi in (('settle_s', 0.0, 10.0), ('min_gap_mm', 0.0, 20.0),
                             ('excursion_margin_mm', 0.0, 2.0), ('stale_s', 0.0, 1.0)):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool)
                    and math.isfinite(v) and lo <= v <= hi):
                out.append(f'{name} = {v!r} must be a number in [{lo:g}, {hi:g}]')
        return out


class ExcitationPlayer:
    """Play ``excitation`` after ``limits.settle_s`` at the tick ``h_s`` (module docstring)."""

    def __init__(self, excitation: Excitation, limits: PlayerLimits | None = None,
                 h_s: float = H_S) -> None:
        self.limits = limits or PlayerLimits()
        reasons = self.limits.problems()
        if reasons:
            raise ValueError('excitation player: ' + '; '.join(reasons))
        self.excitation = excitation
        self.h_s = float(h_s)
        self.profile: list[float] = excitation.velocity_mm_s(self.h_s).tolist()
        self.start_tick = int(round(self.limits.settle_s / self.h_s))
        self.bound_mm = float(excitation.max_travel_mm) + self.limits.excursion_margin_mm
        self.abort_reason = ''
        self.start_mm = math.nan
        self.max_excursion_mm = 0.0
        self._k = 0
        self._enable = 1.0

    @property
    def ticks(self) -> int:
        """Ticks from the first ``step`` to the end of the profile."""
        return self.start_tick + len(self.profile)

    @property
    def finished(self) -> bool:
        """Whether the whole profile was played without an abort."""
        return self._k >= self.ticks and not self.abort_reason

    def command(self, name: str, **kwargs: Any) -> None:
        """Ignore follow commands: the player follows nothing."""

    def internals(self) -> dict[str, float]:
        """Return ``command_enable`` (1 playing or resting, 0 after an abort)."""
        return {'command_enable': self._enable}

    def _abort(self, reason: str) -> float:
        if not self.abort_reason:
            self.abort_reason = reason
        self._enable = 0.0
        return 0.0

    def step(self, tick: Any) -> float:
        """Return this tick's command: zero, the profile's sample, or zero after an abort."""
        k = self._k
        self._k = k + 1
        if self.abort_reason:
            return 0.0
        if not tick.drive_enabled or tick.drive_fault:
            return self._abort(f'drive {"faulted" if tick.drive_fault else "disabled"} at '
                               f't = {tick.t_s:.4f} s')
        enc = tick.encoder_mm
        if not math.isfinite(enc):
            return self._abort(f'encoder position not finite at t = {tick.t_s:.4f} s')
        if tick.t_s - tick.encoder_stamp_s > self.limits.stale_s:
            return self._abort(f'encoder stale ({(tick.t_s - tick.encoder_stamp_s) * 1e3:.1f} '
                               f'ms) at t = {tick.t_s:.4f} s')
        if getattr(tick, 'gap_status', 0) == STATUS_COLLISION:
            return self._abort(f'sensor reports contact at t = {tick.t_s:.4f} s')
        if tick.gap_valid and tick.gap_mm < self.limits.min_gap_mm:
            return self._abort(f'gap reading {tick.gap_mm:.3f} mm below min_gap_mm '
                               f'{self.limits.min_gap_mm:g} at t = {tick.t_s:.4f} s')
        j = k - self.start_tick
        if j < 0:
            return 0.0
        if j == 0:
            self.start_mm = enc
        excursion = abs(enc - self.start_mm)
        self.max_excursion_mm = max(self.max_excursion_mm, excursion)
        if excursion > self.bound_mm:
            return self._abort(f'encoder {excursion:.3f} mm from the start, beyond '
                               f'{self.bound_mm:g} mm (travel + margin) at t = '
                               f'{tick.t_s:.4f} s')
        if j >= len(self.profile):
            return 0.0
        u = self.profile[j]
        return u if np.isfinite(u) else self._abort('non-finite excitation sample')
