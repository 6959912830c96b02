"""The zoomable HTML report of a long bag: size, report time with and without it, render time.

    scripts/in-env python bench/html_report.py [--bag DIR] [--seconds 3600] [--out DIR]
                                               [--rounds N]

Without ``--bag``, a headless run of ``--seconds`` (the bag benches' shift: follow at 1 mm over
a 0.3 mm, 0.5 Hz sine sheet, the shipped controller; ``bench/bag_scale.py``) is written as a
bag first (``--out``: there, kept; else in a temporary folder). Then ``ladrc report BAG`` (with
``report.html``) and ``ladrc report BAG --no-html``, alternating, ``--rounds`` times, each in
its own process (wall time, CPU time and that process's peak RSS), and, where Chromium is
installed, the page opened in headless Chromium (tests/support/chromium_cdp.py): the time from
the navigation's start to every plot drawn (the page's ``performance.now()`` then), then a zoom
to the 50 ms window from the middle of the run, where the page must draw every sample of the
measured gap.

Last line: JSON with ``seconds``, ``ticks``, ``bag_bytes``, ``html_bytes``, ``write_s`` (the
report with its HTML), ``write_cpu_s``, ``write_peak_rss_mib``, ``report_no_html_s``,
``report_no_html_cpu_s``, ``report_no_html_peak_rss_mib`` (each the least of the rounds: a
shared machine only slows a run down), ``rounds`` (every round's wall and CPU times),
``html_parts`` (compressed bytes of each curve's streams, before base64),
``chromium_render_s`` (navigation start to every plot drawn; null without Chromium),
``chromium_wall_s`` (the same, measured from here), ``page_timing`` (the page's base64,
inflate, decode and draw times [ms]), ``console_errors``, ``full_view_level``,
``level_50ms`` (0: every sample), ``points_in_50ms_window`` and ``samples_in_window`` (the
measured gap's points drawn in that window and the bag's samples in it: equal),
``command_points_in_50ms_window`` and ``zoom_s``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import re
import resource
import shutil
import sys
import tempfile
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'ros2_ws' / 'src' / 'ladrc_tools'))
sys.path.insert(0, str(ROOT / 'ros2_ws' / 'src' / 'ladrc_bags'))
sys.path.insert(0, str(ROOT / 'tests' / 'support'))

from ladrc_bags import open_bag  # noqa: E402


def _headless_bag(path: Path, seconds: float) -> None:
    from bag_read import _headless_bag as write  # the bag benches' shift (bag_scale)

    write(path, seconds)


def _html_parts(html: Path) -> dict[str, int]:
    """Return the compressed bytes of each curve's streams, from the page's meta."""
    text = html.read_text(encoding='utf-8')
    m = re.search(r'<script type="application/json" id="ladrc-meta">(.*?)</script>', text, re.S)
    meta = json.loads(m.group(1).replace('<\\/', '</'))
    size = [length for _, length in meta['streams']]
    out = {'t_s': size[meta['time']['stream']]}
    for key, c in meta['curves'].items():
        ids = [c[k] for k in ('raw', 'index', 'value') if k in c] + c.get('levels', [])
        out[key] = sum(size[i] for i in ids)
    return out


def _timed(args: list[str]) -> dict:
    """Run ``ladrc ARGS`` in its own process: bag_scale's wall time and peak RSS, CPU time."""
    from bag_scale import _tool

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    r = _tool(args)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    r['cpu_s'] = round(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime, 2)
    return r


