"""Replay a bag's recorded per-tick inputs through the control core, bit for bit or what-if.

The replay API's front, split by concern: :mod:`.recording` (the bag's recorded inputs,
commands and events, streamed), :mod:`.rerun` (the control core over them, open loop),
:mod:`.compare` (replayed vs recorded, by float64 bit pattern) and :mod:`.whatif` (another
parameter set over the same inputs, :mod:`.overrides` for the set). :func:`run_streamed`
drives a replay over a whole bag with the comparison or the what-if table alongside. Pure
Python + numpy (no rclpy).
"""

from __future__ import annotations

from typing import Any, Callable

from .compare import Comparison, compare
from .overrides import parse_set, whatif_params
from .recording import (
    KIND_NAMES,
    RecordedBatch,
    RecordedEvent,
    Recording,
    ReplayError,
    event_command,
    load_recording,
    open_recording,
)
from .rerun import Replay, ReplayBatch, ReplayResult, replay
from .whatif import OPEN_LOOP_NOTE, WhatIf, whatif_table, write_whatif

__all__ = [
    'ReplayError', 'Recording', 'RecordedBatch', 'RecordedEvent', 'Replay', 'ReplayBatch',
    'ReplayResult', 'Comparison', 'WhatIf', 'open_recording', 'load_recording',
    'event_command', 'replay', 'compare', 'parse_set', 'whatif_params', 'whatif_table',
    'write_whatif', 'run_streamed', 'OPEN_LOOP_NOTE', 'KIND_NAMES',
]


def run_streamed(rec: Recording, run: Replay, whatif: bool,
                 progress: Callable[[int, int], None] | None = None
                 ) -> tuple[dict[str, Any], WhatIf | None]:
    """Replay ``rec`` batch by batch into a :class:`Comparison` (and a :class:`WhatIf`).

    Nothing of the run is held beyond a batch: what an hour-long bag costs is time, not
    memory. Returns the comparison summary and the what-if accumulator (or None).
    """
    cmp = Comparison(live=rec.source != 'headless')
    wi = WhatIf(rec.h_s, rec.n_ticks) if whatif else None
    for rb, pb in run.batches(progress):
        cmp.add(rb, pb)
        if wi is not None:
            wi.add(rb, pb)
    return cmp.summary(run), wi
