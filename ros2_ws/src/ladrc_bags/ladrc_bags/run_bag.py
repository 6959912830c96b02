"""A headless run as a bag: the same topics and layout as a live run of the node set.

``ladrc simulate -o`` and the suite write the runner's result (``ladrc_sim.headless``) as the
recorder would have recorded the sim node and the follow node: capacitive height, feedback,
commands, status, truth and the follow events (``ladrc_contract.events``), so replay, report
and the lock-step equality test read both alike.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import os
from pathlib import Path
import shutil
from typing import Any, Mapping, Sequence

from ladrc_contract.codes import EventKind, FollowState, GapStatus
from ladrc_contract.events import COMMAND_KIND, EventFields, encode
import numpy as np

from .errors import BagError
from .provenance import PARAMS_KEY, VERSION_KEY, param_hash, software_version
from .rows import RowPacker
from .typestore import ladrc_typestore
from .writer import BagWriter, string_msg

# ---- headless runs ----------------------------------------------------------------------
FRAME_ID = 'z_axis'  # the sim node's frame_id (its parameter's default)

COMMANDER = '/ladrc_follow'  # the follow node's fully qualified name (VelocityCommand.commander)


def _fresh(n: int, h_s: float, spans: list[tuple[float, float]]) -> np.ndarray:
    """Return True on ticks with a new sample (the runner holds samples in dropouts)."""
    fresh = np.ones(n, dtype=bool)
    for t_s, dur in spans:
        i0 = int(round(t_s / h_s))
        fresh[i0:i0 + max(1, int(round(dur / h_s)))] = False
    return fresh


def _drive_schedule(n: int, h_s: float, timeline: Sequence[Any]) -> tuple[np.ndarray, ...]:
    enabled = np.ones(n, dtype=bool)
    fault = np.zeros(n, dtype=bool)
    for e in sorted((e for e in timeline if e.name == 'drive'), key=lambda e: e.t_s):
        i = min(n - 1, int(round(e.t_s / h_s)))
        enabled[i:] = bool(e.args.get('enabled', True))
        fault[i:] = bool(e.args.get('fault', False))
    return enabled, fault


def _last_seq(fresh: np.ndarray) -> np.ndarray:
    """Seq (0-based count of fresh samples) of the sample held at each tick."""
    return np.maximum(np.cumsum(fresh) - 1, 0).astype(np.uint64)


def _pack_by_text(packer: RowPacker, n: int, cols: Mapping[str, Any],
                  texts: Mapping[str, Any]) -> list[bytes]:
    """Pack ``n`` rows whose string fields ``texts[key][i]`` vary (one packer per set of texts).

    ``texts``: string field -> its per-row values (None: the field is not there).
    """
    rows = packer.pack(n, cols)
    given = {k: v.tolist() if isinstance(v, np.ndarray) else list(v)
             for k, v in texts.items() if v is not None}
    if not given:
        return rows
    keys = list(given)
    groups: dict[tuple, list[int]] = {}
    for i, combo in enumerate(zip(*given.values(), strict=True)):
        if any(c not in ('', None) for c in combo):
            groups.setdefault(combo, []).append(i)
    for combo, where in groups.items():
        idx = np.asarray(where)
        sub = {k: (v[idx] if isinstance(v, np.ndarray) and v.shape == (n,) else v)
               for k, v in cols.items()}
        strings = {k: v.decode('utf-8') for k, v in packer.texts.items()}
        strings.update({k: '' if c is None else str(c) for k, c in zip(keys, combo,
                                                                        strict=True)})
        for i, row in zip(where, RowPacker(packer.msgtype, packer.store,
                                           strings).pack(idx.size, sub), strict=True):
            rows[i] = row
    return rows


@dataclass
class _Series:
    """A run's per-tick columns, as the node set would have published them."""

    t: np.ndarray
    h_s: float
    internals: dict[str, np.ndarray]
    timeline: list
    gap_fresh: np.ndarray
    enc_fresh: np.ndarray
    gap_seq: np.ndarray
    enc_seq: np.ndarray
    gap_stamp: np.ndarray
    enc_stamp: np.ndarray
    enabled: np.ndarray
    fault: np.ndarray
    reading: np.ndarray
    valid: np.ndarray
    collision: np.ndarray
    encoder: np.ndarray
    command: np.ndarray
    target: np.ndarray
    status_code: np.ndarray

    @property
    def n(self) -> int:
        return self.t.size

    @property
    def ticks(self) -> np.ndarray:
        return np.arange(self.n, dtype=np.uint64)


