"""Report of one bag (live or headless): metrics, loop timing, loss, PNG plots, Markdown + JSON.

Metrics reuse ``ladrc_sim.headless.metrics`` on the bag's ``follow/status`` series: the error
is taken against the true gap when the bag has ``sim/truth`` (interpolated onto the status
stamps), else against the measured gap the controller used. The target counts only outside
STATE_IDLE (the metrics' convention: NaN while not following). Limit hits come from
``limit_flags``. The output folder is built under a temporary name and renamed when complete.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
import sys
from typing import Any, Callable

from ladrc_bags import Bag, BagError, count_lost, open_bag, read_text_topic
from ladrc_contract.codes import FollowState, LimitFlag
from ladrc_contract.run_log import RunLog, verdict
from ladrc_contract.topics import SEQ_FIELD
import numpy as np
import yaml

from .envelope import Envelope
from .outdir import building
from .quantiles import Quantiles

STATE_NAMES = [s.name for s in FollowState]
LIMIT_VELOCITY, LIMIT_ACCELERATION = int(LimitFlag.VELOCITY), int(LimitFlag.ACCELERATION)


def stderr_progress(label: str) -> Callable[[int, int], None]:
    """Return a progress callback printing ``label NN%`` on stderr (one line, rewritten).

    Only on a terminal: piped or logged, stderr carries nothing but the one line of an error.
    """
    last = [-1]

    def show(done: int, total: int) -> None:
        if not sys.stderr.isatty():
            return
        pct = int(100 * done / total) if total else 100
        if pct != last[0]:
            last[0] = pct
            end = '\n' if pct >= 100 else ''
            print(f'\r{label}: {pct:3d}%', end=end, file=sys.stderr, flush=True)
    return show


def _find_key(data: Any, key: str) -> float | None:
    if isinstance(data, dict):
        for k, v in data.items():
            if k == key and isinstance(v, (int, float)):
                return float(v)
            found = _find_key(v, key)
            if found is not None:
                return found
    return None


REPORT_FIELDS = ('tick', 'stamp_s', 'state', 'target_gap_mm', 'td_x1_mm', 'followed',
                 'velocity_mm_s', 'u_unlimited_mm_s', 'eso_z1_mm', 'eso_z2', 'eso_z3',
                 'gap_mm', 'limit_flags', 'period_us', 'compute_us', 'input_age_us', 'overrun',
                 'fault_reason', 't_s', 'gap_stamp_s', 'encoder_stamp_s', 'substate')
"""The follow/status fields the report reads (``substate``: bags of FollowStatus revision 2)."""
TIMING = ('period_us', 'compute_us', 'input_age_us')


HOLD_NS = 1_000_000_000
"""A status row waits at most this much bag time for the truth samples around its stamp."""


class _TruthJoin:
    """``sim/truth`` interpolated onto the status stamps, a slice at a time.

    Status rows wait until truth has been read past their stamp (at most :data:`HOLD_NS` of
    bag time, or the bag ends); the truth kept is what the waiting rows can still need (from
    the sample before them on), so the result is that of ``np.interp`` / ``searchsorted``
    over the whole run (for status stamps in time order).
    """

    def __init__(self) -> None:
        self.t = np.zeros(0)
        self.gap = np.zeros(0)
        self.collision = np.zeros(0, dtype=bool)

    def add(self, tr: dict[str, np.ndarray]) -> None:
        self.t = np.concatenate((self.t, tr['stamp_s']))
        self.gap = np.concatenate((self.gap, tr['true_gap_mm']))
        self.collision = np.concatenate((self.collision, tr['collision'].astype(bool)))

    def ready(self, stamp_s: np.ndarray) -> int:
        """How many of the waiting rows (stamps ``stamp_s``) the truth read so far covers."""
        if self.t.size == 0:
            return 0
        return int(np.searchsorted(stamp_s, self.t[-1], 'right'))

    def keep_recent(self, seconds: float = 1.0) -> None:
        """Drop truth older than ``seconds`` before the newest (no status row is waiting)."""
        if self.t.size > 1:
            k = max(0, int(np.searchsorted(self.t, self.t[-1] - seconds)) - 1)
            self.t, self.gap, self.collision = self.t[k:], self.gap[k:], self.collision[k:]

    def join(self, stamp_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.t.size == 0:
            return np.full(stamp_s.size, np.nan), np.zeros(stamp_s.size, dtype=bool)
        gap = np.interp(stamp_s, self.t, self.gap)
        idx = np.clip(np.searchsorted(self.t, stamp_s), 0, self.t.size - 1)
        collision = self.collision[idx]
        if stamp_s.size:  # keep from the sample before the last joined stamp on
            k = max(0, int(np.searchsorted(self.t, stamp_s[-1])) - 1)
            self.t, self.gap, self.collision = self.t[k:], self.gap[k:], self.collision[k:]
        return gap, collision


class _StatusPass:
    """The accumulators of one pass over ``follow/status`` (:func:`analyse`).

    Whether the controller reports its state (then there is no target while IDLE) is known
    only at its first non-IDLE tick: until then both readings are accumulated (``plain``:
    the recorded target; ``idle``: no target while IDLE) and the other is dropped then.
    """

    def __init__(self, bag: Bag, v_max: float | None, truth: _TruthJoin | None) -> None:
        self.bag = bag
        self.v_max = v_max
        self.truth = truth
        self.extra: Any = None  # analyse(extra=...): another accumulator on the same pass
        self.n_status = bag.count('follow/status')
        self.timing = {k: Quantiles() for k in TIMING}
        self.last_seq: dict[str, int] = {}
        self.lost = {t: 0 for t in SEQ_FIELD if bag.has(t)}
        self.state_seen = False
        self.pending: dict[str, np.ndarray] = {}
        self.acc: dict[str, Any] = {}  # 'plain' / 'idle' -> MetricsAccumulator
        self.env: dict[str, Envelope] = {}
        self.zoom_on = False  # also gather the HTML report's data (zoom_data.ZoomRecorder)
        self.zoom: dict[str, Any] = {}
        self.first: dict[str, float] = {}
        self.overruns = 0
        self.run_log = RunLog()  # faults, holds, time per state (ladrc_contract.run_log)
        self.n_done = 0
        self.prev_rate = (math.nan, math.nan)  # last (t, true gap): the gap rate across slices

    def _start(self, st: dict[str, np.ndarray]) -> None:
        """Set the period (median tick spacing of the first rows) and the accumulators."""
        from ladrc_sim.headless import metrics as M

        self.first['stamp_s'] = float(st['stamp_s'][0])
        h_s = float(np.median(np.diff(st['stamp_s']))) if st['stamp_s'].size > 1 else 0.0
        if not (math.isfinite(h_s) and h_s > 0.0):
            raise BagError(f'{self.bag.path}: follow/status stamps do not advance: no period')
        self.first['h_s'] = h_s
        for name in ('plain', 'idle'):
            self.acc[name] = M.MetricsAccumulator(h_s, v_max_mm_s=self.v_max or math.inf)
            self.env[name] = Envelope(self.n_status)
            if self.zoom_on:
                from .zoom_data import ZoomRecorder

                self.zoom[name] = ZoomRecorder(self.n_status)

    def _true_gap(self, st: dict[str, np.ndarray], t: np.ndarray,
                  series: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Return the error's gap and the collisions: the truth joined, else the measured gap."""
        if self.truth is None:
            return st['gap_mm'].astype(float), np.zeros(t.size, dtype=bool)
        gap, collision = self.truth.join(st['stamp_s'])
        series['true_gap_mm'] = gap
        with np.errstate(invalid='ignore'):  # no material under the face: an inf gap, NaN rate
            if self.n_done:  # central differences across the slice boundary
                t0, gap0 = self.prev_rate
                rate = np.gradient(np.r_[gap0, gap], np.r_[t0, t])[1:]
            else:
                rate = np.gradient(gap, t) if t.size > 1 else np.zeros(t.size)
        series['true_gap_rate'] = rate
        self.prev_rate = (float(t[-1]), float(gap[-1]))
        return gap, collision

    def process(self, st: dict[str, np.ndarray]) -> None:
        """Accumulate status rows whose truth is known."""
        if not self.acc:
            self._start(st)
        t = st['stamp_s'] - self.first['stamp_s']
        state = st['state'].astype(int)
        if not self.state_seen and np.any(state != 0):
            self.state_seen = True  # a controller that reports its state: no target while IDLE
            del self.acc['plain'], self.env['plain']
            self.zoom.pop('plain', None)
        series = {'t_s': t, 'gap_mm': st['gap_mm'], 'state': state,
                  'followed': st['followed'], 'velocity_mm_s': st['velocity_mm_s'],
                  'u_unlimited_mm_s': st['u_unlimited_mm_s']}
        gap, collision = self._true_gap(st, t, series)
        flags = st['limit_flags'].astype(np.int64)
        limits = {'limit_v': (flags & LIMIT_VELOCITY) != 0,
                  'limit_a': (flags & LIMIT_ACCELERATION) != 0}
        for name in self.acc:
            target = st['target_gap_mm'].astype(float)
            # The TD and ESO run in PID (re-initialised) and LADRC only: elsewhere they hold
            # zeros, which would squash the plots' scales.
            active = np.ones(state.size, bool)
            if name == 'idle':
                target = np.where(state != 0, target, np.nan)
                active = np.isin(state, (3, 4))
            self.acc[name].add(t, gap, target, collision, st['velocity_mm_s'], limits)
            plotted = {**series, 'target_mm': target, **{
                col: np.where(active, st[col].astype(float), np.nan)
                for col in ('td_x1_mm', 'eso_z1_mm', 'eso_z2', 'eso_z3')}}
            self.env[name].add(plotted)
            if name in self.zoom:
                self.zoom[name].add(plotted)
        for k in TIMING:
            self.timing[k].add(st[k])
        self.overruns += int(np.count_nonzero(st['overrun']))
        self.run_log.add(st['stamp_s'], state, st['fault_reason'], st['t_s'] - st['gap_stamp_s'],
                         st['t_s'] - st['encoder_stamp_s'], st.get('substate'))
        self.n_done += t.size

    def flush(self, final: bool, latest_ns: int) -> None:
        """Process the waiting rows the truth read so far covers (all of them at the end)."""
        pending, truth = self.pending, self.truth
        if not pending or pending['tick'].size == 0:
            if truth is not None:
                truth.keep_recent()
            return
        k = pending['tick'].size
        if truth is not None and not final:
            # covered by the truth read so far, or waited HOLD_NS of bag time
            k = max(truth.ready(pending['stamp_s']), int(np.searchsorted(
                pending['timestamp_ns'], latest_ns - HOLD_NS, 'right')))
        if not self.acc and k < 2 and not final:
            return  # the period needs two rows
        if k:
            self.process({c: v[:k] for c, v in pending.items()})
            for c in list(pending):
                pending[c] = pending[c][k:]

    def count_lost(self, topic: str, cols: dict[str, np.ndarray]) -> None:
        """Count the messages of ``topic`` lost before the recorder (seq gaps)."""
        seq = cols[SEQ_FIELD[topic]].astype(np.int64)
        if topic in self.last_seq:
            seq = np.r_[self.last_seq[topic], seq]
        self.lost[topic] += count_lost(seq)
        if seq.size:
            self.last_seq[topic] = int(seq[-1])

    def read(self, wanted: dict[str, Any], progress: bool) -> None:
        """Make the one pass over the bag, in time slices."""
        show = stderr_progress('reading the bag') if progress else None
        latest_ns = 0
        for part in self.bag.stream(wanted, progress=show):
            for topic, cols in part.items():
                if cols['timestamp_ns'].size:
                    latest_ns = max(latest_ns, int(cols['timestamp_ns'][-1]))
                if topic in SEQ_FIELD:
                    self.count_lost(topic, cols)
            if self.truth is not None and 'sim/truth' in part:
                self.truth.add(part['sim/truth'])
            if self.extra is not None:
                self.extra.add(part)
            st = part.get('follow/status')
            if st is not None:
                for c in REPORT_FIELDS + ('timestamp_ns',):
                    if c not in st:  # substate: not in bags of FollowStatus revision 1
                        continue
                    self.pending[c] = (np.concatenate((self.pending[c], st[c]))
                                       if c in self.pending else st[c])
            self.flush(False, latest_ns)
        self.flush(True, latest_ns)


