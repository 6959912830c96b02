"""Replay a bag's recorded per-tick inputs through the control core, bit for bit or what-if.

Every ``follow/status`` message holds the exact inputs the controller used that tick
(docs/interfaces.md), and ``follow/events`` holds every follow command and parameter set with
the tick at whose start it took effect. :func:`replay` rebuilds the controller from the bag's
own parameter set, re-applies the events at their ticks (mapping the event fields back to the
command arguments exactly as ``follow_node.py`` produced them), steps it over the recorded
inputs and returns the command it sends (``step`` output, or 0.0 when ``enable`` is off: the
node's masking). :func:`compare` checks it against ``axis/velocity_command`` by float64 *bit
pattern*: a controller that replays exactly reproduces every bit.

What-if (:func:`whatif_params`): the same inputs with another parameter set. This is **open
loop**: the recorded inputs (gap, encoder) do not react to the what-if command, so the result
shows what the controller would have commanded in that situation, not how the closed loop would
have moved. For a closed-loop what-if on a headless bag's scenario use
``ladrc simulate SCENARIO --params FILE``.

Pure Python + numpy (no rclpy): reads bags with :mod:`ladrc_tools.bags.bag`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import json
import math
from pathlib import Path
import time
from typing import Any, Callable, Iterable, Iterator, Mapping

from ladrc_contract.codes import FollowState, LimitFlag
from ladrc_contract.events import decode as decode_event
from ladrc_follow.control.follow import INTERNALS_KEYS, FollowController, TickInput
from ladrc_follow.control.params import (
    ControllerParams,
    ParameterError,
    dump_params,
    params_from_dict,
    params_to_dict,
)
import numpy as np
import yaml

from ..bags.bag import Bag, BagError, open_bag
from .envelope import Envelope
from .outdir import building

__all__ = [
    'ReplayError', 'Recording', 'RecordedBatch', 'RecordedEvent', 'Replay', 'ReplayBatch',
    'ReplayResult', 'Comparison', 'WhatIf', 'open_recording', 'load_recording',
    'event_command', 'replay', 'compare', 'parse_set', 'whatif_params', 'whatif_table',
    'write_whatif', 'run_streamed', 'OPEN_LOOP_NOTE', 'KIND_NAMES',
]

# ladrc_msgs/FollowEvent kinds -> follow command names (follow_node.py's services).
KIND_NAMES = {1: 'start_follow', 2: 'stop_follow', 3: 'set_target', 4: 'machining',
              5: 'height_compensation', 6: 'gradient_follow', 7: 'reset_fault',
              8: 'parameters', 9: 'target_wave'}
PARAMETERS = 8
STATE_NAMES = tuple(s.name for s in FollowState)
LIMIT_VELOCITY, LIMIT_ACCELERATION = int(LimitFlag.VELOCITY), int(LimitFlag.ACCELERATION)

# The TickInput fields, as recorded in FollowStatus (same names).
INPUT_FIELDS = ('t_s', 'gap_mm', 'gap_valid', 'gap_stamp_s', 'encoder_mm', 'encoder_stamp_s',
                'drive_enabled', 'drive_fault', 'gap_status')
# Internals compared / plotted (velocity_mm_s is the command itself, fault_reason a string).
COMPARED_INTERNALS = tuple(k for k in INTERNALS_KEYS if k not in ('velocity_mm_s',
                                                                   'fault_reason'))

# The follow/status fields replay reads (a long bag is read into these columns only).
REPLAY_FIELDS = ('tick', 'velocity_mm_s') + INPUT_FIELDS + tuple(
    k for k in COMPARED_INTERNALS if k not in INPUT_FIELDS)
CHUNK_TICKS = 65536
"""Ticks stepped per batch: Python lists and internals rows exist for one batch at a time."""

OPEN_LOOP_NOTE = ('open loop: the recorded inputs (gap, encoder) do not react to the what-if '
                  'command; for a closed-loop what-if on a headless scenario use '
                  '`ladrc simulate SCENARIO --params FILE`')


class ReplayError(ValueError):
    """A replay cannot run (bad parameter override, unusable what-if); one-line message."""


@dataclass(frozen=True)
class RecordedEvent:
    """One ``follow/events`` message (fields of ``ladrc_msgs/FollowEvent``)."""

    tick: int
    kind: int
    value_mm: float = math.nan
    delay_s: float = 0.0
    velocity_mm_s: float = 0.0
    accel_mm_s2: float = 0.0
    flag: bool = False
    text: str = ''

    @property
    def name(self) -> str:
        """Command name (``parameters`` for a parameter set)."""
        return KIND_NAMES.get(self.kind, f'kind {self.kind}')


@dataclass
class RecordedBatch:
    """Consecutive ``follow/status`` ticks of a recording, their inputs and the commands sent."""

    ticks: np.ndarray                    # follow/status tick, in bag order
    inputs: dict[str, np.ndarray]        # INPUT_FIELDS -> per-status-message values
    status: dict[str, np.ndarray]        # the follow/status columns (recorded internals)
    command: np.ndarray                  # recorded velocity sent for each status tick
    command_enable: np.ndarray           # recorded enable bit (False where missing)
    command_present: np.ndarray          # an axis/velocity_command with seq == tick exists

    def __getitem__(self, sl: slice) -> RecordedBatch:
        return RecordedBatch(self.ticks[sl], {k: v[sl] for k, v in self.inputs.items()},
                             {k: v[sl] for k, v in self.status.items()}, self.command[sl],
                             self.command_enable[sl], self.command_present[sl])


@dataclass
class Recording:
    """What a bag holds for replay: the events, the parameter set and the per-tick batches.

    :func:`open_recording` reads only the small topics; the per-tick data streams from the
    bag, a batch at a time (:meth:`batches`), so an hour-long bag replays in bounded memory.
    :func:`load_recording` also holds the whole run in the array fields (tests, short bags).
    """

    path: Path
    events: list[RecordedEvent]          # follow/events in effect order (tick, bag order)
    params: ControllerParams             # the set in force at the first status tick
    params_source: str
    mode: str | None                     # headless runs' --controller override
    source: str                          # custom_data ladrc.source ('recorder', 'headless')
    n_ticks: int                         # follow/status messages in the bag
    notes: list[str] = field(default_factory=list)
    ticks: np.ndarray | None = None      # the whole run (load_recording), else None
    inputs: dict[str, np.ndarray] | None = None
    status: dict[str, np.ndarray] | None = None
    command: np.ndarray | None = None
    command_enable: np.ndarray | None = None
    command_present: np.ndarray | None = None

    @property
    def h_s(self) -> float:
        """Controller period of the recording [s]."""
        return self.params.h_s

    def whole(self) -> RecordedBatch:
        """Return the whole run as one batch (a recording from :func:`load_recording`)."""
        if self.ticks is None:
            raise ValueError('a streamed recording holds no whole run: use batches()')
        return RecordedBatch(self.ticks, self.inputs, self.status, self.command,
                             self.command_enable, self.command_present)

    def batches(self, progress: Callable[[int, int], None] | None = None
                ) -> Iterator[RecordedBatch]:
        """Yield the run in batches of about CHUNK_TICKS ticks, in bag order."""
        if self.ticks is None:
            yield from _stream_batches(self.path, progress)
            return
        whole, n = self.whole(), self.ticks.size
        for c0 in range(0, n, CHUNK_TICKS):
            yield whole[c0:min(n, c0 + CHUNK_TICKS)]
            if progress is not None:
                progress(min(n, c0 + CHUNK_TICKS), n)


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


def _state_name(state: int) -> str:
    return STATE_NAMES[state] if 0 <= state < len(STATE_NAMES) else str(state)


# ---- reading ----------------------------------------------------------------------------------
def _parse_params(text: str, what: str) -> ControllerParams:
    try:
        data = yaml.safe_load(text)
        return params_from_dict(data)  # reproduce what ran
    except (yaml.YAMLError, ParameterError) as exc:
        raise BagError(f'the parameter set of {what} is unusable: '
                       f'{" ".join(str(exc).split())}') from None


def _read_events(bag: Bag) -> list[RecordedEvent]:
    if not bag.has('follow/events'):
        return []
    out = []
    for _, m in bag.messages('follow/events'):
        out.append(RecordedEvent(int(m.tick), int(m.kind), float(m.value_mm), float(m.delay_s),
                                 float(m.velocity_mm_s), float(m.accel_mm_s2), bool(m.flag),
                                 str(m.text)))
    # stable: events of one tick keep the order the controller logged them in
    out.sort(key=lambda e: e.tick)
    return out


def _first_text(bag: Bag, topic: str) -> str | None:
    # the first set: the node re-publishes run/parameters (latched) on every change
    if not bag.has(topic):
        return None
    for _, msg in bag.messages(topic):
        return str(msg.data)
    return None


CMD_FIELDS = ('seq', 'velocity_mm_s', 'enable')  # + timestamp_ns (bag time), always read


def _inputs(st: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    out = {}
    for name in INPUT_FIELDS:
        if name in st:
            out[name] = st[name]
        else:  # bags from before FollowStatus.gap_status: 0 = "not reported" (TickInput doc)
            out[name] = np.zeros(st['tick'].size, dtype=np.uint8)
    return out


def _join_commands(st: dict[str, np.ndarray], cmd: dict[str, np.ndarray]) -> RecordedBatch:
    """Join each status tick with its command (seq == tick; the last duplicate seq wins)."""
    ticks = st['tick'].astype(np.int64)
    command = np.asarray(st['velocity_mm_s'], dtype=np.float64).copy()
    enable = np.zeros(ticks.size, dtype=bool)
    present = np.zeros(ticks.size, dtype=bool)
    seq = cmd['seq']
    if seq.size:
        order = np.argsort(seq, kind='stable')
        s_sorted = seq[order]
        pos = np.searchsorted(s_sorted, ticks, side='right') - 1
        ok = (pos >= 0) & (s_sorted[np.maximum(pos, 0)] == ticks)
        idx = order[pos[ok]]
        command[ok] = cmd['velocity_mm_s'][idx]
        enable[ok] = cmd['enable'][idx]
        present = ok
    return RecordedBatch(ticks, _inputs(st), st, command, enable, present)


HOLD_NS = 1_000_000_000
"""Bag time a status tick waits for its command (commands may arrive late or out of order)."""


def _stream_batches(path: Path, progress: Callable[[int, int], None] | None
                    ) -> Iterator[RecordedBatch]:
    """Status ticks joined with their commands, read from the bag a slice at a time.

    A status tick is joined once :data:`HOLD_NS` of bag time has been read after it (or the
    bag ends): a command received up to 1 s after its status, in any order, is found, and of
    duplicates the last received wins, as in a join over the whole run. Commands are kept
    from :data:`HOLD_NS` before the oldest waiting tick on, so the memory is that of a few
    slices.
    """
    with open_bag(path) as bag:
        has_cmd = bag.has('axis/velocity_command')
        wanted: dict[str, Any] = {'follow/status': REPLAY_FIELDS}
        if has_cmd:
            wanted['axis/velocity_command'] = CMD_FIELDS
        cmd = {'seq': np.zeros(0, np.int64), 'velocity_mm_s': np.zeros(0),
               'enable': np.zeros(0, bool), 'timestamp_ns': np.zeros(0, np.int64)}
        pending: dict[str, np.ndarray] = {}

        def take(k: int) -> RecordedBatch:
            nonlocal cmd
            st = {c: v[:k] for c, v in pending.items()}
            for c in pending:
                pending[c] = pending[c][k:]
            batch = _join_commands(st, cmd)
            if pending['tick'].size:  # what the waiting ticks may still need
                keep = cmd['timestamp_ns'] >= pending['timestamp_ns'][0] - HOLD_NS
                cmd = {c: v[keep] for c, v in cmd.items()}
            return batch

        latest = 0
        for part in bag.stream(wanted, progress):
            c = part.get('axis/velocity_command')
            if c is not None:
                cmd = {'seq': np.r_[cmd['seq'], c['seq'].astype(np.int64)],
                       'velocity_mm_s': np.r_[cmd['velocity_mm_s'],
                                              c['velocity_mm_s'].astype(np.float64)],
                       'enable': np.r_[cmd['enable'], c['enable'].astype(bool)],
                       'timestamp_ns': np.r_[cmd['timestamp_ns'], c['timestamp_ns']]}
                latest = max(latest, int(c['timestamp_ns'][-1]))
            st = part.get('follow/status')
            if st is not None:
                latest = max(latest, int(st['timestamp_ns'][-1]))
                for k, v in st.items():
                    pending[k] = np.concatenate((pending[k], v)) if k in pending else v
            if not pending or pending['tick'].size == 0:
                if not has_cmd or not cmd['seq'].size:
                    continue
                keep = cmd['timestamp_ns'] >= latest - 2 * HOLD_NS
                cmd = {k: v[keep] for k, v in cmd.items()}
                continue
            k = pending['tick'].size
            if has_cmd:
                k = int(np.searchsorted(pending['timestamp_ns'], latest - HOLD_NS, 'right'))
            if k:
                yield take(k)
        if pending and pending['tick'].size:
            yield take(pending['tick'].size)


def open_recording(path: str | Path) -> Recording:
    """Read what :func:`replay` needs up front (events, parameters, the first tick).

    The per-tick data stays in the bag (:meth:`Recording.batches`). :class:`BagError` (one
    line) if the bag is unusable.
    """
    with open_bag(path) as bag:
        bag.require('follow/status')
        it = bag.iter_columns('follow/status', ('tick', 'state') + INPUT_FIELDS)
        head = next(it, None)
        it.close()
        if head is None or head['tick'].size == 0:
            raise BagError(f'{bag.path}: follow/status holds no message: nothing to replay')
        notes: list[str] = []
        for name in INPUT_FIELDS:
            if name in head:
                continue
            if name == 'gap_status':
                notes.append('follow/status has no gap_status: replayed as 0 (not reported)')
            else:
                raise BagError(f'{bag.path}: follow/status has no {name!r} field: not a '
                               'ladrc_msgs/FollowStatus with the inputs of each tick')
        if not bag.has('axis/velocity_command'):
            notes.append('no axis/velocity_command topic: compared with '
                         'follow/status.velocity_mm_s')
        events = _read_events(bag)
        params_text = _first_text(bag, 'run/parameters')
        custom = bag.custom_data
        bag_path = bag.path
        n_ticks = bag.count('follow/status')

    first = int(head['tick'][0])
    param_events = [e for e in events if e.kind == PARAMETERS]
    initial = [e for e in param_events if e.tick <= first]
    if initial:
        ev = initial[-1]
        params = _parse_params(ev.text, f'the PARAMETERS event at tick {ev.tick}')
        source = f'follow/events PARAMETERS at tick {ev.tick}'
        events = [e for e in events if e is not ev]
    elif params_text:
        params = _parse_params(params_text, 'run/parameters')
        source = 'run/parameters'
        if param_events:
            notes.append(f'the first PARAMETERS event is at tick {param_events[0].tick}, after '
                         f'the first status tick {first}: started from run/parameters')
    else:
        raise BagError(f'{bag_path}: the bag holds no parameter set (no PARAMETERS event on '
                       'follow/events, no run/parameters): cannot rebuild the controller')
    early = [e for e in events if e.tick < first]
    if early:
        notes.append(f'{len(early)} event(s) took effect before the first recorded tick '
                     f'{first} and are not re-applied')
    if first != 0:
        state0 = int(head['state'][0]) if 'state' in head else 0
        notes.append(f'the bag starts at tick {first} in state {_state_name(state0)}: replay '
                     'starts from a fresh controller, exact only if it was IDLE and had not '
                     'followed before')
    mode = custom.get('ladrc.controller')
    return Recording(path=Path(bag_path), events=[e for e in events if e.tick >= first],
                     params=params, params_source=source,
                     mode=mode if mode in ('ladrc', 'pid') else None,
                     source=str(custom.get('ladrc.source', '')), n_ticks=n_ticks, notes=notes)


def load_recording(path: str | Path,
                   progress: Callable[[int, int], None] | None = None) -> Recording:
    """:func:`open_recording` with the whole run read into the array fields."""
    rec = open_recording(path)
    parts = list(rec.batches(progress))

    def cat(get: Callable[[RecordedBatch], np.ndarray]) -> np.ndarray:
        return np.concatenate([get(b) for b in parts])

    return replace(rec, ticks=cat(lambda b: b.ticks),
                   inputs={k: cat(lambda b, k=k: b.inputs[k]) for k in INPUT_FIELDS},
                   status={k: cat(lambda b, k=k: b.status[k]) for k in parts[0].status},
                   command=cat(lambda b: b.command),
                   command_enable=cat(lambda b: b.command_enable),
                   command_present=cat(lambda b: b.command_present))


# ---- events -> controller ---------------------------------------------------------------------
def event_command(ev: RecordedEvent) -> tuple[str, dict[str, Any]]:
    """Return ``(command name, kwargs)`` that re-issue ``ev`` exactly as follow_node did."""
    return decode_event(ev)  # the contract's codec (ladrc_contract.events)


# ---- what-if parameters -----------------------------------------------------------------------
def _flat(d: Mapping[str, Any], prefix: str = '') -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f'{prefix}{k}.'))
        else:
            out[f'{prefix}{k}'] = v
    return out


def parse_set(items: Iterable[str]) -> dict[str, Any]:
    """Parse ``key=value`` overrides (value as YAML: ``law.kp=12``, ``follow.controller=pid``)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition('=')
        key = key.strip()
        if not sep or not key:
            raise ReplayError(f'--set {item!r}: use key=value, e.g. law.kp=12.5')
        try:
            out[key] = yaml.safe_load(text)
        except yaml.YAMLError:
            raise ReplayError(f'--set {item!r}: the value is not valid YAML') from None
    return out


