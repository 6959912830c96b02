"""Re-running the control core over a recording, open loop: the replay itself.

:class:`Replay` rebuilds the controller from the bag's own parameter set (or a what-if set),
re-applies the recorded events at their ticks, steps it over the recorded inputs batch by batch
and returns what it would have sent (``step`` output, or 0.0 when ``enable`` is off: the node's
masking). :func:`run_streamed` drives it over a whole bag with the comparison or the what-if
table accumulating alongside.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import operator
import time
from typing import Any, Callable, Iterator, Mapping

from ladrc_contract.tick import CncInput, TickInput
from ladrc_follow import ControllerParams, FollowController, ParameterError, params_from_dict
import numpy as np
import yaml

from .overrides import _delta, _with
from .recording import (
    CNC_FIELDS,
    COMPARED_INTERNALS,
    INPUT_FIELDS,
    KIND_NAMES,
    PARAMETERS,
    RecordedBatch,
    RecordedEvent,
    Recording,
    ReplayError,
    event_command,
)


@dataclass
class ReplayBatch:
    """What the replayed controller sent for one :class:`RecordedBatch`."""

    velocity: np.ndarray
    enable: np.ndarray
    internals: dict[str, np.ndarray]     # COMPARED_INTERNALS (empty without internals)


@dataclass
class ReplayResult:
    """One replay held whole: the commands sent per status tick, enable bits, internals."""

    velocity: np.ndarray
    enable: np.ndarray
    internals: dict[str, np.ndarray]
    params: ControllerParams             # the set at the start of the replay
    params_source: str
    rejected: list[str]                  # commands the replayed controller refused
    notes: list[str]
    wall_s: float

    @property
    def ticks_per_s(self) -> float:
        """Replay speed (ticks per wall-clock second)."""
        return self.velocity.size / self.wall_s if self.wall_s > 0 else math.inf

    def whole(self) -> ReplayBatch:
        """Return the whole replay as one batch."""
        return ReplayBatch(self.velocity, self.enable, self.internals)


# ---- replay -----------------------------------------------------------------------------------
class Replay:
    """One replay of a recording, stepped batch by batch (:meth:`batches`).

    ``params=None`` replays with the bag's own set (every recorded PARAMETERS event applied
    as recorded). A what-if set (``params``, ``overrides``) starts the run instead; a later
    recorded parameter change is then applied as its *change* (the keys that differ from the
    previous recorded set) on top of the running what-if set, with ``overrides`` kept on top.
    ``mode`` ('ladrc' | 'pid') overrides the bag's headless ``--controller``. After the
    batches: ``rejected`` (commands the controller refused), ``notes``, ``ticks``, ``wall_s``.
    """

    def __init__(self, rec: Recording, params: ControllerParams | None = None, *,
                 overrides: Mapping[str, Any] | None = None, mode: str | None = None,
                 record_internals: bool = True, params_source: str | None = None) -> None:
        self.rec = rec
        self.own = params is None and not overrides
        start = rec.params if params is None else params
        if overrides:
            start = _with(start, overrides, '--set')
        self.params = start
        self.pins = dict(overrides or {})
        self.mode = mode or rec.mode
        self.record_internals = record_internals
        self.params_source = params_source or (rec.params_source if self.own else 'what-if')
        self.rejected: list[str] = []
        self.notes: list[str] = []
        self.ticks = 0
        self.wall_s = 0.0

    @property
    def ticks_per_s(self) -> float:
        """Replay speed (ticks per wall-clock second of stepping)."""
        return self.ticks / self.wall_s if self.wall_s > 0 else math.inf

    def batches(self, progress: Callable[[int, int], None] | None = None
                ) -> Iterator[tuple[RecordedBatch, ReplayBatch]]:
        """Step a fresh controller over the recording; yield each batch and what it sent."""
        ctl = FollowController(self.params, mode=self.mode)  # as recorded
        events = self.rec.events
        n_ev = len(events)
        j = 0
        recorded_set = self.rec.params
        notes, rejected = self.notes, self.rejected
        new_tick = tuple.__new__
        step = ctl.step
        internals = ctl.internals
        compared = operator.itemgetter(*COMPARED_INTERNALS)  # one C call per tick's row
        for rb in self.rec.batches(progress):
            wall0 = time.perf_counter()
            m = rb.ticks.size
            # plain Python values for one batch (the per-tick path is scalar code)
            ticks = rb.ticks.tolist()
            t_l, gap_l, valid_l, gst_l, enc_l, est_l, den_l, dfl_l, stat_l = (
                rb.inputs[f].tolist() for f in INPUT_FIELDS)
            valid_l = [bool(v) for v in valid_l]
            den_l = [bool(v) for v in den_l]
            dfl_l = [bool(v) for v in dfl_l]
            stat_l = [int(v) for v in stat_l]
            cnc_l = _cnc_inputs(rb.status, m)
            out_v = [0.0] * m
            out_en = [False] * m
            rows: list[dict] | None = [] if self.record_internals else None
            for i in range(m):
                k = ticks[i]
                # events due at or before this tick (also those of ticks missing in the bag)
                while j < n_ev and events[j].tick <= k:
                    ev = events[j]
                    j += 1
                    if ev.kind == PARAMETERS:
                        recorded_set = self._apply_set(ctl, ev, recorded_set)
                    elif ev.kind in KIND_NAMES:
                        name, kwargs = event_command(ev)
                        ok, msg = ctl.command(name, **kwargs)
                        if not ok:
                            rejected.append(f'tick {ev.tick} {name}: {msg}')
                    else:
                        notes.append(f'tick {ev.tick}: unknown event kind {ev.kind} ignored')
                u = step(new_tick(TickInput, (t_l[i], gap_l[i], valid_l[i], gst_l[i], enc_l[i],
                                              est_l[i], den_l[i], dfl_l[i], stat_l[i])),
                         cnc_l[i])
                # follow_node: the velocity sent is the step output when enabled, else 0.0
                if ctl.enable:
                    out_v[i] = u
                    out_en[i] = True
                if rows is not None:
                    rows.append(compared(internals()))
            got = {}
            if rows is not None and m:
                table = np.array(rows, dtype=float).reshape(m, len(COMPARED_INTERNALS))
                got = {key: table[:, c].copy() for c, key in enumerate(COMPARED_INTERNALS)}
            elif rows is not None:
                got = {key: np.zeros(0) for key in COMPARED_INTERNALS}
            self.ticks += m
            self.wall_s += time.perf_counter() - wall0
            yield rb, ReplayBatch(np.asarray(out_v, dtype=np.float64),
                                  np.asarray(out_en, dtype=bool), got)
        if j < n_ev:
            notes.append(f'{n_ev - j} event(s) after the last recorded tick not applied')

    def _apply_set(self, ctl: FollowController, ev: RecordedEvent,
                   recorded_set: ControllerParams) -> ControllerParams:
        """Apply a recorded PARAMETERS event; return the recorded set now in force."""
        try:
            new_set = params_from_dict(yaml.safe_load(ev.text))
        except (yaml.YAMLError, ParameterError) as exc:
            self.notes.append(f'tick {ev.tick}: recorded parameter set unusable '
                              f'({" ".join(str(exc).split())[:120]}); not applied')
            return recorded_set
        if self.own:
            target = new_set
        else:
            change = _delta(recorded_set, new_set)
            change.update(self.pins)
            try:
                target = _with(ctl.params, change, f'tick {ev.tick} parameter change')
            except ReplayError as exc:
                self.notes.append(f'{exc}; not applied')
                return new_set
        try:
            ctl.set_params(target)
        except ValueError as exc:
            self.notes.append(f'tick {ev.tick}: parameter set refused '
                              f'({" ".join(str(exc).split())[:120]})')
        return new_set


def _cnc_inputs(status: Mapping[str, np.ndarray], m: int) -> list[CncInput | None]:
    """Return the CNC sample each tick used (FollowStatus.cnc_*); None where none came."""
    seq = status.get('cnc_seq')
    if seq is None or not seq.any():
        return [None] * m
    cols = [status[f].tolist() for f in CNC_FIELDS]
    return [CncInput(int(q), st, int(sg), bool(b), int(c), cf, af, sl, ea) if q else None
            for q, st, sg, b, c, cf, af, sl, ea in zip(*cols, strict=True)]


def replay(rec: Recording, params: ControllerParams | None = None, *,
           overrides: Mapping[str, Any] | None = None, mode: str | None = None,
           record_internals: bool = True, params_source: str | None = None,
           progress: Callable[[int, int], None] | None = None) -> ReplayResult:
    """Run a :class:`Replay` and hold its whole output (the arguments of :class:`Replay`)."""
    run = Replay(rec, params, overrides=overrides, mode=mode,
                 record_internals=record_internals, params_source=params_source)
    parts = [pb for _, pb in run.batches(progress)]
    keys = COMPARED_INTERNALS if record_internals else ()
    return ReplayResult(
        velocity=np.concatenate([p.velocity for p in parts]) if parts else np.zeros(0),
        enable=np.concatenate([p.enable for p in parts]) if parts else np.zeros(0, bool),
        internals={k: np.concatenate([p.internals[k] for p in parts]) if parts
                   else np.zeros(0) for k in keys},
        params=run.params, params_source=run.params_source, rejected=run.rejected,
        notes=run.notes, wall_s=run.wall_s)


