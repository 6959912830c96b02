"""The live view's channels and their decimation: numpy per batch, no rclpy, no foxglove.

The view node (:mod:`.view_node`) takes the contract's topics in batches (raw CDR, decoded into
columns by :class:`~ladrc_bags.columns.CdrColumns`) and turns each 2 kHz topic into what a
screen shows, on a channel named as the topic (``/follow/status``, so that one Foxglove layout
serves the live view and a bag):

* **Display intervals.** Time is cut into intervals of ``1 / display_rate_hz`` (50 Hz: 20 ms,
  40 ticks) by each message's header stamp: interval ``k`` holds the stamps in
  ``[k * T, (k + 1) * T)``. An interval is closed when a message of a later one has arrived (or,
  in the node, when its topic has been quiet for two intervals).
* **Min/max per interval, as real messages.** Of each closed interval the view sends the
  messages (whole rows, every carried field of one tick) at which each *extreme* field
  (``gap_mm``, ``target_gap_mm``, ``fused_gap_mm``, ``velocity_mm_s``, ... see :data:`VIEWS`)
  has its minimum and its maximum, the interval's last message, and every message at which a
  *change* field (state, sub-state, followed, fault and hold reasons, ...) differs from the
  message before: so a 2 ms spike (4 ticks) is always on screen at its value, and no state or
  fault reason is ever skipped. Each sent message is a tick of the topic, its values those the
  tick published (the bag's, for the same stamp); ``view_ticks`` says how many messages of its
  interval the view received. At most ``2 x extremes + 1`` messages per interval plus the
  changes: for the status, about 11 x 50 = 550 messages/s at most, typically far fewer.
* **Vectorised.** Per batch: one interval index per row (integer division of the stamps),
  one ``np.lexsort`` per extreme field and direction (the interval's first row in value order
  is its argmin), one comparison with the shifted column per change field. Python runs per
  *sent* message only (its JSON object).
* **XY path coloured by the gap error** (``/view/xy_gap_error``): per closed status interval the
  tick with the largest ``|gap_mm - target_gap_mm|`` while following (PID or LADRC with a valid
  reading), placed at the nozzle's XY at that tick's stamp (interpolated over the newest XY
  samples of ``cnc/motion`` or ``sim/truth``), with its error band (:data:`BANDS_MM`).

Events (``follow/events``) are not decimated: every one is sent.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any, Iterable

import numpy as np

DISPLAY_RATE_HZ = 50.0
"""Default display intervals per second (what a plot of a few seconds can show)."""

BANDS_MM = (-0.2, -0.05, 0.05, 0.2)
"""Edges of the gap-error bands of the XY path: band 0 (closer than the target by more than
0.2 mm), 1 (closer by 0.05-0.2 mm), 2 (within 0.05 mm), 3 (wider by 0.05-0.2 mm), 4 (wider by
more than 0.2 mm); :data:`NOT_FOLLOWING` (non-negative codes: a layout filters on them)."""
NOT_FOLLOWING = 5
"""The band of a point where the controller was not following (no error to show)."""
FOLLOWING_STATES = (3, 4)
"""PID and LADRC (ladrc_contract.codes.FollowState): a gap error means something there."""


@dataclass(frozen=True)
class TopicView:
    """How one contract topic is shown: fields sent, min/max kept, changes kept."""

    topic: str
    msgtype: str
    fields: tuple[str, ...]
    extremes: tuple[str, ...]
    changes: tuple[str, ...]

    @property
    def channel(self) -> str:
        """The channel's name: the topic's fully qualified name, as a bag stores it."""
        return '/' + self.topic.lstrip('/')


_HEADER = ('header.stamp.sec', 'header.stamp.nanosec')
STATUS = TopicView(
    'follow/status', 'ladrc_msgs/msg/FollowStatus',
    _HEADER + ('tick', 'state', 'followed', 'machining', 'fault_reason', 'target_gap_mm', 't_s',
               'gap_mm', 'gap_valid', 'gap_status', 'drive_enabled', 'drive_fault',
               'fused_gap_mm', 'u_unlimited_mm_s', 'velocity_mm_s', 'limit_flags', 'substate',
               'hold_reason', 'in_position', 'ready_to_move', 'feed_hold_request'),
    extremes=('gap_mm', 'target_gap_mm', 'fused_gap_mm', 'velocity_mm_s', 'u_unlimited_mm_s'),
    changes=('state', 'substate', 'followed', 'machining', 'fault_reason', 'hold_reason',
             'gap_valid', 'drive_fault', 'feed_hold_request'))
TRUTH = TopicView(
    'sim/truth', 'ladrc_msgs/msg/SimTruth',
    _HEADER + ('seq', 'true_gap_mm', 'sheet_mm', 'nozzle_mm', 'edge_coverage',
               'plate_velocity_mm_s', 'collision', 'x_mm', 'y_mm'),
    extremes=('true_gap_mm', 'sheet_mm', 'edge_coverage'),
    changes=('collision',))
COMMAND = TopicView(
    'axis/velocity_command', 'ladrc_msgs/msg/VelocityCommand',
    _HEADER + ('seq', 'velocity_mm_s', 'enable', 'release'),
    extremes=('velocity_mm_s',),
    changes=('enable', 'release'))
CNC = TopicView(
    'cnc/motion', 'ladrc_msgs/msg/CncMotion',
    _HEADER + ('seq', 'x_mm', 'y_mm', 'commanded_feed_mm_s', 'actual_feed_mm_s', 'segment',
               'beam_on', 'contour', 'segment_left_mm', 'edge_ahead_mm'),
    extremes=('actual_feed_mm_s', 'commanded_feed_mm_s'),
    changes=('segment', 'beam_on', 'contour'))
VIEWS: tuple[TopicView, ...] = (STATUS, TRUTH, COMMAND, CNC)
"""The decimated topics (the status first)."""
EVENTS_TOPIC = 'follow/events'
EVENTS_TYPE = 'ladrc_msgs/msg/FollowEvent'
XY_CHANNEL = '/view/xy_gap_error'
LOG_CHANNEL = '/view/log'


# ---- JSON ---------------------------------------------------------------------------------------
def _json_type(kind: str) -> dict[str, Any]:
    if kind == 'string':
        return {'type': 'string'}
    if kind == '?':
        return {'type': 'boolean'}
    if 'f' in kind:
        return {'type': ['number', 'null']}  # NaN and infinities are sent as null
    return {'type': 'integer'}


def json_schema(title: str, kinds: Iterable[tuple[str, str]],
                extra: dict[str, dict[str, Any]] | None = None) -> dict[str, Any]:
    """Return a JSON schema of flattened ``(field, kind)`` pairs, nested at the dots."""
    root: dict[str, Any] = {'title': title, 'type': 'object', 'properties': {}}
    for name, kind in kinds:
        node = root
        parts = name.split('.')
        for p in parts[:-1]:
            node = node['properties'].setdefault(p, {'type': 'object', 'properties': {}})
        node['properties'][parts[-1]] = _json_type(kind)
    root['properties'].update(extra or {})
    return root


def _plain(values: list[Any]) -> list[Any]:
    return [None if isinstance(v, float) and not math.isfinite(v) else v for v in values]


def rows_as_json(cols: dict[str, np.ndarray], names: Iterable[str],
                 index: np.ndarray) -> list[dict[str, Any]]:
    """Return the rows ``index`` of ``cols`` as nested JSON objects (non-finite -> null)."""
    names = list(names)
    columns = [_plain(cols[n][index].tolist()) for n in names]
    paths = [n.split('.') for n in names]
    out = []
    for i in range(len(index)):
        obj: dict[str, Any] = {}
        for path, col in zip(paths, columns, strict=True):
            node = obj
            for p in path[:-1]:
                node = node.setdefault(p, {})
            node[path[-1]] = col[i]
        out.append(obj)
    return out


def stamps_ns(cols: dict[str, np.ndarray]) -> np.ndarray:
    """Return the header stamps of ``cols`` in nanoseconds (int64)."""
    return (cols['header.stamp.sec'].astype(np.int64) * 1_000_000_000
            + cols['header.stamp.nanosec'].astype(np.int64))


# ---- decimation ---------------------------------------------------------------------------------
def _concat(a: dict[str, np.ndarray] | None, b: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    if not a:
        return b
    return {k: np.concatenate([a[k], b[k]]) for k in b}


def _take(cols: dict[str, np.ndarray], index: np.ndarray | slice) -> dict[str, np.ndarray]:
    return {k: v[index] for k, v in cols.items()}


def _run_starts(run_id: np.ndarray) -> np.ndarray:
    return np.r_[0, np.flatnonzero(np.diff(run_id)) + 1] if run_id.size else run_id


def select(cols: dict[str, np.ndarray], interval_ns: int, extremes: Iterable[str],
           changes: Iterable[str], last: dict[str, Any] | None = None
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the rows of ``cols`` to send (module docstring), their run and the run lengths.

    Intervals are runs of rows with one interval index (stamps in arrival order; a stamp that
    goes back starts a run of its own). ``last``: the change fields' values of the row before
    ``cols`` (None: the first row is a change). Returns ``(index, run_of_index, run_lengths)``.
    """
    n = len(cols['header.stamp.sec'])
    bucket = stamps_ns(cols) // interval_ns
    run_id = np.r_[0, np.cumsum(bucket[1:] != bucket[:-1])] if n else np.zeros(0, np.int64)
    starts = _run_starts(run_id)
    ends = np.r_[starts[1:], n] - 1
    picks = [ends]
    for name in extremes:
        v = cols[name].astype(np.float64)
        for order in (np.lexsort((v, run_id)), np.lexsort((-v, run_id))):
            picks.append(order[_run_starts(run_id[order])])
    for name in changes:
        c = cols[name]
        prev = np.empty(n, dtype=object if c.dtype == object else c.dtype)
        if n:
            prev[1:] = c[:-1]
        changed = np.asarray(c[1:] != prev[1:], dtype=bool) if n else np.zeros(0, bool)
        if n:
            first = bool(last is None or last.get(name) != c[0])
            picks.append(np.flatnonzero(np.r_[first, changed]))
    index = np.unique(np.concatenate(picks).astype(np.int64))
    return index, run_id[index], np.diff(np.r_[starts, n])