def _with(base: ControllerParams, overrides: Mapping[str, Any], what: str) -> ControllerParams:
    flat = _flat(params_to_dict(base))
    unknown = sorted(k for k in overrides if k not in flat)
    if unknown:
        raise ReplayError(f'{what}: unknown parameter {", ".join(unknown)} (names as in '
                          '`ros2 param list`, e.g. law.kp, eso.w0_rad_s)')
    flat.update(overrides)
    try:
        return params_from_dict(flat)  # offline, open loop: nothing goes live
    except ParameterError as exc:
        raise ReplayError(f'{what}: {"; ".join(exc.reasons)}') from None


def whatif_params(rec: Recording, params_file: str | Path | None = None,
                  overrides: Mapping[str, Any] | None = None) -> ControllerParams:
    """Return the what-if set: ``params_file`` (else the bag's set) with ``overrides`` on top.

    :class:`ReplayError` for an unreadable file, an unknown key or an invalid set; the period
    ``h_s`` cannot change (the recorded ticks are ``h_s`` apart).
    """
    base = rec.params
    if params_file is not None:
        p = Path(params_file)
        try:
            data = yaml.safe_load(p.read_text(encoding='utf-8'))
        except OSError as exc:
            raise ReplayError(f'--params {p}: cannot read it ({exc.strerror or exc})') from None
        except yaml.YAMLError:
            raise ReplayError(f'--params {p}: not valid YAML') from None
        try:
            base = params_from_dict(data)
        except ParameterError as exc:
            raise ReplayError(f'--params {p}: {"; ".join(exc.reasons)}') from None
    out = _with(base, dict(overrides or {}), '--set') if overrides else base
    if out.h_s != rec.h_s:
        raise ReplayError(f"h_s {out.h_s:g} s differs from the recording's {rec.h_s:g} s: a "
                          'replay runs at the recorded ticks')
    return out


