"""The report as one self-contained HTML page with zoomable, linked plots (``report.html``).

The page inlines uPlot (vendored, MIT: ``vendor/uplot/``), its own script and style
(``html_report.js``, ``html_report.css``) and the data of :mod:`.zoom_data` as one base64 blob
of zlib streams, so it opens from a file with no network (its Content-Security-Policy allows
nothing to be fetched). The plots are those of the PNGs (gap, command, state, ESO), their time
axes linked: drag to zoom, the wheel zooms around the pointer, shift + wheel pans,
double-click shows the whole run.

On every zoom the page picks the finest level with at most :data:`POINTS_PER_PX` points per
pixel of the plot's width: every sample when the window holds that few (at 2 kHz: windows up
to 1.8 s on a plot drawn 1 200 px wide), else the min/max of buckets of 4, 16, 64 ...
samples (:mod:`.pyramid`), so a single-sample spike shows at any zoom. ``window.ladrcReport``
is the page's API (the browser test and the bench use it): ``ready`` (a promise: every plot
drawn), ``zoom(t0_s, t1_s)``, ``reset()`` and ``back()`` (promises), ``window`` and ``level``
(what is shown), ``visible(plot, key)`` (a curve's points in the window), ``values(plot,
key)``, ``pyramid(key, level)`` (the page's min/max level of a curve), ``timing`` and
``errors``.
"""

from __future__ import annotations

import base64
from importlib import resources
import json
import math
from pathlib import Path
from typing import Any, Iterator

from ladrc_bags import BagError

from .zoom_data import ZoomData

POINTS_PER_PX = 3
"""The page draws at most this many points per pixel (uPlot decimates again from 4)."""
ASSETS = ('vendor/uplot/uPlot.iife.min.js', 'vendor/uplot/uPlot.min.css',
          'vendor/uplot/LICENSE', 'html_report.js', 'html_report.css')
COLORS = ('#1f77b4', '#ff7f0e', '#2ca02c', '#d62728', '#000000', '#9467bd')

# plot id, title, y label, series: (curve key, colour, width, dash, stepped)
PLOTS: tuple[tuple[str, str, str, tuple[tuple[str, str, float, bool, bool], ...]], ...] = (
    ('gap', 'Gap', 'gap [mm]', (('gap_mm', COLORS[0], 1.0, False, False),
                                ('true_gap_mm', COLORS[1], 1.2, False, False),
                                ('td_x1_mm', COLORS[2], 1.2, True, False),
                                ('target_mm', COLORS[4], 1.5, False, True))),
    ('command', 'Velocity command', 'velocity [mm/s]',
     (('u_unlimited_mm_s', COLORS[0], 1.0, False, False),
      ('velocity_mm_s', COLORS[1], 1.2, False, False))),
    ('state', 'State', 'state', (('state', COLORS[0], 1.5, False, True),
                                 ('followed', COLORS[2], 6.0, False, True))),
    ('eso_z1', 'ESO z1 and the true gap', 'gap [mm]',
     (('true_gap_mm', COLORS[1], 1.2, False, False),
      ('eso_z1_mm', COLORS[0], 1.0, False, False))),
    ('eso_z2', 'ESO z2 and the true gap rate', '[mm/s]',
     (('true_gap_rate', COLORS[1], 1.0, False, False),
      ('eso_z2', COLORS[0], 1.0, False, False))),
    ('eso_z3', 'ESO z3', '[mm/s²]', (('eso_z3', COLORS[0], 1.0, False, False),)),
)


def asset(name: str) -> str:
    """Return the text of one of the page's files shipped in the package (:data:`ASSETS`)."""
    try:
        return resources.files(__package__).joinpath(name).read_text(encoding='utf-8')
    except (OSError, ValueError) as exc:
        raise BagError(f'the HTML report cannot find its file {name} in the installed '
                       f'ladrc_tools ({exc.__class__.__name__}): reinstall the package '
                       '(or use --no-html)') from None


def _streams(data: ZoomData
             ) -> tuple[list[bytes], list[list[int]], dict[str, Any], dict[str, Any]]:
    """Return the streams, their table ([offset, length] in the blob) and the meta."""
    parts: list[bytes] = []
    table: list[list[int]] = []
    offset = 0

    def put(b: bytes) -> int:
        nonlocal offset
        parts.append(b)
        table.append([offset, len(b)])
        offset += len(b)
        return len(table) - 1

    time = {'stream': put(data.time), 'res': 1e-6}
    curves: dict[str, Any] = {}
    for key, sc in data.curves.items():
        c = sc.curve
        entry: dict[str, Any] = {'label': c.label, 'unit': c.unit, 'res': c.res, 'kind': c.kind}
        if 'raw' in sc.streams:
            entry['raw'] = put(sc.streams['raw'])  # type: ignore[arg-type]
        elif 'index' in sc.streams:
            entry['index'] = put(sc.streams['index'])  # type: ignore[arg-type]
            entry['value'] = put(sc.streams['value'])  # type: ignore[arg-type]
            entry['changes'] = sc.changes
        else:
            entry['levels'] = [put(b) for b in sc.streams['levels']]
            entry['base'] = sc.base_level
        curves[key] = entry
    return parts, table, time, curves


