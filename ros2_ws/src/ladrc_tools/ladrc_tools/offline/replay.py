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

from dataclasses import dataclass, field
import math
import os
from pathlib import Path
import shutil
import time
from typing import Any, Callable, Iterable, Mapping

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

__all__ = [
    'ReplayError', 'Recording', 'RecordedEvent', 'ReplayResult', 'load_recording',
    'event_command', 'replay', 'compare', 'parse_set', 'whatif_params', 'whatif_table',
    'write_whatif', 'OPEN_LOOP_NOTE', 'KIND_NAMES',
]

# ladrc_msgs/FollowEvent kinds -> follow command names (follow_node.py's services).
KIND_NAMES = {1: 'start_follow', 2: 'stop_follow', 3: 'set_target', 4: 'machining',
              5: 'height_compensation', 6: 'gradient_follow', 7: 'reset_fault',
              8: 'parameters'}
PARAMETERS = 8
STATE_NAMES = ('IDLE', 'LOCKING', 'PREINTERPOLATE', 'PID', 'LADRC', 'FAULT')
LIMIT_VELOCITY, LIMIT_ACCELERATION = 1, 2

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
class Recording:
    """What a bag holds for replay: the per-tick inputs, the commands sent and the events."""

    path: Path
    ticks: np.ndarray                    # follow/status tick, in bag order
    inputs: dict[str, np.ndarray]        # INPUT_FIELDS -> per-status-message values
    status: dict[str, np.ndarray]        # every follow/status column (recorded internals)
    command: np.ndarray                  # recorded velocity sent for each status tick
    command_enable: np.ndarray           # recorded enable bit (False where missing)
    command_present: np.ndarray          # an axis/velocity_command with seq == tick exists
    events: list[RecordedEvent]          # follow/events in effect order (tick, bag order)
    params: ControllerParams             # the set in force at the first status tick
    params_source: str
    mode: str | None                     # headless runs' --controller override
    source: str                          # custom_data ladrc.source ('recorder', 'headless')
    notes: list[str] = field(default_factory=list)

    @property
    def h_s(self) -> float:
        """Controller period of the recording [s]."""
        return self.params.h_s


@dataclass
class ReplayResult:
    """One replay: the commands sent per status tick, enable bits and (optional) internals."""

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


def _state_name(state: int) -> str:
    return STATE_NAMES[state] if 0 <= state < len(STATE_NAMES) else str(state)


# ---- reading ----------------------------------------------------------------------------------
def _parse_params(text: str, what: str) -> ControllerParams:
    try:
        data = yaml.safe_load(text)
        return params_from_dict(data)
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