def _delta(old: ControllerParams, new: ControllerParams) -> dict[str, Any]:
    a, b = _flat(params_to_dict(old)), _flat(params_to_dict(new))
    return {k: v for k, v in b.items() if a.get(k) != v}


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
                                              est_l[i], den_l[i], dfl_l[i], stat_l[i])))
                # follow_node: the velocity sent is the step output when enabled, else 0.0
                if ctl.enable:
                    out_v[i] = u
                    out_en[i] = True
                if rows is not None:
                    rows.append(internals())
            got = {}
            if rows is not None:
                got = {key: np.fromiter((r[key] for r in rows), dtype=float, count=m)
                       for key in COMPARED_INTERNALS}
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


# ---- what-if comparison -----------------------------------------------------------------------
_WHATIF_INTERNALS = ('disturbance_term_mm_s', 'eso_z1_mm', 'eso_z2', 'eso_z3', 'td_x1_mm',
                     'u0_mm_s', 'p_term_mm_s', 'd_term_mm_s')


class WhatIf:
    """The recorded and the what-if command side by side, fed batch by batch (:meth:`add`).

    Holds running sums (RMS, limit hits, time per state, largest internal differences) and
    the plot's envelope (:class:`~.envelope.Envelope` over ``n_ticks``).
    """

    def __init__(self, h_s: float, n_ticks: int) -> None:
        self.h_s = h_s
        self.n = 0
        self.sums = {'a': 0.0, 'b': 0.0, 'd': 0.0, 'count': 0}
        self.dmax = -math.inf
        self.limits = {'recorded': [0, 0], 'whatif': [0, 0]}
        self.states = {'recorded': np.zeros(len(STATE_NAMES), np.int64),
                       'whatif': np.zeros(len(STATE_NAMES), np.int64)}
        self.internals_diff: dict[str, float] = {}
        self.plot = Envelope(n_ticks)
        self.t0: float | None = None

    def add(self, rb: RecordedBatch, pb: ReplayBatch) -> None:
        """Add one batch."""
        a, b = rb.command, pb.velocity
        m = a.size
        if m == 0:
            return
        ok = np.isfinite(a) & np.isfinite(b)
        dv = b[ok] - a[ok]
        self.sums['a'] += float(np.sum(a[ok] ** 2))
        self.sums['b'] += float(np.sum(b[ok] ** 2))
        self.sums['d'] += float(np.sum(dv * dv))
        self.sums['count'] += int(dv.size)
        if dv.size:
            self.dmax = max(self.dmax, float(np.max(np.abs(dv))))
        zeros = np.zeros(m)
        for who, flags, state in (
                ('recorded', rb.status.get('limit_flags', zeros), rb.status.get('state', zeros)),
                ('whatif', pb.internals.get('limit_flags', zeros),
                 pb.internals.get('state', zeros))):
            f = np.nan_to_num(np.asarray(flags, dtype=float)).astype(np.int64)
            self.limits[who][0] += int(np.count_nonzero(f & LIMIT_VELOCITY))
            self.limits[who][1] += int(np.count_nonzero(f & LIMIT_ACCELERATION))
            s = np.nan_to_num(np.asarray(state, dtype=float), nan=-1).astype(int)
            s = s[(s >= 0) & (s < len(STATE_NAMES))]
            self.states[who] += np.bincount(s, minlength=len(STATE_NAMES))
        for key in _WHATIF_INTERNALS:
            if key in rb.status and key in pb.internals:
                x = np.asarray(rb.status[key], dtype=float) - pb.internals[key]
                x = x[np.isfinite(x)]
                cur = self.internals_diff.get(key, 0.0)
                self.internals_diff[key] = max(cur, float(np.max(np.abs(x))) if x.size else 0.0)
        t = np.asarray(rb.inputs['t_s'], dtype=float)
        if self.t0 is None:
            self.t0 = float(t[0])
        dist = 'disturbance_term_mm_s'
        nan = np.full(m, np.nan)
        self.plot.add({'t_s': t - self.t0, 'recorded': a, 'whatif': b, 'difference': b - a,
                       'dist_recorded': rb.status.get(dist, nan),
                       'dist_whatif': pb.internals.get(dist, nan),
                       'state_recorded': rb.status.get('state', nan),
                       'state_whatif': pb.internals.get('state', nan)})
        self.n += m

    def table(self, rejected: list[str]) -> dict[str, Any]:
        """Side-by-side figures of the recorded and the what-if command (mm/s, ticks)."""
        c = self.sums['count']

        def rms(key: str) -> float:
            return math.sqrt(self.sums[key] / c) if c else math.nan

        def states(who: str) -> dict[str, float]:
            return {name: round(float(self.states[who][i]) * self.h_s, 6)
                    for i, name in enumerate(STATE_NAMES) if self.states[who][i]}

        return {
            'ticks': int(self.n),
            'command_rms_recorded_mm_s': rms('a'),
            'command_rms_whatif_mm_s': rms('b'),
            'command_rms_difference_mm_s': rms('d'),
            'command_max_difference_mm_s': self.dmax if c else math.nan,
            'limit_hits_recorded': dict(zip(('velocity', 'acceleration'),
                                            self.limits['recorded'], strict=True)),
            'limit_hits_whatif': dict(zip(('velocity', 'acceleration'),
                                          self.limits['whatif'], strict=True)),
            'state_time_s_recorded': states('recorded'),
            'state_time_s_whatif': states('whatif'),
            'internals_max_difference': dict(self.internals_diff),
            'rejected_commands': rejected,
            'open_loop': True,
            'note': OPEN_LOOP_NOTE,
        }


