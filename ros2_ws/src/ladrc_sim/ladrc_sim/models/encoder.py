"""Axis encoder: position quantized to ``resolution_mm``, with optional glitches for fault tests.

Glitches (scenario events ``encoder_jump`` / ``encoder_stuck``):

* ``jump``: ``size_mm`` is added to the reading from ``t_s`` for ``duration_s`` (``inf``:
  for good, as a lost count would);
* ``stuck``: the reading holds the value it had at ``t_s`` for ``duration_s``.

Both are laid out per tick up front, so the per-tick path only indexes lists.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

from ladrc_contract.schema import param

from .axis import H_S, check_fields


@dataclass(frozen=True)
class EncoderParams:
    """Encoder resolution (1 µm by default, a typical linear scale / motor encoder)."""

    resolution_mm: float = param(0.001, '', '0 = not quantized', ge=0.0)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class Glitch:
    """One encoder fault: ``kind`` 'jump' or 'stuck' from ``t_s`` for ``duration_s``."""

    kind: str = param('jump', choices=('jump', 'stuck'))
    t_s: float = param(0.0, ge=0.0)
    duration_s: float = param(math.inf, gt=0.0, inf_ok=True)
    size_mm: float = param(0.0)

    def __post_init__(self) -> None:
        check_fields(self)


class Encoder:
    """Quantized position reading over a run of ``n_ticks``; ``read(i, position_mm)``."""

    def __init__(self, params: EncoderParams, n_ticks: int, h_s: float = H_S,
                 glitches: tuple[Glitch, ...] = ()):
        self.params = params
        self._res = params.resolution_mm
        offset = [0.0] * n_ticks
        stuck = [False] * n_ticks
        for g in glitches:
            i0 = max(0, int(round(g.t_s / h_s)))
            i1 = n_ticks if math.isinf(g.duration_s) else min(
                n_ticks, i0 + max(1, int(round(g.duration_s / h_s))))
            for i in range(i0, i1):
                if g.kind == 'jump':
                    offset[i] += g.size_mm
                else:
                    stuck[i] = True
        self._offset = offset
        self._stuck = stuck
        self._any = any(stuck) or any(o != 0.0 for o in offset)
        self._last = 0.0

    def read(self, i: int, position_mm: float) -> float:
        """Return the encoder reading (mm) at tick ``i`` for the true axis position."""
        if self._any:
            if self._stuck[i]:
                return self._last
            position_mm += self._offset[i]
            r = self._res
            v = round(position_mm / r) * r if r > 0.0 else position_mm
            self._last = v
            return v
        r = self._res
        return round(position_mm / r) * r if r > 0.0 else position_mm