@dataclass
class Decimator:
    """One topic's display intervals across batches (module docstring)."""

    view: TopicView
    interval_ns: int
    pending: dict[str, np.ndarray] | None = None
    last: dict[str, Any] | None = None
    received: int = 0
    sent: int = 0

    def push(self, cols: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray,
                                                         np.ndarray]:
        """Add a batch (arrival order); return the closed intervals' rows, selection, counts.

        Returns ``(rows, index, view_ticks)``: the closed rows (all of them: the XY path
        reads them too), the indices of those to send, and for each of these how many
        messages its interval held. The last interval stays open until a later one begins.
        """
        n_new = len(cols.get('header.stamp.sec', ()))
        self.received += n_new
        cols = _concat(self.pending, cols)
        n = len(cols['header.stamp.sec'])
        if not n:
            return cols, np.zeros(0, np.int64), np.zeros(0, np.int64)
        bucket = stamps_ns(cols) // self.interval_ns
        open_from = int(np.flatnonzero(np.r_[True, bucket[1:] != bucket[:-1]])[-1])
        self.pending = _take(cols, slice(open_from, None))
        return self._close(_take(cols, slice(0, open_from)))

    def flush(self) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
        """Close the open interval (its topic went quiet); same return as :meth:`push`."""
        rows, self.pending = self.pending, None
        if not rows:
            return {}, np.zeros(0, np.int64), np.zeros(0, np.int64)
        return self._close(rows)

    def _close(self, rows: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray,
                                                           np.ndarray]:
        if not len(rows['header.stamp.sec']):
            return rows, np.zeros(0, np.int64), np.zeros(0, np.int64)
        index, run, lengths = select(rows, self.interval_ns, self.view.extremes,
                                     self.view.changes, self.last)
        self.last = {c: rows[c][-1] for c in self.view.changes}
        self.sent += int(index.size)
        return rows, index, lengths[run]


