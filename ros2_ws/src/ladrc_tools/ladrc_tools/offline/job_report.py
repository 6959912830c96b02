"""The drawing of a cutting job (``ladrc job -o``): the sheet, the path, pierces, holds, faults."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

HOLD_MARKERS = {1: ('corner lock', 'tab:orange'), 2: ('void lock', 'tab:purple'),
                7: ('hold', 'tab:brown'), 8: ('edge ahead', 'tab:cyan')}
"""FollowStatus.SUB_* of the holds drawn, with their label and colour."""


def draw_job(job: Any, result: Any, path: Path) -> None:
    """Draw ``result`` of ``job`` into ``path`` (PNG): gap error and state along the path."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    s = result.series
    x, y = s['x_mm'], s['y_mm']
    cutting = (s['segment'] == 2) & (s['beam'] > 0)
    err = s['true_gap_mm'] - s['target_gap_mm']
    fig, axes = plt.subplots(1, 2, figsize=(16, 16 * job.height_mm / job.width_mm / 2 + 1.5),
                             constrained_layout=True)
    program = job.program()
    for ax, what in zip(axes, ('gap error while cutting [mm]', 'follow state'), strict=True):
        ax.plot([0, job.width_mm, job.width_mm, 0, 0], [0, 0, job.height_mm, job.height_mm, 0],
                color='k', lw=1.0)
        for part in program.parts:
            ax.plot(*part.exterior.xy, color='0.7', lw=0.6)
            for hole in part.interiors:
                ax.plot(*hole.xy, color='0.7', lw=0.6)
        ax.plot(x[~cutting], y[~cutting], ',', color='0.8')
        if what.startswith('gap'):
            lim = max(0.05, float(np.nanmax(np.abs(err[cutting]))) if cutting.any() else 0.1)
            sc = ax.scatter(x[cutting], y[cutting], c=err[cutting], s=1, cmap='coolwarm_r',
                            vmin=-lim, vmax=lim)
        else:
            sc = ax.scatter(x, y, c=s['state'], s=1, cmap='viridis', vmin=0, vmax=5)
        fig.colorbar(sc, ax=ax, shrink=0.6, label=what)
        for c in program.contours:
            ax.plot(*c.pierce_xy, 'kx', ms=4)
        for code, (label, colour) in HOLD_MARKERS.items():
            m = s['substate'] == code
            if m.any():
                ax.plot(x[m], y[m], '.', color=colour, ms=2, label=label)
        fault = np.flatnonzero(np.diff((s['state'] == 5).astype(int)) == 1) + 1
        if fault.size:
            ax.plot(x[fault], y[fault], '*', color='red', ms=12, label='FAULT')
        ax.set_aspect('equal')
        ax.set_xlabel('x [mm]')
        ax.set_ylabel('y [mm]')
        ax.legend(loc='upper right', fontsize=7)
    f = result.figures
    fig.suptitle(f'{job.name}: {f["job_time_s"]:g} s, {f["pierces"]} pierces, '
                 f'{f["faults"]} faults, '
                 f'{f["contacts"]} contacts, min gap/target {f["min_gap_over_target_cutting"]}')
    fig.savefig(path, dpi=110)
    plt.close(fig)
