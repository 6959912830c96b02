"""The zoomable HTML report: its pyramid, its streams, the page in Chromium.

Pure Python: the min/max pyramid keeps a single-sample spike at every level and its levels
equal numpy's min/max over each bucket (fed in slices or whole); the streams give back every
sample at the stated resolution, bit for bit. In headless Chromium (the DevTools protocol,
tests/support/chromium_cdp.py; skipped with the set-up's reason where Chromium is missing):
the report of the showcase renders every plot with no console error and no request, a zoom
into the 50 ms around the sheet edge draws every sample the bag has there, the page's own
pyramid equals :mod:`ladrc_tools.offline.pyramid`'s, spikes show at every zoom, and dragging
across one plot zooms them all.
"""

from __future__ import annotations

import base64
from contextlib import contextmanager
import json
from pathlib import Path
import re
import sys

from ladrc_bags import BagError, open_bag
from ladrc_tools.cli import main as ladrc
from ladrc_tools.offline import html_report, zoom_data
from ladrc_tools.offline.codec import (
    BLOCK,
    QuantEncoder,
    StepEncoder,
    decode,
    decode_steps,
    quantise,
    unvarint,
    varint,
)
from ladrc_tools.offline.html_report import POINTS_PER_PX
from ladrc_tools.offline.pyramid import FACTOR, Pyramid, pyramid
from ladrc_tools.offline.report import REPORT_FIELDS, write_report
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'support'))

from system import require  # noqa: E402

TIMEOUT_S = 300.0  # per browser call: a loaded machine is slow, never wrong


# ---------------------------------------------------------------------------- pure Python

def _feed(p: Pyramid, y: np.ndarray, rng: np.random.Generator) -> None:
    """Feed ``y`` in slices of random sizes (0 included)."""
    a = 0
    while a < y.size:
        k = int(rng.integers(0, 3000))
        p.add(y[a:a + k])
        a += k