@dataclass
class XyPath:
    """The XY path of a job coloured by the gap error (module docstring)."""

    interval_ns: int
    keep: int = 8000  # XY samples kept to place the status ticks (4 s at 2 kHz)
    t_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    x_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    y_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def add_xy(self, cols: dict[str, np.ndarray]) -> None:
        """Keep the newest XY samples (``cnc/motion`` or ``sim/truth`` rows)."""
        ok = np.isfinite(cols['x_mm']) & np.isfinite(cols['y_mm'])
        if not np.any(ok):
            return
        self.t_ns = np.r_[self.t_ns, stamps_ns(cols)[ok]][-self.keep:]
        self.x_mm = np.r_[self.x_mm, cols['x_mm'][ok]][-self.keep:]
        self.y_mm = np.r_[self.y_mm, cols['y_mm'][ok]][-self.keep:]

    def points(self, status: dict[str, np.ndarray]) -> list[tuple[int, dict[str, Any]]]:
        """Return ``(log time, point)`` per interval of closed ``status`` rows (worst error)."""
        n = len(status.get('header.stamp.sec', ()))
        if not n or not self.t_ns.size:
            return []
        t = stamps_ns(status)
        bucket = t // self.interval_ns
        run_id = np.r_[0, np.cumsum(bucket[1:] != bucket[:-1])]
        following = (np.isin(status['state'], FOLLOWING_STATES) & status['gap_valid']
                     & np.isfinite(status['gap_mm']))
        err = np.where(following, status['gap_mm'] - status['target_gap_mm'], np.nan)
        order = np.lexsort((-np.abs(err), run_id))  # per run: the largest |error| first
        pick = order[_run_starts(run_id[order])]
        order = np.argsort(self.t_ns, kind='stable')
        tx = self.t_ns[order].astype(np.float64)
        x = np.interp(t[pick].astype(np.float64), tx, self.x_mm[order])
        y = np.interp(t[pick].astype(np.float64), tx, self.y_mm[order])
        e = err[pick]
        band = np.where(np.isfinite(e), np.digitize(e, BANDS_MM), NOT_FOLLOWING)
        out = []
        for i, k in enumerate(pick.tolist()):
            stamp = int(t[k])
            out.append((stamp, {
                'header': {'stamp': {'sec': stamp // 1_000_000_000,
                                     'nanosec': stamp % 1_000_000_000}},
                'x_mm': float(x[i]), 'y_mm': float(y[i]),
                'gap_error_mm': float(e[i]) if math.isfinite(e[i]) else None,
                'band': int(band[i]), 'tick': int(status['tick'][k])}))
        return out


