"""The fleet's report: Markdown with PNG plots, from the tables (tables.py, rules.py).

``fleet.md``: what was read (bags, failed with their reason, still being written), the flagged
machines and days with the rule and the values behind each, the parameter-set changes with
error RMS and faults per hour before and after, and per machine its trend figures.
``heatmap.png``: machines x days, the day's error RMS, flagged machine-days marked.
``flagged.png``: each flagged figure per day, the flagged machine against the others.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .tables import TREND


def _fmt(v: Any, nd: int = 4) -> str:
    if v is None:
        return '–'
    if isinstance(v, float):
        return f'{v:.{nd}g}'
    return str(v)


def heatmap(days: list[dict[str, Any]], flags: list[dict[str, Any]], out: Path) -> str | None:
    """Draw machines x days of the error RMS, flagged cells marked; return the file name."""
    if not days:
        return None
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    machines = sorted({d['machine_id'] for d in days})
    dates = sorted({d['day'] for d in days})
    grid = np.full((len(machines), len(dates)), np.nan)
    for d in days:
        if d['error_rms_mm'] is not None:
            grid[machines.index(d['machine_id']), dates.index(d['day'])] = d['error_rms_mm']
    fig, ax = plt.subplots(figsize=(1.2 + 0.9 * len(dates), 1.0 + 0.35 * len(machines)))
    im = ax.imshow(grid, aspect='auto', cmap='viridis')
    fig.colorbar(im, ax=ax, label='error RMS [mm]')
    for f in flags:
        ax.text(dates.index(f['day']), machines.index(f['machine_id']), '×', ha='center',
                va='center', color='red', fontsize=14, fontweight='bold')
    ax.set_xticks(range(len(dates)), dates, rotation=45, ha='right')
    ax.set_yticks(range(len(machines)), machines)
    ax.set_title('error RMS per machine and day (× flagged)')
    fig.tight_layout()
    fig.savefig(out / 'heatmap.png', dpi=100)
    plt.close(fig)
    return 'heatmap.png'


def flagged_series(days: list[dict[str, Any]], flags: list[dict[str, Any]], out: Path
                   ) -> str | None:
    """Draw each flagged (machine, figure) per day against the fleet; return the file name."""
    pairs = sorted({(f['machine_id'], f['figure']) for f in flags})
    if not pairs:
        return None
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    dates = sorted({d['day'] for d in days})
    fig, axes = plt.subplots(len(pairs), 1, figsize=(7, 2.2 * len(pairs)), squeeze=False)
    for ax, (machine, figure) in zip(axes[:, 0], pairs, strict=True):
        for m in sorted({d['machine_id'] for d in days}):
            ys = {d['day']: d[figure] for d in days if d['machine_id'] == m}
            y = [np.nan if ys.get(x) is None else ys[x] for x in dates]
            ax.plot(range(len(dates)), y, color='tab:red' if m == machine else '0.7',
                    lw=2 if m == machine else 1, marker='o', ms=3, zorder=3 if m == machine else 1,
                    label=machine if m == machine else None)
        ax.set_ylabel(figure, fontsize=8)
        ax.set_xticks(range(len(dates)), dates, fontsize=7)
        ax.legend(loc='best', fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / 'flagged.png', dpi=100)
    plt.close(fig)
    return 'flagged.png'


def markdown(summary: dict[str, Any], rows: list[dict[str, Any]], machines: list[dict[str, Any]],
             flags: list[dict[str, Any]], changes: list[dict[str, Any]],
             plots: list[str]) -> str:
    """Return ``fleet.md``."""
    lines = ['# Fleet report', '',
             f"{summary['bags']} bag(s) read: {summary['ok']} ok, {summary['failed']} failed; "
             f"{summary['writing']} still being written (skipped); {summary['computed']} "
             f"computed, {summary['cached']} from the cache; {summary['workers']} worker(s), "
             f"{summary['wall_s']:.1f} s.", '']
    for p in plots:
        lines += [f'![{p}]({p})', '']
    lines += ['## Flagged', '']
    if flags:
        lines += ['| machine | day | rule | value | fleet median | why |',
                  '|---|---|---|---|---|---|']
        lines += [f"| {f['machine_id']} | {f['day']} | {f['rule']} | {_fmt(f['value'])} | "
                  f"{_fmt(f['fleet_median'])} | {f['why']} |" for f in flags]
    else:
        lines.append('Nothing stands out.')
    lines += ['', '## Parameter-set changes', '']
    if changes:
        lines += ['| machine | at | from → to | bags before / after | error RMS before → after '
                  '[mm] | faults/h before → after |', '|---|---|---|---|---|---|']
        lines += [f"| {c['machine_id']} | {c['at']} | {c['from_hash']} → {c['to_hash']} | "
                  f"{c['bags_before']} / {c['bags_after']} | {_fmt(c['error_rms_before_mm'])} → "
                  f"{_fmt(c['error_rms_after_mm'])} | {_fmt(c['faults_per_h_before'])} → "
                  f"{_fmt(c['faults_per_h_after'])} |" for c in changes]
    else:
        lines.append('None in these bags.')
    lines += ['', '## Machines: first day → last day (slope per day)', '',
              '| machine | days | bags | ' + ' | '.join(TREND) + ' |',
              '|---|---|---|' + '---|' * len(TREND)]
    for m in machines:
        cells = [f"{_fmt(m[f'{k}_first'])} → {_fmt(m[f'{k}_last'])} "
                 f"({_fmt(m[f'{k}_per_day'], 2)})" for k in TREND]
        lines.append(f"| {m['machine_id']} | {m['days']} | {m['bags']} | " + ' | '.join(cells)
                     + ' |')
    failed = [r for r in rows if r['status'] != 'ok']
    lines += ['', '## Bags not read', '']
    if failed or summary['writing_paths']:
        lines += ['| bag | status | reason |', '|---|---|---|']
        lines += [f"| {r['bag']} | {r['status']} | {r['error']} |" for r in failed]
        lines += [f'| {p} | writing | still being written: skipped |'
                  for p in summary['writing_paths']]
    else:
        lines.append('None.')
    return '\n'.join(lines) + '\n'