def load_recording(path: str | Path,
                   progress: Callable[[int, int], None] | None = None) -> Recording:
    """Read what :func:`replay` needs from a bag; :class:`BagError` (one line) if unusable."""
    with open_bag(path) as bag:
        bag.require('follow/status')
        st = bag.columns('follow/status', REPLAY_FIELDS, progress=progress)
        if st['tick'].size == 0:
            raise BagError(f'{bag.path}: follow/status holds no message: nothing to replay')
        notes: list[str] = []
        ticks = st['tick'].astype(np.int64)
        inputs: dict[str, np.ndarray] = {}
        for name in INPUT_FIELDS:
            if name in st:
                inputs[name] = st[name]
            elif name == 'gap_status':
                # bags from before FollowStatus.gap_status: 0 = "not reported" (TickInput doc)
                inputs[name] = np.zeros(ticks.size, dtype=np.uint8)
                notes.append('follow/status has no gap_status: replayed as 0 (not reported)')
            else:
                raise BagError(f'{bag.path}: follow/status has no {name!r} field: not a '
                               'ladrc_msgs/FollowStatus with the inputs of each tick')
        if bag.has('axis/velocity_command'):
            cmd = bag.columns('axis/velocity_command', ['seq', 'velocity_mm_s', 'enable'])
        else:
            cmd = {'seq': np.zeros(0, np.int64), 'velocity_mm_s': np.zeros(0),
                   'enable': np.zeros(0, bool)}
            notes.append('no axis/velocity_command topic: compared with '
                         'follow/status.velocity_mm_s')
        command = np.asarray(st['velocity_mm_s'], dtype=np.float64).copy()
        enable = np.zeros(ticks.size, dtype=bool)
        present = np.zeros(ticks.size, dtype=bool)
        seq = np.asarray(cmd['seq'], dtype=np.int64)
        if seq.size:
            # the command of each status tick (seq == tick); the last duplicate seq wins
            order = np.argsort(seq, kind='stable')
            s_sorted = seq[order]
            pos = np.searchsorted(s_sorted, ticks, side='right') - 1
            ok = (pos >= 0) & (s_sorted[np.maximum(pos, 0)] == ticks)
            idx = order[pos[ok]]
            command[ok] = np.asarray(cmd['velocity_mm_s'], dtype=np.float64)[idx]
            enable[ok] = np.asarray(cmd['enable'], dtype=bool)[idx]
            present = ok
        events = _read_events(bag)
        params_text = _first_text(bag, 'run/parameters')
        custom = bag.custom_data
        bag_path = bag.path

    first = int(ticks[0])
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
        state0 = int(st['state'][0]) if 'state' in st else 0
        notes.append(f'the bag starts at tick {first} in state {_state_name(state0)}: replay '
                     'starts from a fresh controller, exact only if it was IDLE and had not '
                     'followed before')
    mode = custom.get('ladrc.controller')
    return Recording(path=Path(bag_path), ticks=ticks, inputs=inputs, status=st,
                     command=command, command_enable=enable, command_present=present,
                     events=[e for e in events if e.tick >= first], params=params,
                     params_source=source, mode=mode if mode in ('ladrc', 'pid') else None,
                     source=str(custom.get('ladrc.source', '')), notes=notes)