XY_SCHEMA: dict[str, Any] = {
    'title': 'ladrc_view/XyGapError', 'type': 'object', 'properties': {
        'header': {'type': 'object', 'properties': {'stamp': {'type': 'object', 'properties': {
            'sec': {'type': 'integer'}, 'nanosec': {'type': 'integer'}}}}},
        'x_mm': {'type': 'number'}, 'y_mm': {'type': 'number'},
        'gap_error_mm': {'type': ['number', 'null'],
                         'description': 'gap reading - target at the worst tick [mm]'},
        'band': {'type': 'integer', 'description': '0..4 by BANDS_MM; 5: not following'},
        'tick': {'type': 'integer'}}}
"""The XY path's channel."""

LOG_LEVEL = {'info': 2, 'warning': 3, 'error': 4}
"""foxglove.Log levels used here."""
LOG_SCHEMA: dict[str, Any] = {
    'title': 'foxglove.Log', 'type': 'object', 'properties': {
        'timestamp': {'type': 'object', 'properties': {'sec': {'type': 'integer'},
                                                       'nsec': {'type': 'integer'}}},
        'level': {'type': 'integer'}, 'message': {'type': 'string'},
        'name': {'type': 'string'}, 'file': {'type': 'string'}, 'line': {'type': 'integer'}}}
"""Foxglove's well-known log message, JSON-encoded: the Log panel shows it."""


def log_record(stamp_ns: int, level: str, message: str, name: str) -> dict[str, Any]:
    """Return a foxglove.Log message."""
    return {'timestamp': {'sec': stamp_ns // 1_000_000_000, 'nsec': stamp_ns % 1_000_000_000},
            'level': LOG_LEVEL[level], 'message': message, 'name': name, 'file': '', 'line': 0}


@dataclass
class ReasonLog:
    """Turn the sent status rows into log lines: each new fault or hold reason, each state."""

    state: int | None = None
    fault: str = ''
    hold: str = ''

    def lines(self, rows: list[dict[str, Any]], stamps: list[int]) -> list[tuple[int, dict]]:
        """Return ``(log time, foxglove.Log)`` for the changes in ``rows`` (in order)."""
        from ladrc_contract.codes import FollowState, SubState

        out = []
        for row, t in zip(rows, stamps, strict=True):
            if row['state'] != self.state:
                self.state = row['state']
                out.append((t, log_record(t, 'info', 'state ' + _name(FollowState, self.state),
                                          'ladrc_follow')))
            if row['fault_reason'] != self.fault:
                self.fault = row['fault_reason']
                if self.fault:
                    out.append((t, log_record(t, 'error', 'FAULT: ' + self.fault,
                                              'ladrc_follow')))
            if row['hold_reason'] != self.hold:
                self.hold = row['hold_reason']
                if self.hold:
                    sub = _name(SubState, row['substate'])
                    out.append((t, log_record(t, 'warning', f'hold ({sub}): {self.hold}',
                                              'ladrc_follow')))
        return out


def _name(enum: Any, value: int) -> str:
    try:
        return enum(value).name
    except ValueError:
        return str(value)
