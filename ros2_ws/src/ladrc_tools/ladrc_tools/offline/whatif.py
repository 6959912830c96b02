"""What-if: the recorded inputs through another parameter set, and its table and plot.

This is **open loop**: the recorded inputs (gap, encoder) do not react to the what-if command,
so the result shows what the controller would have commanded in that situation, not how the
closed loop would have moved. For a closed-loop what-if on a headless bag's scenario use
``ladrc simulate SCENARIO --params FILE``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping

from ladrc_contract.codes import LimitFlag
from ladrc_follow import ControllerParams, dump_params
import numpy as np

from .envelope import Envelope
from .outdir import building
from .recording import STATE_NAMES, RecordedBatch, Recording, ReplayError
from .rerun import ReplayBatch, ReplayResult

LIMIT_VELOCITY, LIMIT_ACCELERATION = int(LimitFlag.VELOCITY), int(LimitFlag.ACCELERATION)

OPEN_LOOP_NOTE = ('open loop: the recorded inputs (gap, encoder) do not react to the what-if '
                  'command; for a closed-loop what-if on a headless scenario use '
                  '`ladrc simulate SCENARIO --params FILE`')


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