def _series(result: Any) -> _Series:
    h_s = float(result.h_s)
    t = np.asarray(result.t_s, dtype=float)
    n = t.size
    timeline = list(getattr(result.scenario, 'timeline', ()))
    gap_fresh = _fresh(n, h_s, [(e.t_s, e.args['duration_s']) for e in timeline
                                if e.name == 'sensor_dropout'])
    enc_fresh = _fresh(n, h_s, [(e.t_s, e.args['duration_s']) for e in timeline
                                if e.name == 'encoder_dropout'])
    enabled, fault = _drive_schedule(n, h_s, timeline)
    valid = np.asarray(result.reading_valid, dtype=bool)
    collision = np.asarray(result.collision, dtype=bool)
    return _Series(
        t=t, h_s=h_s, timeline=timeline,
        internals={k: np.asarray(v) for k, v in (result.internals or {}).items()},
        gap_fresh=gap_fresh, enc_fresh=enc_fresh,
        gap_seq=_last_seq(gap_fresh), enc_seq=_last_seq(enc_fresh),
        # sample time of the held sample: the time of the last fresh tick
        gap_stamp=t[np.maximum.accumulate(np.where(gap_fresh, np.arange(n), 0))],
        enc_stamp=t[np.maximum.accumulate(np.where(enc_fresh, np.arange(n), 0))],
        enabled=enabled, fault=fault,
        reading=np.asarray(result.reading_mm, dtype=float), valid=valid, collision=collision,
        encoder=np.asarray(result.encoder_mm, dtype=float),
        command=np.asarray(result.command_mm_s, dtype=float),
        target=np.asarray(result.target_gap_mm, dtype=float),
        status_code=np.where(valid, GapStatus.OK,
                             np.where(collision, GapStatus.COLLISION, GapStatus.OUT_OF_RANGE)))


def _sample_rows(s: _Series, result: Any, store: Any) -> tuple[list[bytes], list[bytes]]:
    """Pack the capacitive height and the axis feedback of every tick, as the sim sends."""
    frame = {'header.frame_id': FRAME_ID}
    # the raw value behind each reading, as the sim node sends it (models/sensor.py)
    raw_hz = result.raw_hz() if callable(getattr(result, 'raw_hz', None)) else np.nan
    cap_rows = RowPacker('ladrc_msgs/msg/CapacitiveHeight', store, frame).pack(s.n, {
        'stamp_s': s.t, 'seq': s.gap_seq, 'gap_mm': s.reading,
        'raw_hz': raw_hz, 'valid': s.valid, 'status': s.status_code})
    enc_vel = np.diff(s.encoder, prepend=s.encoder[:1]) / s.h_s  # what a driver differentiates
    fb_rows = _pack_by_text(
        RowPacker('ladrc_msgs/msg/AxisFeedback', store, frame), s.n, {
            'stamp_s': s.t, 'seq': s.enc_seq, 'position_mm': s.encoder,
            'velocity_mm_s': np.nan_to_num(enc_vel), 'drive_enabled': s.enabled,
            'drive_fault': s.fault},
        {'fault_reason': np.where(s.fault, result.drive_fault_reason, '')})
    return cap_rows, fb_rows


def _command_rows(s: _Series, store: Any) -> list[bytes]:
    """Pack the commands; ``enable`` as the controller says it, or from its state."""
    state = s.internals.get('state')
    if 'command_enable' in s.internals:  # a controller that says it (the excitation player)
        enable = np.nan_to_num(s.internals['command_enable']).astype(bool)
    elif state is not None:
        # FollowController.enable: approaching or following, or a command not yet zero
        # (a retract, a ramp down)
        state = np.nan_to_num(state).astype(np.uint8)
        enable = (((state >= FollowState.PREINTERPOLATE) & (state <= FollowState.LADRC))
                  | (s.command != 0.0))
    else:
        enable = np.isfinite(s.target)
    # the runner's convention is lock step's: command k answers step k (docs/follow-node.md)
    return RowPacker('ladrc_msgs/msg/VelocityCommand', store, {'commander': COMMANDER}).pack(
        s.n, {'stamp_s': s.t, 'seq': s.ticks, 'velocity_mm_s': s.command, 'enable': enable,
              'sample_seq': s.ticks})