def _recording(bag: Bag) -> dict[str, Any] | None:
    """Return the live run's ``recording.json`` beside the bag's files, if readable."""
    rec_file = bag.path / 'recording.json' if bag.path.is_dir() else None
    if rec_file is not None and rec_file.is_file():
        try:
            return json.loads(rec_file.read_text())
        except (OSError, ValueError):
            return None
    return None


def analyse(bag: Bag, progress: bool = False, extra: Any = None
            ) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Return ``(report dict, plot series)`` of an open bag (:func:`analyse_zoom`)."""
    report, series, _ = analyse_zoom(bag, progress, extra, zoom=False)
    return report, series


def analyse_zoom(bag: Bag, progress: bool = False, extra: Any = None, zoom: bool = True
                 ) -> tuple[dict[str, Any], dict[str, np.ndarray], Any]:
    """Return ``(report dict, plot series, zoom data)`` of an open bag (needs ``follow/status``).

    ``extra``: another accumulator riding the same pass (the fleet's sensor check): its
    ``fields`` (topic -> field names) are read too and each slice goes to its ``add(part)``.

    ONE pass over the bag in time slices (:meth:`Bag.stream`); memory is that of a slice plus
    the accumulators (metrics, timing quantiles, plot envelope), whatever the bag's length.
    The plot series come back decimated (:mod:`.envelope`). ``zoom``: the same pass also
    gathers the HTML report's data (:class:`.zoom_data.ZoomData`, else None), third.
    """
    bag.require('follow/status')
    n_status = bag.count('follow/status')
    if n_status < 2:
        raise BagError(f'{bag.path}: follow/status holds {n_status} message(s); '
                       'a report needs a run')
    params_text = read_text_topic(bag, 'run/parameters') or ''
    try:
        params = yaml.safe_load(params_text) if params_text else None
    except yaml.YAMLError:
        params = None
    v_max = _find_key(params, 'v_max_mm_s')
    wanted: dict[str, Any] = {t: [f] for t, f in SEQ_FIELD.items()}  # loss: the counters
    wanted['follow/status'] = REPORT_FIELDS
    wanted['sim/truth'] = ['stamp_s', 'true_gap_mm', 'collision', 'seq']
    truth = _TruthJoin() if bag.count('sim/truth') > 1 else None
    run = _StatusPass(bag, v_max, truth)
    run.zoom_on = zoom
    if extra is not None:
        run.extra = extra
        for topic, fields in extra.fields.items():
            wanted[topic] = tuple(dict.fromkeys((*wanted.get(topic, ()), *fields)))
    run.read(wanted, progress)
    if not run.acc or run.n_done < 2:
        raise BagError(f'{bag.path}: follow/status holds {run.n_done} readable message(s); '
                       'a report needs a run')
    name = 'idle' if run.state_seen else 'plain'
    acc = run.acc[name]
    metrics = acc.result()
    series = run.env[name].result()
    run_summary = run.run_log.summary()
    spec = run_spec(bag)
    duration_s = float(series['t_s'][-1])
    report = {
        'bag': str(bag.path),
        'title': run_title(bag, spec),
        'source': bag.custom_data.get('ladrc.source', 'unknown'),
        'scenario': bag.custom_data.get('ladrc.scenario', ''),
        'duration_s': duration_s,
        'ticks': int(run.n_done),
        'h_s': run.first['h_s'],
        'error_against': ('true (sim/truth)' if truth is not None
                          else 'measured (follow/status gap_mm)'),
        'metrics': metrics.as_dict(),
        # the error metrics' time base: target ticks from the followed time on
        'metrics_time_base': {'followed_s': round(acc.error_ticks * run.first['h_s'], 4),
                              'run_s': round(duration_s, 4)},
        'states': run_summary['state_s'],
        'final_state': run_summary['final_state'],
        'faults': run_summary['faults'],
        'timing': {**{k: run.timing[k].stats() for k in TIMING}, 'overruns': run.overruns},
        'holds': run_summary['holds'],
        'messages': dict(bag.message_counts),
        'messages_lost': int(sum(run.lost.values())),
        'messages_lost_by_topic': run.lost,
        'v_max_mm_s': v_max,
    }
    report['ok'], report['outcome'] = verdict(
        run_summary, spec.get('expect_fault') is True)
    recording = _recording(bag)
    if recording is not None:
        report['recording'] = recording
    return report, series, (run.zoom[name].finish() if name in run.zoom else None)


def run_spec(bag: Bag) -> dict[str, Any]:
    """Return the bag's scenario or job file as a mapping (``run/scenario``); {} if none."""
    text = read_text_topic(bag, 'run/scenario') or ''
    try:
        data = yaml.safe_load(text) if text else None
        if isinstance(data, dict) and isinstance(data.get('job'), str):  # a job's bag
            data = yaml.safe_load(data['job'])
    except yaml.YAMLError:
        return {}
    return data if isinstance(data, dict) else {}


def run_title(bag: Bag, spec: dict[str, Any]) -> str:
    """Return a report's title: the run (scenario or job, source, start time), not the folder."""
    custom = bag.custom_data
    what = str(spec.get('name') or custom.get('ladrc.scenario', '') or 'unnamed run')
    source = {'recorder': 'live', '': 'unknown source'}.get(
        custom.get('ladrc.source', ''), custom.get('ladrc.source', ''))
    start = custom.get('ladrc.start_utc', '')
    when = f', {start[:16].replace("T", " ")} UTC' if start else ''
    return f'{what} ({source}{when})'


def _save(fig: Any, out: Path, name: str) -> str:
    """Lay out, write and close one figure; return its file name."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(out / name, dpi=110)
    plt.close(fig)
    return name


def _mark_faults(ax: Any, report: dict[str, Any]) -> None:
    """Draw each fault of the run as a red vertical line, numbered as in the report."""
    for k, fault in enumerate(report.get('faults', []), 1):
        ax.axvline(fault['t_s'], color='r', lw=1.2, ls='--',
                   label='fault' if k == 1 else None)
        ax.annotate(f'F{k}', (fault['t_s'], 1.0), xycoords=('data', 'axes fraction'),
                    color='r', fontsize=8, ha='left', va='top')


def _plots(series: dict[str, np.ndarray], report: dict[str, Any], out: Path) -> list[str]:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    t = series['t_s']
    names = []

    fig, ax = plt.subplots(figsize=(11, 4.5))
    ax.plot(t, series['gap_mm'], lw=0.6, label='measured gap')
    if 'true_gap_mm' in series:
        ax.plot(t, series['true_gap_mm'], lw=0.8, label='true gap')
    ax.plot(t, series['td_x1_mm'], lw=0.8, ls='--', label='TD reference x1')
    ax.plot(t, series['target_mm'], lw=1.0, color='k', label='target')
    _mark_faults(ax, report)
    ax.set_xlabel('t [s]')
    ax.set_ylabel('gap [mm]')
    ax.legend(loc='best', fontsize=8)
    ax.grid(alpha=0.3)
    names.append(_save(fig, out, 'gap.png'))

    if 'true_gap_mm' in series:
        fig, axs = plt.subplots(3, 1, figsize=(11, 7), sharex=True)
        axs[0].plot(t, series['true_gap_mm'], lw=0.8, label='true gap')
        axs[0].plot(t, series['eso_z1_mm'], lw=0.6, label='ESO z1')
        axs[0].set_ylabel('gap [mm]')
        axs[1].plot(t, series['true_gap_rate'], lw=0.5, label='true gap rate [mm/s]')
        axs[1].plot(t, series['eso_z2'], lw=0.6, label='ESO z2')
        axs[2].plot(t, series['eso_z3'], lw=0.6, label='ESO z3')
        axs[2].set_xlabel('t [s]')
        for a in axs:
            a.legend(loc='best', fontsize=8)
            a.grid(alpha=0.3)
        names.append(_save(fig, out, 'eso.png'))

    fig, ax = plt.subplots(figsize=(11, 4))
    ax.plot(t, series['u_unlimited_mm_s'], lw=0.5, label='unlimited')
    ax.plot(t, series['velocity_mm_s'], lw=0.7, label='sent')
    v_max = report.get('v_max_mm_s')
    if v_max:
        for s in (1, -1):
            ax.axhline(s * v_max, color='r', ls=':', lw=1,
                       label='velocity limit' if s == 1 else None)
    ax.set_xlabel('t [s]')
    ax.set_ylabel('velocity command [mm/s]')
    ax.legend(loc='best', fontsize=8)
    ax.grid(alpha=0.3)
    names.append(_save(fig, out, 'command.png'))

    fig, ax = plt.subplots(figsize=(11, 2.8))
    ax.step(t, series['state'], where='post', lw=1, label='state')
    ax.fill_between(t, -0.4, -0.1, where=series['followed'].astype(bool), step='post',
                    color='g', alpha=0.5, label='followed')
    _mark_faults(ax, report)
    ax.set_yticks(range(len(STATE_NAMES)), STATE_NAMES)
    ax.set_ylim(-0.5, len(STATE_NAMES) - 0.5)
    ax.set_xlabel('t [s]')
    ax.legend(loc='upper right', fontsize=8)
    ax.grid(alpha=0.3)
    names.append(_save(fig, out, 'state.png'))
    return names


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return 'n/a' if not math.isfinite(v) else f'{v:.4g}'
    return str(v)


def _fmt_nested(v: Any) -> str:
    if isinstance(v, dict):
        return ', '.join(f'{k}: {_fmt_nested(x)}' for k, x in v.items())
    return _fmt(v)


def _markdown(report: dict[str, Any], pngs: list[str]) -> str:
    base = report['metrics_time_base']
    lines = [f'# Report: {report["title"]}', '',
             f'**{report["outcome"]}**', '',
             f'- bag: `{report["bag"]}`',
             f'- source: {report["source"]}' + (f', scenario `{report["scenario"]}`'
                                                 if report['scenario'] else ''),
             f'- duration: {report["duration_s"]:.3f} s, {report["ticks"]} ticks, '
             f'h = {report["h_s"] * 1e3:.3f} ms',
             '- time per state: ' + (', '.join(f'{k} {v:g} s' for k, v in
                                               report['states'].items()) or 'none'),
             f'- error against the {report["error_against"]} gap',
             f'- messages lost (seq gaps): {report["messages_lost"]}', '',
             f'## Faults ({len(report["faults"])})', '']
    if report['faults']:
        lines += ['| # | t [s] | state before | reason | gap age [ms] | encoder age [ms] |',
                  '| --- | --- | --- | --- | --- | --- |']
        lines += [f'| F{k} | {f["t_s"]:.4f} | {f["state_before"]} | '
                  f'{f["reason"].replace("|", "/")} | {_fmt(f["gap_age_ms"])} | '
                  f'{_fmt(f["encoder_age_ms"])} |'
                  for k, f in enumerate(report['faults'], 1)]
    else:
        lines += ['None.']
    lines += ['', '## Holds', '']
    if report.get('holds'):
        lines += ['| hold (FollowStatus.substate) | episodes | time [s] |', '| --- | --- | --- |']
        lines += [f'| {name} | {v["count"]} | {v["seconds"]:g} |'
                  for name, v in report['holds'].items()]
    else:
        lines += ['None.']
    lines += ['', '## Metrics', '',
              f'Error metrics over the followed time: {base["followed_s"]:g} s of '
              f'{base["run_s"]:g} s (ticks with a target, from the followed time on).', '',
              '| metric | value |', '| --- | --- |']
    lines += [f'| {k} | {_fmt(v)} |' for k, v in report['metrics'].items()]
    lines += ['', '## Loop timing', '', '| quantity | p50 | p99 | max |',
              '| --- | --- | --- | --- |']
    for k in ('period_us', 'compute_us', 'input_age_us'):
        s = report['timing'][k]
        lines.append(f'| {k} | {_fmt(s["p50"])} | {_fmt(s["p99"])} | {_fmt(s["max"])} |')
    lines += ['', f'Overruns: {report["timing"]["overruns"]}']
    job = report.get('job')
    if job:
        lines += ['', f'## Job `{job["name"]}`', '', '| figure | value |', '| --- | --- |']
        lines += [f'| {k} | {_fmt_nested(v)} |' for k, v in job['figures'].items()]
    lines += ['', '## Plots', '']
    lines += [f'![{p[:-4]}]({p})' for p in pngs]
    return '\n'.join(lines) + '\n'


def write_report(bag_path: str | Path, out_dir: str | Path | None = None,
                 progress: bool = False, html: bool = True) -> Path:
    """Write ``report.md``, ``report.json`` and PNGs for a bag; return the output folder.

    Default output: ``<bag>_report`` beside the bag. Refuses an existing output folder.
    ``html``: also ``report.html``, the plots zoomable (:mod:`.html_report`), from the same
    pass.
    """
    bag_path = Path(bag_path)
    out = Path(out_dir) if out_dir else bag_path.with_name(bag_path.name + '_report')
    if out.exists():
        raise BagError(f'{out} exists already: choose another output folder (-o)')
    with open_bag(bag_path) as bag:
        report, series, zoom = analyse_zoom(bag, progress, zoom=html)
        job = _job(bag)
    with building(out) as tmp:
        pngs = _plots(series, report, tmp)
        if zoom is not None:
            from .html_report import write_html

            write_html(zoom, report, STATE_NAMES, tmp / 'report.html')
        if job is not None:  # a cutting job's bag: the job drawn, its figures
            from .job_report import draw_job

            report['job'] = {'name': job.job.name, 'figures': job.figures}
            draw_job(job.job, job, tmp / 'job.png')
            pngs.append('job.png')
        report['plots'] = pngs
        (tmp / 'report.json').write_text(json.dumps(strict_json(report), indent=1) + '\n',
                                         encoding='utf-8')
        (tmp / 'report.md').write_text(_markdown(report, pngs), encoding='utf-8')
    return out


def _job(bag: Bag) -> Any:
    """Return the bag's cutting job read back (:mod:`.job_bag`), None when it is not a job's."""
    from .job_bag import job_in_bag

    text = read_text_topic(bag, 'run/parameters') or ''
    try:
        ratio = _find_key(yaml.safe_load(text), 'corner_lock_ratio') if text else None
    except yaml.YAMLError:
        ratio = None
    try:
        return job_in_bag(bag, ratio if ratio is not None else 0.8)
    except ValueError as exc:  # the job's texts do not load (JobError: one line)
        raise BagError(f'{bag.path}: run/scenario holds a job that does not load: '
                       f'{" ".join(str(exc).split())}') from None


def strict_json(v: Any) -> Any:
    """Return ``v`` with numpy scalars as Python ones and NaN/inf as None (strict JSON)."""
    if isinstance(v, dict):
        return {str(k): strict_json(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [strict_json(x) for x in v]
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    return v