def whatif_table(rec: Recording, res: ReplayResult) -> dict[str, Any]:
    """Side-by-side figures of a whole recording and a whole what-if replay (:class:`WhatIf`)."""
    wi = WhatIf(rec.h_s, rec.ticks.size)
    wi.add(rec.whole(), res.whole())
    return wi.table(res.rejected)


def _plot(series: Mapping[str, np.ndarray], path: Path) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    t = series['t_s']
    fig, ax = plt.subplots(4, 1, figsize=(11, 10), sharex=True)
    ax[0].plot(t, series['recorded'], lw=0.8, label='recorded')
    ax[0].plot(t, series['whatif'], lw=0.8, alpha=0.8, label='what-if')
    ax[0].set_ylabel('command [mm/s]')
    ax[0].legend(loc='upper right')
    ax[0].set_title('replay what-if (open loop: the recorded inputs do not react)')
    ax[1].plot(t, series['difference'], lw=0.8, color='C3')
    ax[1].set_ylabel('what-if − recorded [mm/s]')
    if np.isfinite(series['dist_recorded']).any():
        ax[2].plot(t, series['dist_recorded'], lw=0.8, label='recorded')
        ax[2].plot(t, series['dist_whatif'], lw=0.8, alpha=0.8, label='what-if')
        ax[2].legend(loc='upper right')
    ax[2].set_ylabel('ESO disturbance\nterm −z/b0 [mm/s]')
    if np.isfinite(series['state_recorded']).any():
        ax[3].step(t, series['state_recorded'], where='post', lw=0.8, label='recorded')
        ax[3].step(t, series['state_whatif'], where='post', lw=0.8, alpha=0.8,
                   label='what-if')
        ax[3].set_yticks(range(len(STATE_NAMES)), STATE_NAMES)
        ax[3].legend(loc='upper right')
    ax[3].set_ylabel('state')
    ax[3].set_xlabel('t [s] from the first recorded tick')
    for a in ax:
        a.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _markdown(table: Mapping[str, Any], bag: Path, params_source: str) -> str:
    def f(v: Any) -> str:
        return f'{v:.6g}' if isinstance(v, float) else str(v)

    lh_r, lh_w = table['limit_hits_recorded'], table['limit_hits_whatif']
    rows = [
        ('command RMS [mm/s]', table['command_rms_recorded_mm_s'],
         table['command_rms_whatif_mm_s']),
        ('velocity limit hits [ticks]', lh_r['velocity'], lh_w['velocity']),
        ('acceleration limit hits [ticks]', lh_r['acceleration'], lh_w['acceleration']),
    ]
    lines = [f'# Replay what-if: `{bag}`', '',
             f'Parameters: {params_source}. **{OPEN_LOOP_NOTE}.**', '',
             '| | recorded | what-if |', '| --- | --- | --- |']
    lines += [f'| {name} | {f(a)} | {f(b)} |' for name, a, b in rows]
    lines += ['', f'Command difference (what-if − recorded): RMS '
              f'{f(table["command_rms_difference_mm_s"])} mm/s, max |·| '
              f'{f(table["command_max_difference_mm_s"])} mm/s over {table["ticks"]} ticks.',
              '', '| state | recorded [s] | what-if [s] |', '| --- | --- | --- |']
    names = list(dict.fromkeys([*table['state_time_s_recorded'],
                                *table['state_time_s_whatif']]))
    lines += [f'| {s} | {f(table["state_time_s_recorded"].get(s, 0.0))} | '
              f'{f(table["state_time_s_whatif"].get(s, 0.0))} |' for s in names]
    if table['rejected_commands']:
        lines += ['', 'Commands the what-if controller refused:', '']
        lines += [f'- {r}' for r in table['rejected_commands']]
    lines += ['', '![what-if](whatif.png)', '']
    return '\n'.join(lines)


def write_whatif(bag: Path, table: Mapping[str, Any], plot: Mapping[str, np.ndarray],
                 params: ControllerParams, params_source: str, out_dir: str | Path) -> Path:
    """Write ``whatif.png``, ``whatif.md``, ``whatif.json`` and ``params.yaml`` to ``out_dir``.

    ``table`` and ``plot`` come from :class:`WhatIf` (``table()``, ``plot.result()``). Built
    under a temporary name and renamed when complete; an existing ``out_dir`` is refused
    (:class:`ReplayError`).
    """
    from .report import strict_json

    out = Path(out_dir)
    if out.exists():
        raise ReplayError(f'{out} exists already: outputs are never overwritten')
    with building(out) as tmp:
        _plot(plot, tmp / 'whatif.png')
        (tmp / 'whatif.md').write_text(_markdown(table, bag, params_source), encoding='utf-8')
        (tmp / 'whatif.json').write_text(json.dumps(strict_json(
            {'bag': str(bag), 'params_source': params_source, **table}), indent=1),
            encoding='utf-8')
        (tmp / 'params.yaml').write_text(dump_params(params), encoding='utf-8')
    return out


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