# ---- events -> controller ---------------------------------------------------------------------
def event_command(ev: RecordedEvent) -> tuple[str, dict[str, Any]]:
    """Return ``(command name, kwargs)`` that re-issue ``ev`` exactly as follow_node did."""
    k = ev.kind
    if k == 1:
        return 'start_follow', {'target_gap_mm': ev.value_mm}
    if k == 2:
        return 'stop_follow', {}
    if k == 3:
        return 'set_target', {'target_gap_mm': ev.value_mm}
    if k == 4:
        return 'machining', {'on': ev.flag}
    if k == 5:
        return 'height_compensation', {'offset_mm': ev.value_mm, 'delay_s': ev.delay_s}
    if k == 6:
        return 'gradient_follow', {'target_gap_mm': ev.value_mm, 'delay_s': ev.delay_s,
                                   'velocity_mm_s': ev.velocity_mm_s,
                                   'accel_mm_s2': ev.accel_mm_s2}
    if k == 7:
        return 'reset_fault', {}
    raise ValueError(f'follow/events kind {k} is not a follow command')


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
        return params_from_dict(flat)
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
def replay(rec: Recording, params: ControllerParams | None = None, *,
           overrides: Mapping[str, Any] | None = None, mode: str | None = None,
           record_internals: bool = True, params_source: str | None = None,
           progress: Callable[[int, int], None] | None = None) -> ReplayResult:
    """Step a fresh controller over ``rec``'s inputs, re-applying its events at their ticks.

    ``params=None`` replays with the bag's own set (every recorded PARAMETERS event applied
    as recorded). A what-if set (``params``, ``overrides``) starts the run instead; a later
    recorded parameter change is then applied as its *change* (the keys that differ from the
    previous recorded set) on top of the running what-if set, with ``overrides`` kept on top.
    ``mode`` ('ladrc' | 'pid') overrides the bag's headless ``--controller``.
    """
    own = params is None and not overrides
    start = rec.params if params is None else params
    if overrides:
        start = _with(start, overrides, '--set')
    pins = dict(overrides or {})
    ctl = FollowController(start, mode=mode or rec.mode)
    n = rec.ticks.size
    events = rec.events
    n_ev = len(events)
    j = 0
    recorded_set = rec.params
    rejected: list[str] = []
    notes: list[str] = []
    out_v = np.zeros(n, dtype=np.float64)
    out_en = np.zeros(n, dtype=bool)
    int_parts: dict[str, list[np.ndarray]] = {k: [] for k in COMPARED_INTERNALS}
    new_tick = tuple.__new__
    step = ctl.step
    internals = ctl.internals
    wall0 = time.perf_counter()
    for c0 in range(0, n, CHUNK_TICKS):
        c1 = min(n, c0 + CHUNK_TICKS)
        # plain Python values for one batch (the per-tick path is scalar code)
        ticks = rec.ticks[c0:c1].tolist()
        t_l, gap_l, valid_l, gst_l, enc_l, est_l, den_l, dfl_l, stat_l = (
            rec.inputs[f][c0:c1].tolist() for f in INPUT_FIELDS)
        valid_l = [bool(v) for v in valid_l]
        den_l = [bool(v) for v in den_l]
        dfl_l = [bool(v) for v in dfl_l]
        stat_l = [int(v) for v in stat_l]
        chunk_v = [0.0] * (c1 - c0)
        chunk_en = [False] * (c1 - c0)
        rows: list[dict] | None = [] if record_internals else None
        for i in range(c1 - c0):
            k = ticks[i]
            # events due at or before this tick (also those of ticks missing in the bag)
            while j < n_ev and events[j].tick <= k:
                ev = events[j]
                j += 1
                if ev.kind == PARAMETERS:
                    try:
                        new_set = params_from_dict(yaml.safe_load(ev.text))
                    except (yaml.YAMLError, ParameterError) as exc:
                        notes.append(f'tick {ev.tick}: recorded parameter set unusable '
                                     f'({" ".join(str(exc).split())[:120]}); not applied')
                        continue
                    if own:
                        target = new_set
                    else:
                        change = _delta(recorded_set, new_set)
                        change.update(pins)
                        try:
                            target = _with(ctl.params, change,
                                           f'tick {ev.tick} parameter change')
                        except ReplayError as exc:
                            notes.append(f'{exc}; not applied')
                            recorded_set = new_set
                            continue
                    recorded_set = new_set
                    try:
                        ctl.set_params(target)
                    except ValueError as exc:
                        notes.append(f'tick {ev.tick}: parameter set refused '
                                     f'({" ".join(str(exc).split())[:120]})')
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
                chunk_v[i] = u
                chunk_en[i] = True
            if rows is not None:
                rows.append(internals())
        out_v[c0:c1] = chunk_v
        out_en[c0:c1] = chunk_en
        if progress is not None:
            progress(c1, n)
        if rows is not None:
            for key in COMPARED_INTERNALS:
                int_parts[key].append(np.fromiter((r[key] for r in rows), dtype=float,
                                                  count=len(rows)))
    if j < n_ev:
        notes.append(f'{n_ev - j} event(s) after the last recorded tick not applied')
    int_arrays = {}
    if record_internals:
        for k in list(int_parts):  # column by column: the batches are released as joined
            v = int_parts.pop(k)
            int_arrays[k] = np.concatenate(v) if v else np.zeros(0)
    wall = time.perf_counter() - wall0
    src = params_source or (rec.params_source if own else 'what-if')
    return ReplayResult(velocity=out_v, enable=out_en, internals=int_arrays,
                        params=start, params_source=src, rejected=rejected, notes=notes,
                        wall_s=wall)


