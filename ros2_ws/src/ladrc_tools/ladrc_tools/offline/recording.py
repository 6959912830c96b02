"""A bag as replay reads it: the recorded per-tick inputs, commands and events, streamed.

Every ``follow/status`` message holds the exact inputs the controller used that tick
(docs/interfaces.md), ``axis/velocity_command`` what it sent, and ``follow/events`` every follow
command and parameter set with the tick at whose start it took effect. :func:`open_recording`
reads them in batches of :data:`CHUNK_TICKS` ticks (a bag of hours never whole in memory) and
:func:`event_command` maps a recorded event back to the command that re-issues it (the
contract's codec, ``ladrc_contract.events``). Pure Python + numpy (no rclpy).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import math
from pathlib import Path
from typing import Any, Callable, Iterator

from ladrc_bags import Bag, BagError, open_bag, read_first_text
from ladrc_contract.codes import EventKind, FollowState
from ladrc_contract.events import COMMAND_KIND
from ladrc_contract.events import decode as decode_event
from ladrc_follow import INTERNALS_KEYS, ControllerParams, ParameterError, params_from_dict
import numpy as np
import yaml

# ladrc_msgs/FollowEvent kinds -> follow command names (the contract's codec), and the sets
KIND_NAMES = {**{int(k): name for name, k in COMMAND_KIND.items()},
              int(EventKind.PARAMETERS): 'parameters'}
PARAMETERS = int(EventKind.PARAMETERS)


STATE_NAMES = tuple(s.name for s in FollowState)


# The TickInput fields, as recorded in FollowStatus (same names).
INPUT_FIELDS = ('t_s', 'gap_mm', 'gap_valid', 'gap_stamp_s', 'encoder_mm', 'encoder_stamp_s',
                'drive_enabled', 'drive_fault', 'gap_status')


# The CNC motion values a tick used (FollowStatus revision 2; ladrc_contract.tick.CncInput in
# field order). Bags from before it lack them: replayed without a CNC, as they ran.
CNC_FIELDS = ('cnc_seq', 'cnc_stamp_s', 'cnc_segment', 'cnc_beam_on', 'cnc_contour',
              'cnc_commanded_feed_mm_s', 'cnc_actual_feed_mm_s', 'cnc_segment_left_mm',
              'cnc_edge_ahead_mm')


# Internals compared / plotted (velocity_mm_s is the command itself, fault_reason a string).
COMPARED_INTERNALS = tuple(k for k in INTERNALS_KEYS if k not in ('velocity_mm_s',
                                                                   'fault_reason'))


# The follow/status fields replay reads (a long bag is read into these columns only).
REPLAY_FIELDS = ('tick', 'velocity_mm_s') + INPUT_FIELDS + tuple(
    k for k in COMPARED_INTERNALS if k not in INPUT_FIELDS) + CNC_FIELDS


CHUNK_TICKS = 65536
"""Ticks stepped per batch: Python lists and internals rows exist for one batch at a time."""


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
        params_text = read_first_text(bag, 'run/parameters')
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