def _base64(parts: list[bytes], chunk: int = 3 << 20) -> Iterator[str]:
    """Yield the base64 of the parts joined, a chunk at a time (multiples of 3 bytes)."""
    carry = b''
    for part in parts:
        buf = carry + part
        cut = len(buf) // chunk * chunk
        for a in range(0, cut, chunk):
            yield base64.b64encode(buf[a:a + chunk]).decode('ascii')
        carry = buf[cut:]
    if carry:
        yield base64.b64encode(carry).decode('ascii')


def _summary(report: dict[str, Any]) -> list[str]:
    m = report.get('metrics', {})

    def num(v: Any, unit: str = '') -> str:
        return f'{v:.4g}{unit}' if isinstance(v, (int, float)) and v == v else 'n/a'

    lines = [str(report.get('outcome', ''))]
    lines += [f'F{k} at {f["t_s"]:.4f} s, from {f["state_before"]}: {f["reason"]}'
              for k, f in enumerate(report.get('faults', []), 1)]
    lines += [f'{report.get("source", "?")}' + (f', scenario {report["scenario"]}'
                                              if report.get('scenario') else ''),
             f'{report.get("duration_s", 0.0):.3f} s, {report.get("ticks", 0)} ticks, '
             f'h = {report.get("h_s", 0.0) * 1e3:.3f} ms',
             f'error against the {report.get("error_against", "?")} gap: '
             f'RMS {num(m.get("error_rms_mm"), " mm")}, max {num(m.get("error_max_mm"), " mm")}',
             f'messages lost (seq gaps): {report.get("messages_lost", 0)}']
    return lines


def page_parts(data: ZoomData, report: dict[str, Any], states: list[str]) -> Iterator[str]:
    """Yield the page's text in parts (written one after the other: no copy of the whole)."""
    streams, table, time, curves = _streams(data)
    plots = []
    for pid, title, ylabel, series in PLOTS:
        present = [{'key': k, 'color': col, 'width': w, 'dash': dash, 'stepped': st}
                   for k, col, w, dash, st in series if k in curves]
        if pid.startswith('eso') and not any(s['key'].startswith('eso') for s in present):
            continue
        if present:
            plots.append({'id': pid, 'title': title, 'y': ylabel, 'series': present})
    meta = {
        'title': f'Report: {report.get("title") or Path(str(report.get("bag", "bag"))).name}',
        'faults': [{'t': f['t_s'], 'label': f'F{k}'}
                   for k, f in enumerate(report.get('faults', []), 1)],
        'summary': _summary(report),
        'n': data.n, 'factor': data.factor, 'auxLevel': data.aux_level,
        'pointsPerPx': POINTS_PER_PX, 'topBuckets': 1024,
        'hS': _finite(report.get('h_s')), 'vMax': _finite(report.get('v_max_mm_s')),
        'states': states, 'time': time, 'curves': curves, 'plots': plots, 'streams': table,
    }
    meta_json = json.dumps(meta, allow_nan=False).replace('</', '<\\/')
    licence = asset('vendor/uplot/LICENSE').replace('*/', '* /')
    csp = ("default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; "
           "img-src data:")
    yield from [
        '<!doctype html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n',
        f'<meta http-equiv="Content-Security-Policy" content="{csp}">\n',
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n',
        f'<title>{_esc(meta["title"])}</title>\n',
        '<style>\n', asset('vendor/uplot/uPlot.min.css'), '\n', asset('html_report.css'),
        '\n</style>\n',
        '<script>\n/* uPlot, vendored from the npm package (ladrc_tools/offline/vendor/uplot):\n',
        licence, '\n*/\n', asset('vendor/uplot/uPlot.iife.min.js'), '\n</script>\n',
        '</head>\n<body>\n',
        f'<h1>{_esc(meta["title"])}</h1>\n<div id="summary"></div>\n',
        '<div id="toolbar"><button id="reset" type="button">whole run</button> '
        '<button id="back" type="button">back</button> <span id="window"></span></div>\n',
        '<p id="status">decoding the data&hellip;</p>\n<div id="plots"></div>\n',
        '<p id="help">Drag across a plot to zoom in, wheel to zoom around the pointer, '
        'shift + wheel to pan, double-click for the whole run. Every sample is drawn once '
        'the window holds at most a few per pixel; wider windows draw the min and max of '
        'each bucket of samples, so no extreme is lost.</p>\n<p id="stored"></p>\n',
        '<script type="application/json" id="ladrc-meta">', meta_json, '</script>\n',
        '<script type="application/octet-stream" id="ladrc-data">']
    yield from _base64(streams)
    yield from ['</script>\n',
                '<script>\n', asset('html_report.js'), '\n</script>\n</body>\n</html>\n']


def _finite(v: Any) -> float | None:
    """Return ``v`` as a float when it is a finite number, else None (strict JSON)."""
    return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else None


def _esc(text: str) -> str:
    return text.replace('&', '&amp;').replace('<', '&lt;').replace('>', '&gt;')


def write_html(data: ZoomData, report: dict[str, Any], states: list[str], path: Path) -> int:
    """Write the page to ``path``; return its size in bytes."""
    size = 0
    with open(path, 'wb') as f:
        for part in page_parts(data, report, states):
            raw = part.encode('utf-8')
            f.write(raw)
            size += len(raw)
    return size
