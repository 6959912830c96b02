"""The written calibration (calibration.py, part 3): table file, samples, plot, Markdown, JSON.

:func:`write_calibration` writes ``cap_table.yaml`` (read by the controller:
``ladrc_follow/control/cap_table.py``; ``cap_table.rejected.yaml`` when the table has
problems), ``sweep.csv``, ``calibration.png``, ``calibration.md`` and ``calibration.json``
under a temporary name and renames the folder when complete.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
import time
from typing import Any

from ladrc_follow import table_yaml
import numpy as np

from .calibration import COLUMNS, Phase, SweepMotion, SweepRecord
from .calibration_table import Calibration


def _fmt(v: Any, unit: str = '') -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return 'n/a'
    if isinstance(v, float):
        return f'{v:.4g}{unit}'
    return f'{v}{unit}'


def summary(cal: Calibration) -> dict[str, Any]:
    """Return the JSON summary (the CLI's last line): points, range, error, grade, noise."""
    f = cal.figures
    out = {k: f.get(k) for k in ('points', 'range_mm', 'max_error_mm', 'grade', 'noise_mm',
                                 'repeatability_mm', 'roughness_mm', 'gap_min_mm',
                                 'gap_max_mm', 'contact', 'contact_position_mm',
                                 'samples_descent', 'samples_retract')}
    out['grade'] = cal.grade
    out['problems'] = list(cal.problems)
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in out.items()}


def _plot(cal: Calibration, path: Path) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    s = cal.samples
    down = (s['phase'] == Phase.DESCEND) & (s['valid'] > 0) & np.isfinite(s['raw_hz'])
    fig, ax = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    ax[0].plot(s['gap_mm_enc'][down], s['raw_hz'][down] * 1e-3, ',', color='0.6',
               label='descent samples')
    ax[0].plot(cal.knots_gap_mm, cal.knots_raw_hz * 1e-3, '.-', ms=3, label='table')
    ax[0].set_ylabel('raw [kHz]')
    ax[0].legend(loc='lower right')
    ax[0].set_title(f'capacitive calibration: {len(cal.table)} points, grade {cal.grade}')
    ax[1].plot(cal.knots_gap_mm, cal.knots_noise_mm * 1e3, label='noise per sample')
    ax[1].plot(cal.knots_gap_mm, np.abs(cal.retract_diff_mm) * 1e3,
               label='|retract − descent|')
    ax[1].set_ylabel('µm')
    ax[1].legend()
    if np.isfinite(cal.truth_error_mm).any():
        ax[2].plot(cal.knots_gap_mm, cal.truth_error_mm * 1e3, label='table − true gap')
        ax[2].legend()
    else:
        ax[2].text(0.5, 0.5, 'no truth (real sensor)', ha='center', transform=ax[2].transAxes)
    ax[2].set_ylabel('error [µm]')
    ax[2].set_xlabel('gap (encoder − contact) [mm]')
    for a in ax:
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown(cal: Calibration, title: str = 'Capacitive calibration') -> str:
    """Return the calibration report (calibration.md)."""
    f = cal.figures
    meta = cal.table.meta
    lines = [f'# {title}', '',
             f'Grade **{cal.grade}**' + (': rejected' if cal.problems else '') + '.', '']
    if cal.problems:
        lines += ['Problems:', ''] + [f'- {p}' for p in cal.problems] + ['']
    rows = [('points', f['points']), ('gap range', f"{_fmt(f['gap_min_mm'])}–"
                                                  f"{_fmt(f['gap_max_mm'], ' mm')}"),
            ('noise per sample (median over the points)', _fmt(f['noise_mm'], ' mm')),
            ('noise per sample (largest)', _fmt(f['noise_max_mm'], ' mm')),
            ('repeatability (retract − descent, largest)', _fmt(f['repeatability_mm'], ' mm')),
            ('roughness (leave-one-out, largest)', _fmt(f['roughness_mm'], ' mm')),
            ('error against the true gap (largest, window means)',
             _fmt(f['max_error_mm'], ' mm')),
            ('contact', f"{f['contact'] or 'none'} at {_fmt(f['contact_position_mm'], ' mm')}"),
            ('samples (descent / retract)', f"{f['samples_descent']} / {f['samples_retract']}")]
    for k in ('descent_mm_s', 'retract_mm_s', 'source', 'created'):
        if k in meta:
            rows.append((k, str(meta[k])))
    lines += ['| figure | value |', '| --- | --- |'] + [f'| {a} | {b} |' for a, b in rows]
    lines += ['', '![calibration](calibration.png)', '',
              'Files: `cap_table.yaml` (the table: set `sensor.table_file` of the follow node '
              'to it), `sweep.csv` (every sample), `calibration.json`.', '']
    return '\n'.join(lines)


def write_calibration(cal: Calibration, out: Path, title: str = 'Capacitive calibration'
                      ) -> Path:
    """Write table, samples, plot, Markdown and JSON into ``out`` (never overwritten)."""
    from ..offline.outdir import building

    out = Path(out)
    if out.exists():
        raise FileExistsError(f'{out} exists already: outputs are never overwritten')
    with building(out) as tmp:
        header = (f'Capacitive calibration table (docs/calibration.md), grade {cal.grade}.\n'
                  'Load: follow node parameter sensor.table_file.')
        if not cal.problems:
            (tmp / 'cap_table.yaml').write_text(table_yaml(cal.table, header), encoding='utf-8')
        else:
            (tmp / 'cap_table.rejected.yaml').write_text(
                table_yaml(cal.table, header + '\nREJECTED: ' + '; '.join(cal.problems)),
                encoding='utf-8')
        s = cal.samples
        cols = list(COLUMNS) + ['gap_mm_enc']
        data = np.stack([s[c] for c in cols], axis=1)
        np.savetxt(tmp / 'sweep.csv', data, delimiter=',', header=','.join(cols),
                   comments='', fmt='%.10g')
        _plot(cal, tmp / 'calibration.png')
        (tmp / 'calibration.md').write_text(markdown(cal, title), encoding='utf-8')
        (tmp / 'calibration.json').write_text(json.dumps(
            {**summary(cal), 'figures': {k: v for k, v in cal.figures.items()},
             'meta': dict(cal.table.meta)}, indent=1, default=_json_default),
            encoding='utf-8')
    return out


def _json_default(v: Any) -> Any:
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    return str(v)


def table_meta(motion: SweepMotion, record: SweepRecord, source: str) -> dict[str, Any]:
    """Metadata written into the table file: how, when and where the sweep was made."""
    return {'source': source,
            'created': time.strftime('%Y-%m-%dT%H:%M:%S%z'),
            'descent_mm_s': motion.descent_mm_s, 'retract_mm_s': motion.retract_mm_s,
            'contact': record.contact_kind,
            'contact_position_mm': record.contact_position_mm,
            'start_position_mm': record.start_position_mm}
