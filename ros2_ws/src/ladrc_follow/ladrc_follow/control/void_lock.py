"""Void lock (plasmac ``voidlock``): a surface that falls faster than a sheet is not followed.

A nozzle that crosses a hole, a kerf or the sheet's edge reads a gap that widens faster than any
sheet falls away; following it down drives the nozzle toward material that is not there (or
into the part of the sheet still under its footprint). LinuxCNC's plasmac locks the height when
the arc voltage's slope exceeds ``voidlock_slope`` for ``voidlock_on_cycles`` cycles and
unlocks after ``voidlock_off_cycles`` below it. Here the signal is the apparent sheet surface
``encoder − gap`` (the reading's change that the axis' own travel does not explain), judged
twice by the one lock:

* **one sample** (:meth:`VoidLock.sample`, asked by the input gate): a new reading wider than
  the encoder-predicted gap by more than ``follow.jump_mm``, a fall no sheet makes in one
  sample period, locks at once (a slope of ``jump_mm / h``, beyond any count) and the sample is
  not used; a level that persists for ``follow.jump_confirm_s`` is taken as real, and the slope
  below judges it from then on;
* **the slope** (:meth:`VoidLock.slope`, asked by the edge guard on every usable tick): the
  apparent surface's speed, low-passed over ``edge.fall_tau_s``, falling faster than
  ``edge.fall_mm_s`` for ``edge.void_lock_ticks`` ticks in a row locks; ``edge.void_unlock_ticks``
  ticks in a row at or above it unlock. Closing in after an unlock is probed (edge.py).

While locked the controller holds (no command toward the sheet; the CNC sees ``SUB_VOID_LOCK``
with the reason). The lock's memory survives parameter sets (the controller owns one).
Plain Python scalars, one tick at a time.
"""

from __future__ import annotations

import math


class VoidLock:
    """The void lock of one controller (module docstring)."""

    def __init__(self, counts: dict[str, int]) -> None:
        self.counts = counts  # 'jump': samples held; 'void_lock': lock episodes
        self.surface_mm_s = 0.0  # apparent-surface speed, low-passed over fall_tau_s
        self._jump_t0_s = math.nan  # time of the first jumped reading being held
        self._beyond = 0  # ticks in a row with the slope beyond the limit
        self._within = 0  # ticks in a row with it within, while locked
        self.slope_locked = False
        self.reason = ''

    def configure(self, jump_mm: float, jump_confirm_s: float, fall_mm_s: float,
                  fall_tau_s: float, lock_ticks: int, unlock_ticks: int, h_s: float) -> None:
        """Take the limits of a parameter set (the memory stays)."""
        self._jump_mm, self._confirm_s = jump_mm, jump_confirm_s
        self._fall_mm_s = fall_mm_s
        self._c = h_s / (fall_tau_s + h_s)  # backward-Euler low-pass, as pid.py
        self._lock_ticks, self._unlock_ticks = lock_ticks, unlock_ticks

    @property
    def jump_held(self) -> bool:
        """A jumped reading is being held (its level not yet confirmed)."""
        return not math.isnan(self._jump_t0_s)

    @property
    def locked(self) -> bool:
        """Held by either judgement."""
        return self.slope_locked or self.jump_held

    def sample(self, t_s: float, widening_mm: float) -> bool:
        """Judge a new reading ``widening_mm`` wider than the encoder predicts: True = hold it."""
        if widening_mm > self._jump_mm:
            self.counts['jump'] += 1
            if math.isnan(self._jump_t0_s):
                self._lock(f'void lock: reading {widening_mm:.3f} mm wider than the encoder '
                           f'predicts in one sample (limit {self._jump_mm:g} mm); held until '
                           f'it persists {self._confirm_s * 1e3:g} ms')
                self._jump_t0_s = t_s
            if t_s - self._jump_t0_s < self._confirm_s:
                return True
        self._jump_t0_s = math.nan
        return False

    def slope(self, ds_mm_s: float) -> bool:
        """Take this tick's apparent-surface speed (unfiltered); return whether locked by it."""
        v = self.surface_mm_s = self.surface_mm_s + self._c * (ds_mm_s - self.surface_mm_s)
        if v < -self._fall_mm_s:
            self._within = 0
            self._beyond += 1
            if not self.slope_locked and self._beyond >= self._lock_ticks:
                self._lock(f'void lock: the apparent surface falls at {-v:.0f} mm/s, faster '
                           f'than a sheet (limit {self._fall_mm_s:g} mm/s); held')
                self.slope_locked = True
        else:
            self._beyond = 0
            if self.slope_locked:
                self._within += 1
                if self._within >= self._unlock_ticks:
                    self.slope_locked = False
                    self._within = 0
        return self.slope_locked

    def clear_slope(self) -> None:
        """Forget the slope (a verification aborted, an edge hold released): unlocked, at rest."""
        self.surface_mm_s = 0.0
        self._beyond = self._within = 0
        self.slope_locked = False

    def _lock(self, reason: str) -> None:
        """Lock (called before the judgement's own flag is set): one episode per lock."""
        if not self.locked:
            self.counts['void_lock'] += 1
        self.reason = reason
