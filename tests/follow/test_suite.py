"""The control-quality suite (``ladrc suite``): table files, seed columns, real differences."""

from __future__ import annotations

import csv
import json
import math

from ladrc_tools.cli import main
from ladrc_tools.offline import suite
import numpy as np
import pytest

SCENARIOS = ('thin_sheet', 'sine_5hz')
VARIANTS = ('pid', 'ladrc')


@pytest.fixture(scope='module')
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp('suite')
    code = main(['suite', '--quick', '-q', '--jobs', '2', '--scenarios', ','.join(SCENARIOS),
                 '--variants', ','.join(VARIANTS), '-o', str(out)])
    assert code == 0
    return out, json.loads((out / 'suite.json').read_text())['rows']


def test_quick_suite_writes_one_row_per_case_with_seed_columns(quick_run):
    out, rows = quick_run
    assert [(r['scenario'], r['variant']) for r in rows] == [
        (s, v) for s in SCENARIOS for v in VARIANTS]
    with open(out / 'suite.csv', newline='') as f:
        table = list(csv.DictReader(f))
    assert len(table) == len(rows)
    assert {'seed_metric', 'seed_value', 'seed_note', 'chatter_mm_s', 'amp_ratio',
            'deviation_min_mm', 'deviation_max_mm'} <= set(table[0])
    md = (out / 'suite.md').read_text()
    assert 'notes (measured)' in md and '-1…+1.49' in md and '-0.7…+0.7' in md
    thin = {r['variant']: r for r in rows if r['scenario'] == 'thin_sheet'}
    assert thin['pid']['seed_value'] == '-1…+1.49'
    assert thin['ladrc']['seed_value'] == '-0.7…+0.7'
    assert all(r['final_state'] != 'FAULT' and r['collisions'] == 0 for r in rows)


@pytest.fixture(scope='module')
def seed_run(tmp_path_factory):
    """Run the thin sheet as the notes ran it: without the edge verification the seed lacks."""
    out = tmp_path_factory.mktemp('suite_seed')
    code = main(['suite', '--quick', '-q', '--jobs', '2', '--scenarios', 'thin_sheet',
                 '--variants', ','.join(VARIANTS), '--law-only', '-o', str(out)])
    assert code == 0
    return out, json.loads((out / 'suite.json').read_text())['rows']


def test_ladrc_deviation_range_on_the_thin_sheet_is_smaller_than_the_pid(seed_run, quick_run):
    # notes §5.3.5: LADRC -0.7..+0.7 mm against the PID's -1..+1.49 mm; the quick cut (3 s)
    # still contains the flick at 1.5 s.
    thin = {r['variant']: r for r in seed_run[1]}
    assert '--law-only' in (seed_run[0] / 'suite.md').read_text()
    rng = {v: r['deviation_max_mm'] - r['deviation_min_mm'] for v, r in thin.items()}
    assert thin['ladrc']['ladrc_share'] > 0.9  # the LADRC really ran (not machining)
    assert thin['pid']['ladrc_share'] == 0.0
    assert rng['ladrc'] < 0.9 * rng['pid'], rng
    # shipped: the gas pushes the plate down 0.9 mm at up to 21 mm/s when it comes on; that
    # sinks below the verified level faster than it can be verified, so the nozzle holds
    # (docs/safety.md): a wider range above the target, never closer, no fault
    _, rows = quick_run
    shipped = {r['variant']: r for r in rows if r['scenario'] == 'thin_sheet'}
    for v in VARIANTS:
        assert shipped[v]['deviation_max_mm'] > thin[v]['deviation_max_mm']
        assert shipped[v]['deviation_min_mm'] > thin[v]['deviation_min_mm'] - 0.05
        assert shipped[v]['final_state'] != 'FAULT' and shipped[v]['collisions'] == 0


def test_amplitude_at_recovers_a_sine_and_chatter_ignores_slow_motion():
    h = 0.0005
    t = np.arange(4000) * h                     # 2 s = 10 whole periods at 5 Hz
    x = 0.3 * np.sin(2 * np.pi * 5.0 * t + 0.4) + 0.1
    assert suite.amplitude_at(x, 5.0, h) == pytest.approx(0.3, rel=1e-9)
    slow = 10.0 * np.sin(2 * np.pi * 2.0 * t)  # 2 Hz: far below the 20 Hz corner
    fast = 0.5 * np.sin(2 * np.pi * 200.0 * t)  # RMS 0.5/sqrt(2), far above it
    window = np.zeros(t.size, dtype=bool)
    window[1000:3000] = True
    assert suite.chatter_rms(slow, window, h) < 1e-3
    assert suite.chatter_rms(slow + fast, window, h) == pytest.approx(0.5 / math.sqrt(2),
                                                                        rel=0.02)


def test_bad_names_are_one_line_errors(capsys):
    assert main(['suite', '--scenarios', 'no_such_scenario', '-q']) == 2
    assert "unknown scenario 'no_such_scenario'" in capsys.readouterr().err
    assert main(['suite', '--variants', 'ladrc,pdi', '-q']) == 2
    assert 'unknown variant(s) pdi' in capsys.readouterr().err
