"""Replayed against recorded: the commands compared by float64 bit pattern, per tick.

A controller that replays exactly reproduces every bit; the first mismatch, the missing ticks
and the internals that diverged first are reported.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .recording import RecordedBatch, Recording
from .rerun import Replay, ReplayBatch, ReplayResult


# ---- comparison -------------------------------------------------------------------------------
def _bits_differ(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (np.ascontiguousarray(a, dtype=np.float64).view(np.uint64)
            != np.ascontiguousarray(b, dtype=np.float64).view(np.uint64))


class Comparison:
    """A replay against its recording, bit for bit, fed batch by batch (:meth:`add`).

    ``mismatches`` counts ticks whose sent velocity differs in its float64 bit pattern, up to
    the first break in the status ticks (a missing tick breaks exact replay after it: the
    controller cannot be stepped over inputs the bag does not hold); ticks after the break are
    counted in ``mismatches_after_gap``. ``enable_mismatches`` compares the drive enable bit
    (live bags only: headless bags derive it from the state). ``internal_mismatch_ticks``
    counts ticks where a recorded status internal (ESO states, terms, state, ...) differs.
    """

    def __init__(self, live: bool) -> None:
        self.live = live
        self.n = 0
        self.start_tick: int | None = None
        self.prev_tick: int | None = None
        self.end_tick: int | None = None
        self.broken = False              # a tick is missing: exactness ends there
        self.exact_until: int | None = None
        self.missing = 0
        self.mismatches = 0
        self.after = 0
        self.first: dict[str, Any] | None = None
        self.enable_mism = 0
        self.commands_missing = 0
        self.int_ticks = 0
        self.int_fields: dict[str, int] = {}
        self.first_int: dict[str, Any] | None = None

    def add(self, rb: RecordedBatch, pb: ReplayBatch) -> None:
        """Compare one batch."""
        ticks = rb.ticks
        m = ticks.size
        if m == 0:
            return
        if self.start_tick is None:
            self.start_tick = int(ticks[0])
        d = np.diff(ticks if self.prev_tick is None else np.r_[self.prev_tick, ticks])
        self.missing += int(np.sum(d[d > 1] - 1)) if d.size else 0
        exact = m  # ticks of this batch before the first break
        if self.broken:
            exact = 0
        else:
            br = np.flatnonzero(d != 1)
            if br.size:
                exact = int(br[0]) + (0 if self.prev_tick is not None else 1)
                self.broken = True
            last_exact = exact - 1
            if last_exact >= 0:
                self.exact_until = int(ticks[last_exact])
        self.prev_tick = self.end_tick = int(ticks[-1])
        diff = _bits_differ(rb.command, pb.velocity)
        mism = np.flatnonzero(diff[:exact])
        if mism.size and self.first is None:
            i0 = int(mism[0])
            self.first = {'tick': int(ticks[i0]), 'recorded_mm_s': float(rb.command[i0]),
                          'replayed_mm_s': float(pb.velocity[i0])}
        self.mismatches += int(mism.size)
        self.after += int(np.count_nonzero(diff[exact:]))
        if self.live:
            en = (rb.command_enable != pb.enable) & rb.command_present
            self.enable_mism += int(np.count_nonzero(en[:exact]))
        self.commands_missing += int(m - np.count_nonzero(rb.command_present))
        self.n += m
        any_diff = np.zeros(m, dtype=bool)
        per_key: dict[str, np.ndarray] = {}
        for key, mine in pb.internals.items():
            if key not in rb.status:
                continue
            recd = np.asarray(rb.status[key], dtype=np.float64)
            dk = _bits_differ(recd, mine) & ~(np.isnan(recd) & np.isnan(mine))
            dk[exact:] = False
            c = int(np.count_nonzero(dk))
            if c:
                self.int_fields[key] = self.int_fields.get(key, 0) + c
                any_diff |= dk
                per_key[key] = dk
        self.int_ticks += int(np.count_nonzero(any_diff))
        if self.first_int is None and any_diff.any():
            i0 = int(np.argmax(any_diff))
            self.first_int = {'tick': int(ticks[i0]), 'fields': {
                k: [float(rb.status[k][i0]), float(pb.internals[k][i0])]
                for k, dk in per_key.items() if dk[i0]}}

    def summary(self, run: Replay | ReplayResult) -> dict[str, Any]:
        """Return the comparison as a dict (the replay's JSON line)."""
        out: dict[str, Any] = {
            'ticks': int(self.n),
            'mismatches': self.mismatches,
            'first_mismatch_tick': self.first['tick'] if self.first else None,
            'missing_ticks': self.missing,
            'params_source': run.params_source,
            'start_tick': self.start_tick,
            'end_tick': self.end_tick,
            'exact_until_tick': self.exact_until,
            'mismatches_after_gap': self.after,
            'commands_missing': self.commands_missing,
            'enable_mismatches': self.enable_mism if self.live else None,
            'internal_mismatch_ticks': self.int_ticks,
            'internal_mismatch_fields': self.int_fields,
            'first_internal_mismatch': self.first_int,
            'rejected_commands': len(run.rejected),
            'replay_s': run.wall_s,
            'ticks_per_s': run.ticks_per_s,
        }
        if self.first is not None:
            out['first_mismatch'] = {k: self.first[k] for k in ('recorded_mm_s',
                                                                 'replayed_mm_s')}
        return out


def compare(rec: Recording, res: ReplayResult) -> dict[str, Any]:
    """Compare a whole replay with a whole recording (:class:`Comparison` in one batch)."""
    cmp = Comparison(live=rec.source != 'headless')
    cmp.add(rec.whole(), res.whole())
    return cmp.summary(res)