def _status_rows(s: _Series, store: Any) -> list[bytes]:
    """Pack FollowStatus per tick: the inputs used, the internals, NaN for the rest."""
    packer = RowPacker('ladrc_msgs/msg/FollowStatus', store)
    t = s.t
    cols: dict[str, Any] = {
        'stamp_s': t, 'tick': s.ticks, 't_s': t, 'sample_seq': s.ticks,
        'feed_override_request': 1.0, 'target_gap_mm': s.target, 'gap_seq': s.gap_seq,
        'gap_mm': s.reading, 'gap_valid': s.valid, 'gap_status': s.status_code,
        'gap_stamp_s': s.gap_stamp, 'encoder_seq': s.enc_seq, 'encoder_mm': s.encoder,
        'encoder_stamp_s': s.enc_stamp, 'drive_enabled': s.enabled, 'drive_fault': s.fault,
        'velocity_mm_s': s.command, 'u_unlimited_mm_s': s.command, 'period_us': s.h_s * 1e6,
        'compute_us': np.nan,
        'input_age_us': (t - np.minimum(s.gap_stamp, s.enc_stamp)) * 1e6,
    }
    for f in packer.fields:
        if f.startswith('header.') or f in cols:
            continue
        if packer.dtype[f].kind == 'f':
            cols[f] = np.nan
    for key, values in s.internals.items():
        if key in packer.fields and not key.startswith('header.'):
            kind = packer.dtype[key].kind
            cols[key] = (values if kind == 'f'
                         else np.nan_to_num(values).astype(packer.dtype[key]))
    return _pack_by_text(packer, s.n, cols, {k: s.internals.get(k)
                                             for k in ('fault_reason', 'hold_reason')})


def _truth_rows(s: _Series, result: Any, store: Any) -> list[bytes]:
    plate_v = getattr(result, 'plate_velocity_mm_s', None)
    return RowPacker('ladrc_msgs/msg/SimTruth', store, {'header.frame_id': FRAME_ID}).pack(
        s.n, {'stamp_s': s.t, 'seq': s.ticks,
              'true_gap_mm': result.true_gap_mm, 'sheet_mm': result.sheet_mm,
              'nozzle_mm': result.nozzle_mm, 'edge_coverage': result.coverage,
              'plate_velocity_mm_s': np.nan if plate_v is None else plate_v,
              'collision': s.collision, 'x_mm': getattr(result, 'x_mm', np.nan),
              'y_mm': getattr(result, 'y_mm', np.nan)})  # XY: a job's run


def _event_rows(s: _Series, store: Any, params_yaml: str) -> list[tuple[int, bytes]]:
    """Return the events: PARAMETERS at tick 0, then the scenario's commands at their ticks.

    As the follow node logs them (``ladrc_contract.events``).
    """
    Event = store.types['ladrc_msgs/msg/FollowEvent']
    Header = store.types['std_msgs/msg/Header']
    Time = store.types['builtin_interfaces/msg/Time']

    def event(tick: int, f: EventFields) -> tuple[int, bytes]:
        sec, nsec = divmod(int(round(s.t[tick] * 1e9)), 1_000_000_000)
        msg = Event(header=Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=''),
                    tick=tick, kind=f.kind, value_mm=f.value_mm, delay_s=f.delay_s,
                    velocity_mm_s=f.velocity_mm_s, accel_mm_s2=f.accel_mm_s2, flag=f.flag,
                    text=f.text)
        return tick, bytes(store.serialize_cdr(msg, 'ladrc_msgs/msg/FollowEvent'))

    events = [event(0, EventFields(EventKind.PARAMETERS, text=params_yaml))] if params_yaml else []
    for e in s.timeline:
        if getattr(e, 'is_command', False) and e.name in COMMAND_KIND:
            events.append(event(min(s.n - 1, int(round(e.t_s / s.h_s))), encode(e.name, e.args)))
    events.sort(key=lambda x: x[0])
    return events


