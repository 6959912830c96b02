"""The drive's integer units and the contract's mm and mm/s, both ways.

A CiA 402 drive counts position in increments (0x6064, INTEGER32) and velocity in its velocity
unit (0x606C, 0x60FF, INTEGER32): increments/s on many drives, 0.1 rpm or a gear-scaled unit on
others. :class:`DriveUnits` holds the two factors (increments per mm; velocity units per mm/s),
from parameters (checked against the drive's objects where it has them: a later layer).

Commands are rounded toward zero (``int`` truncation): the integer the drive gets is never
larger in magnitude than the command, so a downward command never comes out bigger (the nozzle
never moves faster toward the sheet than the controller asked). Readings are converted exactly
(a float of the integer).
"""

from __future__ import annotations

from dataclasses import dataclass
import math

INT32_MIN = -(1 << 31)
INT32_MAX = (1 << 31) - 1


@dataclass(frozen=True)
class DriveUnits:
    """Increments per mm and velocity units per mm/s of one drive (both > 0, finite)."""

    increments_per_mm: float = 1000.0
    velocity_units_per_mm_s: float = 1000.0  # default: increments/s at 1000 increments/mm

    def __post_init__(self) -> None:
        for name in ('increments_per_mm', 'velocity_units_per_mm_s'):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f'{name} = {v}: must be a finite number > 0')

    @classmethod
    def from_velocity_factor(cls, increments_per_mm: float,
                             increments_per_s_per_unit: float) -> DriveUnits:
        """Units of a drive whose velocity unit is ``increments_per_s_per_unit`` increments/s.

        Increments/s: 1; a unit of 0.1 rpm on an encoder of N increments per revolution:
        N / 600.
        """
        return cls(increments_per_mm, increments_per_mm / increments_per_s_per_unit)

    # ---- readings: integer -> contract -------------------------------------------------
    def position_mm(self, increments: int) -> float:
        """Position actual (0x6064) in mm."""
        return increments / self.increments_per_mm

    def velocity_mm_s(self, units: int) -> float:
        """Velocity actual (0x606C) in mm/s."""
        return units / self.velocity_units_per_mm_s

    # ---- commands: contract -> integer (toward zero, within INT32) ----------------------
    def velocity_command(self, mm_s: float) -> int:
        """Target velocity (0x60FF) for ``mm_s``, rounded toward zero; NaN -> 0."""
        if math.isnan(mm_s):
            return 0
        return _toward_zero(mm_s * self.velocity_units_per_mm_s)

    def position_command(self, mm: float) -> int:
        """Return a position (increments) for ``mm``, toward zero; NaN -> ValueError."""
        if math.isnan(mm):
            raise ValueError('position NaN')
        return _toward_zero(mm * self.increments_per_mm)

    # ---- the drive's side: what the emulated drive reports --------------------------------
    def position_increments(self, mm: float) -> int:
        """Return the encoder count for a position: the nearest increment."""
        return _clip32(round(mm * self.increments_per_mm))

    def velocity_units(self, mm_s: float) -> int:
        """Velocity actual for ``mm_s``, rounded to the nearest unit."""
        return _clip32(round(mm_s * self.velocity_units_per_mm_s))


def _clip32(v: int) -> int:
    return INT32_MAX if v > INT32_MAX else (INT32_MIN if v < INT32_MIN else v)


def _toward_zero(x: float) -> int:
    if math.isinf(x):
        return INT32_MAX if x > 0 else INT32_MIN
    return _clip32(int(x))  # int() truncates toward zero


@dataclass(frozen=True)
class AnalogScale:
    """The capacitive reading on an analog input: ``counts = offset + mm * counts_per_mm``.

    Two counts are signals, not gaps: ``invalid`` (the amplifier's out-of-range output: no
    sheet under the nozzle, beyond the range, no sensor) and ``contact`` (its short-circuit
    output: the nozzle touches the sheet). Every other count is a gap. ``lo`` .. ``hi``: the
    input's integer range (its data type in the EDS).
    """

    counts_per_mm: float = 1000.0  # 0..20 mm -> 0..20000 counts
    invalid: int = 0x7FFF
    contact: int = -0x8000
    offset: float = 0.0
    lo: int = -0x8000
    hi: int = 0x7FFF

    def counts(self, mm: float, valid: bool = True, contact: bool = False) -> int:
        """Return the count the input reports for ``mm`` (nearest; the signals as such)."""
        if contact:
            return self.contact
        if not valid or not math.isfinite(mm):
            return self.invalid
        c = max(self.lo, min(self.hi, round(self.offset + mm * self.counts_per_mm)))
        if c in (self.invalid, self.contact):  # a gap never reads as a signal
            c += 1 if c < self.hi and c + 1 not in (self.invalid, self.contact) else -1
        return c

    def mm(self, counts: int) -> tuple[float, bool]:
        """``(mm, valid)`` of a count (NaN, False for ``invalid``; 0, False for ``contact``)."""
        if counts == self.invalid:
            return math.nan, False
        if counts == self.contact:
            return 0.0, False
        return (counts - self.offset) / self.counts_per_mm, True

    def status(self, counts: int) -> int:
        """``CapacitiveHeight.status`` of a count: 0 ok, 1 out of range, 2 collision."""
        return 1 if counts == self.invalid else (2 if counts == self.contact else 0)