def _browser(html: Path, t_s: np.ndarray, work: Path) -> dict:
    """Open the page in headless Chromium: render time, the 50 ms zoom."""
    from chromium_cdp import Chromium

    out: dict = {}
    with Chromium(work / 'chromium-profile') as c:
        t0 = time.perf_counter()
        c.navigate(html.resolve().as_uri(), timeout_s=600)
        c.evaluate('window.ladrcReport.ready', timeout_s=600)
        out['chromium_wall_s'] = round(time.perf_counter() - t0, 3)
        timing = c.evaluate('window.ladrcReport.timing')
        out['chromium_render_s'] = round(timing['ready_ms'] / 1e3, 3)
        out['page_timing'] = {k: round(v, 1) for k, v in timing.items()}
        out['full_view_level'] = c.evaluate('window.ladrcReport.level')
        mid = float(t_s[-1]) / 2
        w0, w1 = mid, mid + 0.05
        t1 = time.perf_counter()
        gap = c.evaluate(f'window.ladrcReport.zoom({w0!r}, {w1!r}).then(() => '
                         'window.ladrcReport.visible("gap", "gap_mm"))', timeout_s=600)
        out['zoom_s'] = round(time.perf_counter() - t1, 3)
        cmd = c.evaluate('window.ladrcReport.visible("command", "velocity_mm_s")')
        out['level_50ms'] = gap['level']
        out['points_in_50ms_window'] = gap['points']
        out['samples_in_window'] = int(np.count_nonzero((t_s >= w0) & (t_s <= w1)))
        out['command_points_in_50ms_window'] = cmd['points']
        out['console_errors'] = c.console_errors()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--bag', default=None, help='bag (default: write a headless one)')
    ap.add_argument('--seconds', type=float, default=3600.0, help='headless bag length [s]')
    ap.add_argument('--out', default=None, help='write the headless bag here (kept)')
    ap.add_argument('--rounds', type=int, default=1,
                    help='report with and without the HTML, alternating, this many times')
    a = ap.parse_args()
    from ladrc_tools.offline.codec import quantise
    from ladrc_tools.offline.zoom_data import TIME_RES_S

    tmp = Path(tempfile.mkdtemp(prefix='html-report-bench-'))
    try:
        if a.bag:
            bag = Path(a.bag)
        else:
            bag = Path(a.out) if a.out else tmp / 'shift'
            t0 = time.perf_counter()
            _headless_bag(bag, a.seconds)
            print(f'bag: {a.seconds:.0f} s written in {time.perf_counter() - t0:.0f} s',
                  file=sys.stderr, flush=True)
        with open_bag(bag) as b:
            stamp = b.columns('follow/status', ['stamp_s'])['stamp_s']
        t_s = quantise(stamp - stamp[0], TIME_RES_S)[0] * TIME_RES_S  # the page's time axis
        files = [bag] if bag.is_file() else list(bag.iterdir())
        result: dict = {'seconds': round(float(t_s[-1]), 3), 'ticks': int(t_s.size),
                        'bag_bytes': sum(f.stat().st_size for f in files)}
        runs: dict[str, list[dict]] = {'with': [], 'without': []}
        for k in range(max(1, a.rounds)):
            for name, extra in (('with', []), ('without', ['--no-html'])):
                out = tmp / f'{name}{k}'
                r = _timed(['report', str(bag), '-o', str(out), '-q', *extra])
                print(f'ladrc report ({name} html, round {k + 1}): {r["wall_s"]} s, '
                      f'CPU {r["cpu_s"]} s, {r["peak_rss_mib"]} MiB', file=sys.stderr,
                      flush=True)
                if r['rc'] != 0:
                    raise SystemExit(f'ladrc report ({name} html) exit {r["rc"]}')
                runs[name].append(r)
                if k or name == 'without':
                    shutil.rmtree(out, ignore_errors=True)
        html = tmp / 'with0' / 'report.html'

        def least(name: str, key: str) -> float | None:
            values = [r[key] for r in runs[name] if r[key] is not None]
            return min(values) if values else None

        result.update({
            'html_bytes': html.stat().st_size, 'write_s': least('with', 'wall_s'),
            'write_cpu_s': least('with', 'cpu_s'),
            'write_peak_rss_mib': least('with', 'peak_rss_mib'),
            'report_no_html_s': least('without', 'wall_s'),
            'report_no_html_cpu_s': least('without', 'cpu_s'),
            'report_no_html_peak_rss_mib': least('without', 'peak_rss_mib'),
            'rounds': [{'with_s': w['wall_s'], 'with_cpu_s': w['cpu_s'],
                        'without_s': o['wall_s'], 'without_cpu_s': o['cpu_s']}
                       for w, o in zip(runs['with'], runs['without'], strict=True)],
            'html_parts': _html_parts(html)})
        browser = {k: None for k in ('chromium_render_s', 'chromium_wall_s', 'page_timing',
                                     'full_view_level', 'level_50ms', 'points_in_50ms_window',
                                     'samples_in_window', 'command_points_in_50ms_window',
                                     'zoom_s', 'console_errors')}
        if shutil.which('chromium'):
            browser.update(_browser(html, t_s, tmp))
        else:
            print('chromium is not installed: no browser figures', file=sys.stderr)
        result.update(browser)
        print(json.dumps(result))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == '__main__':
    main()