def write_run_bag(result: Any, path: str | Path, params_yaml: str = '',
                  scenario_yaml: str = '', *, storage: str = 'mcap',
                  controller: str = '', provenance: Mapping[str, str] | None = None,
                  truth: bool = True) -> Path:
    """Write a headless ``ladrc_sim.headless.runner.RunResult`` as a bag with a live run's layout.

    One message per tick on the 2 kHz topics (capacitive height and feedback only on ticks
    with a fresh sample, as a driver publishes nothing during a dropout), ``follow/events``
    from the scenario's commands at the runner's ticks (plus a PARAMETERS event at tick 0),
    ``run/parameters`` and ``run/scenario`` texts. Stamps and bag times are sim time. Status
    fields come from ``result.internals`` when the controller reports them under FollowStatus
    names, else from the run's series (floats the run does not know are NaN). The command's
    ``enable`` is ``internals['command_enable']`` when the controller reports it (the
    excitation player), else derived from the follow state. Written into a temporary folder
    and renamed, so ``path`` appears only complete. ``custom_data`` holds the software version
    and the parameter set's hash (:mod:`.provenance`), plus ``provenance`` (a generated fleet:
    machine id and wall-clock start). ``truth=False`` leaves ``sim/truth`` out (a fleet's bags:
    a real machine has none).
    """
    path = Path(path)
    if path.exists():
        raise BagError(f'{path} exists already: a bag is never overwritten')
    store = ladrc_typestore()
    s = _series(result)
    cap_rows, fb_rows = _sample_rows(s, result, store)
    rows = {'axis/capacitive_height': cap_rows, 'axis/feedback': fb_rows,
            'axis/velocity_command': _command_rows(s, store),
            'follow/status': _status_rows(s, store),
            'sim/truth': _truth_rows(s, result, store) if truth else None}
    events = _event_rows(s, store, params_yaml)
    tmp = path.with_name(f'.{path.name}.partial')
    if tmp.exists():
        shutil.rmtree(tmp)
    custom = {'ladrc.source': 'headless',
              'ladrc.scenario': str(getattr(result.scenario, 'name', ''))}
    if controller:
        custom['ladrc.controller'] = controller
    custom[VERSION_KEY] = software_version()
    if params_yaml:
        custom[PARAMS_KEY] = param_hash(params_yaml)
    custom.update(provenance or {})
    # no flush or metadata rewrite on the wall clock: the bag is renamed into place only when
    # complete, and chunks cut by size alone make the same run the same bytes however fast
    # the machine writes (a 0.25 s flush cut a loaded run's chunks elsewhere)
    writer = BagWriter(tmp, storage=storage, split_s=None, custom_data=custom, typestore=store,
                       name=path.name, flush_s=math.inf, metadata_s=math.inf)
    try:
        _write_ticks(writer, s, rows, events, store, params_yaml, scenario_yaml)
        writer.close()
        os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return path


def _write_ticks(writer: BagWriter, s: _Series, rows: dict[str, list[bytes]],
                 events: list[tuple[int, bytes]], store: Any, params_yaml: str,
                 scenario_yaml: str) -> None:
    """Write every message in the order a live recorder receives them within a tick."""
    for topic in ('axis/capacitive_height', 'axis/feedback', 'axis/velocity_command',
                  'follow/status', 'follow/events', 'sim/truth', 'run/parameters',
                  'run/scenario'):
        if rows.get(topic, True) is not None:
            writer.add_topic(topic)
    for topic, text in (('run/parameters', params_yaml), ('run/scenario', scenario_yaml)):
        writer.write(topic, 0, string_msg(text, store))
    ns = np.round(s.t * 1e9).astype(np.int64).tolist()
    w = writer.write_raw
    cap, fb, truth = rows['axis/capacitive_height'], rows['axis/feedback'], rows['sim/truth']
    status, cmd = rows['follow/status'], rows['axis/velocity_command']
    k = 0
    gap_fresh, enc_fresh = s.gap_fresh.tolist(), s.enc_fresh.tolist()
    for i in range(s.n):
        ts = ns[i]
        while k < len(events) and events[k][0] == i:
            w('follow/events', ts, events[k][1])
            k += 1
        if gap_fresh[i]:
            w('axis/capacitive_height', ts, cap[i])
        if truth is not None:
            w('sim/truth', ts, truth[i])
        if enc_fresh[i]:
            w('axis/feedback', ts, fb[i])
        w('follow/status', ts, status[i])
        w('axis/velocity_command', ts, cmd[i])