def _numpy_level(y: np.ndarray, s: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return min, max and max-first of each bucket of ``s`` samples, with numpy, directly.

    Max-first: the first occurrence of the max is before that of the min (NaN ignored).
    """
    b = np.r_[y, np.full(-y.size % s, np.nan)].reshape(-1, s)  # the last bucket padded
    with np.errstate(invalid='ignore'), pytest.warns(RuntimeWarning) if np.isnan(
            b).all(axis=1).any() else _nothing():
        lo, hi = np.nanmin(b, axis=1), np.nanmax(b, axis=1)
    mf = (np.argmax(np.where(np.isnan(b), -np.inf, b), axis=1)
          < np.argmin(np.where(np.isnan(b), np.inf, b), axis=1))
    return lo, hi, mf & ~np.isnan(b).all(axis=1)


@contextmanager
def _nothing():
    yield


def test_pyramid_keeps_a_single_sample_spike_at_every_level():
    rng = np.random.default_rng(1)
    n = 200_003
    y = 1.0 + 0.005 * rng.standard_normal(n)
    up, down = 123_457, 150_001
    y[up] = 1.8  # one sample: 0.5 ms at 2 kHz
    y[down] = 0.3
    p = Pyramid(base_level=1)
    _feed(p, y, rng)
    levels = p.finish()
    assert [lev.level for lev in levels] == list(range(1, len(levels) + 1))
    assert levels[-1].buckets <= 1024 < levels[-2].buckets
    for lev in levels:
        assert lev.hi[up // lev.samples] == 1.8, lev.level
        assert lev.lo[down // lev.samples] == 0.3, lev.level
        assert 1.8 in lev.pairs() and 0.3 in lev.pairs()
        assert lev.buckets == -(-n // lev.samples)


@pytest.mark.parametrize('base_level', [0, 1, 3])
def test_pyramid_levels_equal_numpy_over_each_bucket(base_level):
    rng = np.random.default_rng(2 + base_level)
    n = 70_001
    y = np.cumsum(rng.standard_normal(n))
    y[1000:1400] = np.nan  # a dropout spanning buckets
    y[5000:5003] = np.nan
    y[20_000:20_064] = np.nan  # exactly one bucket of 64
    y[30_000] = np.inf
    y[:17] = 3.0  # ties: the first occurrence decides the order
    p = Pyramid(base_level=base_level)
    _feed(p, y, rng)
    levels = p.finish()
    whole = pyramid(y, base_level=base_level)
    assert len(levels) == len(whole) >= 2
    for lev, ref in zip(levels, whole, strict=True):
        assert lev.samples == FACTOR ** lev.level
        lo, hi, mf = _numpy_level(y, lev.samples)
        for got in (lev, ref):
            np.testing.assert_array_equal(got.lo, lo, err_msg=f'level {lev.level}')
            np.testing.assert_array_equal(got.hi, hi, err_msg=f'level {lev.level}')
            np.testing.assert_array_equal(got.max_first, mf, err_msg=f'level {lev.level}')
        first = np.where(mf, hi, lo)
        np.testing.assert_array_equal(lev.pairs()[0::2], first)


def test_varints_and_zigzag_round_trip():
    v = np.array([0, 1, 127, 128, 300, 2 ** 35 + 7, 2 ** 63 - 1, 2 ** 64 - 1], dtype=np.uint64)
    np.testing.assert_array_equal(unvarint(varint(v)), v)
    assert varint(np.array([300], dtype=np.uint64)) == bytes([0xAC, 0x02])  # LEB128
    with pytest.raises(ValueError):
        unvarint(b'\x80')


def _series(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    t = np.arange(n) * 0.0005
    gap = np.round(1.0 + 0.2 * np.sin(3 * t) + 0.005 * rng.standard_normal(n), 3)  # 1 µm steps
    gap[5000:5100] = np.nan
    gap[90_000] = np.inf
    gap[90_001] = -np.inf
    gap[90_002] = 1e300  # beyond the codec's range: stored as +inf
    return {'time': t + 1234.5, 'gap': gap, 'smooth': 2.0 + 0.3 * np.sin(t),
            'noise': 40.0 * rng.standard_normal(n), 'huge': 1e9 * rng.standard_normal(n)}


@pytest.mark.parametrize('res', [1e-6, 1e-4, 1e-3, 1.0])
def test_streams_round_trip_every_sample_at_the_resolution(res):
    rng = np.random.default_rng(7)
    n = 2 * BLOCK + 12_345  # blocks of both orders, a short last one
    for name, y in _series(rng, n).items():
        enc = QuantEncoder(res)
        a = 0
        while a < n:  # slices across block boundaries
            k = int(rng.integers(1, BLOCK // 2))
            enc.add(y[a:a + k])
            a += k
        data = enc.finish()
        back = decode(data, res)
        q, kind = quantise(y, res)
        expect = np.where(kind == 0, q * res, y)
        expect[kind == 2] = np.inf  # NaN stays NaN; beyond the range: an infinity of its sign
        expect[kind == 3] = -np.inf
        # bit for bit (NaN where NaN): the value round(y / res) * res
        assert back.dtype == np.float64 and back.size == n
        np.testing.assert_array_equal(back.view(np.int64)[kind == 0],
                                      (q * res).view(np.int64)[kind == 0], err_msg=name)
        np.testing.assert_array_equal(back, expect, err_msg=name)
        finite = np.isfinite(y) & (np.abs(y / res) <= 2 ** 50)
        assert np.all(np.abs(back[finite] - y[finite]) <= res / 2 * (1 + 1e-9) + 1e-12 * np.abs(
            y[finite])), name


def test_step_stream_keeps_every_change():
    rng = np.random.default_rng(3)
    n = 100_000
    state = np.repeat(rng.integers(0, 6, 400), 250).astype(float)
    state[777] = 5.0  # a one-sample excursion
    state[50_000:50_010] = np.nan
    enc = StepEncoder(1.0)
    for a in range(0, n, 7_777):
        enc.add(state[a:a + 7_777])
    steps = decode_steps(*enc.finish(), 1.0)
    np.testing.assert_array_equal(steps.expand(n), state)
    assert steps.index[0] == 0 and np.all(np.diff(steps.index) > 0)
    assert enc.changes == steps.index.size < 1000


def test_the_blob_is_base64_of_the_streams_joined_whatever_the_chunk():
    rng = np.random.default_rng(4)
    parts = [rng.bytes(int(k)) for k in rng.integers(0, 50, 40)]
    whole = base64.b64encode(b''.join(parts)).decode('ascii')
    for chunk in (3, 6, 30, 3 << 20):
        assert ''.join(html_report._base64(parts, chunk)) == whole


def test_a_missing_page_file_is_one_line_naming_it():
    with pytest.raises(BagError, match=r'cannot find its file nope\.js .*--no-html'):
        html_report.asset('nope.js')
    for name in html_report.ASSETS:  # shipped with the package
        assert html_report.asset(name)


def test_aux_level_keeps_the_finest_level_that_fits():
    assert zoom_data.aux_level(400_000) == 0  # every sample up to 200 s at 2 kHz
    assert zoom_data.aux_level(400_001) == 1
    assert zoom_data.aux_level(3_600 * 2_000) == 3  # an hour: buckets of 64 samples (32 ms)
    for n in (10, 10 ** 6, 10 ** 8):
        lev = zoom_data.aux_level(n)
        assert lev == 0 or 2 * -(-n // FACTOR ** lev) <= zoom_data.AUX_VALUES_MAX


# ------------------------------------------------------------------------- the bag, the page

@pytest.fixture(scope='module')
def showcase(tmp_path_factory) -> dict:
    """Return the showcase headless (25 s: an edge, a target change), its report, its series."""
    root = tmp_path_factory.mktemp('html_report')
    bag = root / 'showcase'
    assert ladrc(['simulate', 'showcase', '-o', str(bag)]) == 0
    out = write_report(bag, root / 'report')
    with open_bag(bag) as b:
        st = b.columns('follow/status', list(REPORT_FIELDS))
    return {'root': root, 'bag': bag, 'html': out / 'report.html', 'status': st,
            'report': json.loads((out / 'report.json').read_text())}


def _q(y: np.ndarray, res: float) -> np.ndarray:
    """Return the values as the page holds them (the stream's resolution)."""
    q, kind = quantise(y, res)
    return np.where(kind == 0, q * res, np.nan)


def _t(st: dict) -> np.ndarray:
    return _q(st['stamp_s'] - st['stamp_s'][0], zoom_data.TIME_RES_S)


def test_report_keeps_its_outputs_and_adds_the_page(showcase, tmp_path):
    out = write_report(showcase['bag'], tmp_path / 'plain', html=False)
    names = sorted(p.name for p in out.iterdir())
    assert names == ['command.png', 'eso.png', 'gap.png', 'report.json', 'report.md',
                     'state.png']
    html_out = showcase['html'].parent
    assert sorted(p.name for p in html_out.iterdir()) == sorted(names + ['report.html'])
    for name in ('report.json', 'report.md'):  # the same figures either way
        assert (out / name).read_text() == (html_out / name).read_text().replace(
            str(html_out), str(out))
    text = showcase['html'].read_text(encoding='utf-8')
    assert 'uPlot' in text and 'The MIT License' in text and 'Leon Sorokin' in text
    assert not re.search(r'(src|href)="https?:', text), 'the page must load nothing'
    # the CLI: --no-html, and no required flag
    assert ladrc(['report', str(showcase['bag']), '-o', str(tmp_path / 'cli'), '-q',
                  '--no-html']) == 0
    assert not (tmp_path / 'cli' / 'report.html').exists()


# ------------------------------------------------------------------------------- Chromium

@pytest.fixture(scope='module')
def browser(tmp_path_factory):
    """One headless Chromium for the module (ended by its process group's id)."""
    require('chromium')
    from chromium_cdp import Chromium

    with Chromium(tmp_path_factory.mktemp('chromium') / 'profile') as c:
        yield c


def _open(c, html: Path) -> list[str]:
    """Open a page, wait for every plot drawn; return the plot ids."""
    c.events.clear()
    c.navigate(html.resolve().as_uri(), TIMEOUT_S)
    return c.evaluate('window.ladrcReport.ready', TIMEOUT_S)


def _zoom(c, t0: float, t1: float, plot: str, key: str) -> dict:
    t0, t1 = float(t0), float(t1)
    return c.evaluate(f'window.ladrcReport.zoom({t0!r}, {t1!r}).then(() => '
                      f'window.ladrcReport.visible({plot!r}, {key!r}))', TIMEOUT_S)


def _values(c, plot: str, key: str) -> tuple[np.ndarray, np.ndarray]:
    v = c.evaluate(f'window.ladrcReport.values({plot!r}, {key!r})', TIMEOUT_S)
    return np.array(v['x'], float), np.array([np.nan if y is None else y for y in v['y']], float)


def _edge_window(st: dict, t: np.ndarray) -> tuple[float, float, int]:
    """Return a 50 ms window around the sheet edge (the largest jump of the gap), its index."""
    gap = st['gap_mm'].astype(float)
    following = st['state'] >= 3
    jump = np.abs(np.diff(gap))
    jump[~following[1:]] = 0.0
    jump[np.isnan(jump)] = 0.0
    k = int(np.argmax(jump)) + 1
    h = float(np.median(np.diff(t)))
    return float(t[k] - 0.02 - h / 2), float(t[k] + 0.03 - h / 2), k


def test_page_renders_every_plot_without_console_errors_or_requests(browser, showcase):
    require('chromium')
    plots = _open(browser, showcase['html'])
    assert plots == ['gap', 'command', 'state', 'eso_z1', 'eso_z2', 'eso_z3']
    draws = browser.evaluate('Object.values(window.ladrcReport.plots).map((p) => p.draws)')
    assert all(d >= 1 for d in draws), draws
    canvases = browser.evaluate('document.querySelectorAll("#plots canvas").length')
    assert canvases == len(plots)
    assert browser.evaluate('window.ladrcReport.errors') == []
    assert browser.console_errors() == [], browser.console_log()
    assert browser.requests() == [showcase['html'].resolve().as_uri()]  # nothing else fetched


def test_zoom_into_the_edge_shows_every_sample(browser, showcase):
    require('chromium')
    st = showcase['status']
    t = _t(st)
    _open(browser, showcase['html'])
    t0, t1, k = _edge_window(st, t)
    inside = (t >= t0) & (t <= t1)
    assert 95 <= inside.sum() <= 105 and inside[k]
    for plot, key, res in (('gap', 'gap_mm', 1e-4), ('command', 'velocity_mm_s', 1e-3)):
        vis = _zoom(browser, t0, t1, plot, key)
        assert vis['level'] == 0, vis
        assert vis['points'] == int(inside.sum()), vis
        x, y = _values(browser, plot, key)
        np.testing.assert_array_equal(x, t[inside])
        np.testing.assert_array_equal(y, _q(st[key].astype(float), res)[inside])
    assert browser.console_errors() == [], browser.console_log()


def test_the_page_pyramid_is_the_python_one_and_spikes_show_at_every_zoom(browser, showcase):
    require('chromium')
    st = showcase['status']
    t = _t(st)
    _open(browser, showcase['html'])
    gap = _q(st['gap_mm'].astype(float), 1e-4)
    for lev in pyramid(gap, base_level=1):
        got = browser.evaluate(f'window.ladrcReport.pyramid("gap_mm", {lev.level})', TIMEOUT_S)
        assert got is not None and got['samples'] == lev.samples
        pairs = np.column_stack([np.array(got['first'], float),
                                 np.array(got['second'], float)]).ravel()
        np.testing.assert_array_equal(np.nan_to_num(pairs, nan=-9e9),
                                      np.nan_to_num(lev.pairs(), nan=-9e9), err_msg=lev.level)
    # the command's extremes (single ticks) at the whole run, 5 s and 0.5 s around them
    vel = _q(st['velocity_mm_s'].astype(float), 1e-3)
    for k in (int(np.nanargmax(vel)), int(np.nanargmin(vel))):
        for half in (None, 2.5, 0.25):
            a, b = (t[0], t[-1]) if half is None else (t[k] - half, t[k] + half)
            vis = _zoom(browser, a, b, 'command', 'velocity_mm_s')
            width = browser.evaluate('window.ladrcReport.plots.command.u.over.clientWidth')
            assert vis['points'] <= POINTS_PER_PX * width + 4, vis
            if half is None:
                assert vis['level'] >= 1, vis
            _, y = _values(browser, 'command', 'velocity_mm_s')
            assert vel[k] in y, (half, vis)
    assert browser.console_errors() == [], browser.console_log()


def test_dragging_across_one_plot_zooms_every_plot(browser, showcase):
    require('chromium')
    _open(browser, showcase['html'])
    browser.evaluate('window.ladrcReport.plots.gap.u.over.scrollIntoView()')
    box = browser.evaluate('(() => { const r = window.ladrcReport.plots.gap.u.over'
                           '.getBoundingClientRect(); return [r.left, r.top, r.width, '
                           'r.height]; })()')
    x0, y0, w, h = box
    ya = y0 + h / 2
    for kind, x, buttons in (('mousePressed', x0 + 0.4 * w, 1), ('mouseMoved', x0 + 0.45 * w, 1),
                             ('mouseMoved', x0 + 0.5 * w, 1), ('mouseReleased', x0 + 0.5 * w, 0)):
        browser.call('Input.dispatchMouseEvent', {'type': kind, 'x': x, 'y': ya,
                                                  'button': 'left', 'buttons': buttons,
                                                  'clickCount': 1})
    windows = browser.evaluate(
        'new Promise((r) => setTimeout(r, 200)).then(() => [window.ladrcReport.window, '
        'Object.values(window.ladrcReport.plots).map((p) => [p.u.scales.x.min, '
        'p.u.scales.x.max])])', TIMEOUT_S)
    (a, b), scales = windows
    duration = showcase['report']['duration_s']
    assert 0.05 * duration < b - a < 0.15 * duration  # a tenth of the width was dragged
    assert all(s == [a, b] for s in scales), scales  # linked: every plot shows that window
    assert browser.console_errors() == [], browser.console_log()


def test_pyramid_only_curves_in_the_page(browser, showcase, monkeypatch):
    """A long run's ESO and TD are kept as min/max levels only: the page draws them so."""
    require('chromium')
    monkeypatch.setattr(zoom_data, 'AUX_VALUES_MAX', 20_000)  # the showcase's 50 000 ticks
    out = write_report(showcase['bag'], showcase['root'] / 'report_aux')
    _open(browser, out / 'report.html')
    st = showcase['status']
    t = _t(st)
    t0, t1, _ = _edge_window(st, t)
    vis = _zoom(browser, t0, t1, 'gap', 'gap_mm')
    assert vis['level'] == 0 and vis['points'] == int(((t >= t0) & (t <= t1)).sum())
    td = browser.evaluate('window.ladrcReport.visible("gap", "td_x1_mm")')
    assert td['level'] == 2 and 0 < td['points'] < vis['points']  # buckets of 16 samples
    z2 = _q(np.where(np.isin(st['state'], (3, 4)), st['eso_z2'].astype(float), np.nan), 1e-3)
    vis = _zoom(browser, float(t[0]), float(t[-1]), 'eso_z2', 'eso_z2')
    _, y = _values(browser, 'eso_z2', 'eso_z2')
    assert np.nanmax(y) == np.nanmax(z2) and np.nanmin(y) == np.nanmin(z2)
    assert browser.console_errors() == [], browser.console_log()