# ---- comparison -------------------------------------------------------------------------------
def _bits_differ(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (np.ascontiguousarray(a, dtype=np.float64).view(np.uint64)
            != np.ascontiguousarray(b, dtype=np.float64).view(np.uint64))


def compare(rec: Recording, res: ReplayResult) -> dict[str, Any]:
    """Compare a replay with the recording, bit for bit; return the summary dict.

    ``mismatches`` counts ticks whose sent velocity differs in its float64 bit pattern, up to
    the first break in the status ticks (a missing tick breaks exact replay after it: the
    controller cannot be stepped over inputs the bag does not hold); ticks after the break are
    counted in ``mismatches_after_gap``. ``enable_mismatches`` compares the drive enable bit
    (live bags only: headless bags derive it from the state). ``internal_mismatch_ticks``
    counts ticks where a recorded status internal (ESO states, terms, state, ...) differs.
    """
    ticks = rec.ticks
    n = ticks.size
    d = np.diff(ticks)
    breaks = np.flatnonzero(d != 1)
    missing = int(np.sum(d[d > 1] - 1)) if d.size else 0
    exact_end = int(breaks[0]) + 1 if breaks.size else n  # status index of the first break
    diff = _bits_differ(rec.command, res.velocity)
    mism_idx = np.flatnonzero(diff[:exact_end])
    after = int(np.count_nonzero(diff[exact_end:]))
    live = rec.source != 'headless'
    en_diff = (rec.command_enable != res.enable) & rec.command_present
    enable_mism = int(np.count_nonzero(en_diff[:exact_end])) if live else None
    int_ticks = 0
    first_int: dict[str, Any] | None = None
    int_fields: dict[str, int] = {}
    if res.internals:
        any_diff = np.zeros(n, dtype=bool)
        for key, mine in res.internals.items():
            if key not in rec.status:
                continue
            recd = np.asarray(rec.status[key], dtype=np.float64)
            both_nan = np.isnan(recd) & np.isnan(mine)
            dk = _bits_differ(recd, mine) & ~both_nan
            dk[exact_end:] = False
            c = int(np.count_nonzero(dk))
            if c:
                int_fields[key] = c
                any_diff |= dk
        int_ticks = int(np.count_nonzero(any_diff))
        if int_ticks:
            i0 = int(np.argmax(any_diff))
            first_int = {'tick': int(ticks[i0]), 'fields': {
                k: [float(rec.status[k][i0]), float(res.internals[k][i0])]
                for k in int_fields if _bits_differ(
                    np.asarray(rec.status[k][i0:i0 + 1], dtype=np.float64),
                    res.internals[k][i0:i0 + 1])[0]
                and not (math.isnan(rec.status[k][i0]) and math.isnan(res.internals[k][i0]))}}
    first = int(ticks[mism_idx[0]]) if mism_idx.size else None
    out: dict[str, Any] = {
        'ticks': int(n),
        'mismatches': int(mism_idx.size),
        'first_mismatch_tick': first,
        'missing_ticks': missing,
        'params_source': res.params_source,
        'start_tick': int(ticks[0]),
        'end_tick': int(ticks[-1]),
        'exact_until_tick': int(ticks[exact_end - 1]),
        'mismatches_after_gap': after,
        'commands_missing': int(n - np.count_nonzero(rec.command_present)),
        'enable_mismatches': enable_mism,
        'internal_mismatch_ticks': int_ticks,
        'internal_mismatch_fields': int_fields,
        'first_internal_mismatch': first_int,
        'rejected_commands': len(res.rejected),
        'replay_s': res.wall_s,
        'ticks_per_s': res.ticks_per_s,
    }
    if first is not None:
        i0 = int(mism_idx[0])
        out['first_mismatch'] = {'recorded_mm_s': float(rec.command[i0]),
                                 'replayed_mm_s': float(res.velocity[i0])}
    return out


# ---- what-if comparison -----------------------------------------------------------------------
def _limit_hits(flags: np.ndarray) -> dict[str, int]:
    f = np.nan_to_num(np.asarray(flags, dtype=float)).astype(np.int64)
    return {'velocity': int(np.count_nonzero(f & LIMIT_VELOCITY)),
            'acceleration': int(np.count_nonzero(f & LIMIT_ACCELERATION))}


def whatif_table(rec: Recording, res: ReplayResult) -> dict[str, Any]:
    """Side-by-side figures of the recorded and the what-if command (mm/s, ticks)."""
    a, b = rec.command, res.velocity
    ok = np.isfinite(a) & np.isfinite(b)
    dv = b[ok] - a[ok]
    rec_flags = rec.status.get('limit_flags', np.zeros(a.size))
    new_flags = res.internals.get('limit_flags', np.zeros(b.size))
    h = rec.h_s

    def rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x * x))) if x.size else math.nan

    def states(s: np.ndarray) -> dict[str, float]:
        s = np.nan_to_num(np.asarray(s, dtype=float), nan=-1).astype(int)
        return {name: round(float(np.count_nonzero(s == i)) * h, 6)
                for i, name in enumerate(STATE_NAMES) if np.any(s == i)}

    internals_diff = {}
    for key in ('disturbance_term_mm_s', 'eso_z1_mm', 'eso_z2', 'eso_z3', 'td_x1_mm',
                'u0_mm_s', 'p_term_mm_s', 'd_term_mm_s'):
        if key in rec.status and key in res.internals:
            x = np.asarray(rec.status[key], dtype=float) - res.internals[key]
            x = x[np.isfinite(x)]
            internals_diff[key] = float(np.max(np.abs(x))) if x.size else 0.0
    return {
        'ticks': int(a.size),
        'command_rms_recorded_mm_s': rms(a[ok]),
        'command_rms_whatif_mm_s': rms(b[ok]),
        'command_rms_difference_mm_s': rms(dv),
        'command_max_difference_mm_s': float(np.max(np.abs(dv))) if dv.size else math.nan,
        'limit_hits_recorded': _limit_hits(rec_flags),
        'limit_hits_whatif': _limit_hits(new_flags),
        'state_time_s_recorded': states(rec.status.get('state', np.zeros(a.size))),
        'state_time_s_whatif': states(res.internals.get('state', np.zeros(b.size))),
        'internals_max_difference': internals_diff,
        'rejected_commands': res.rejected,
        'open_loop': True,
        'note': OPEN_LOOP_NOTE,
    }


def _plot(rec: Recording, res: ReplayResult, path: Path) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    t = np.asarray(rec.inputs['t_s'], dtype=float)
    t = t - t[0]
    st = rec.status
    fig, ax = plt.subplots(4, 1, figsize=(11, 10), sharex=True)
    ax[0].plot(t, rec.command, lw=0.8, label='recorded')
    ax[0].plot(t, res.velocity, lw=0.8, alpha=0.8, label='what-if')
    ax[0].set_ylabel('command [mm/s]')
    ax[0].legend(loc='upper right')
    ax[0].set_title('replay what-if (open loop: the recorded inputs do not react)')
    ax[1].plot(t, res.velocity - rec.command, lw=0.8, color='C3')
    ax[1].set_ylabel('what-if − recorded [mm/s]')
    key = 'disturbance_term_mm_s'
    if key in st and key in res.internals:
        ax[2].plot(t, st[key], lw=0.8, label='recorded')
        ax[2].plot(t, res.internals[key], lw=0.8, alpha=0.8, label='what-if')
        ax[2].legend(loc='upper right')
    ax[2].set_ylabel('ESO disturbance\nterm −z/b0 [mm/s]')
    if 'state' in st and 'state' in res.internals:
        ax[3].step(t, st['state'], where='post', lw=0.8, label='recorded')
        ax[3].step(t, res.internals['state'], where='post', lw=0.8, alpha=0.8, label='what-if')
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


def write_whatif(rec: Recording, res: ReplayResult, out_dir: str | Path) -> Path:
    """Write ``whatif.png``, ``whatif.md``, ``whatif.json`` and ``params.yaml`` to ``out_dir``.

    Built under a temporary name and renamed when complete; an existing ``out_dir`` is
    refused (:class:`ReplayError`).
    """
    import json

    from .report import strict_json

    out = Path(out_dir)
    if out.exists():
        raise ReplayError(f'{out} exists already: outputs are never overwritten')
    tmp = out.with_name(f'.{out.name}.partial')
    shutil.rmtree(tmp, ignore_errors=True)
    table = whatif_table(rec, res)
    try:
        tmp.mkdir(parents=True)
        _plot(rec, res, tmp / 'whatif.png')
        (tmp / 'whatif.md').write_text(_markdown(table, rec.path, res.params_source),
                                       encoding='utf-8')
        (tmp / 'whatif.json').write_text(json.dumps(strict_json(
            {'bag': str(rec.path), 'params_source': res.params_source, **table}), indent=1),
            encoding='utf-8')
        (tmp / 'params.yaml').write_text(dump_params(res.params), encoding='utf-8')
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
