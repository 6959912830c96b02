"""The fleet tools: provenance, the generated fleet, flags, tables, cache, bad bags.

One small fleet is generated once (4 machines x 3 days x 1 bag, seed 7: not the seed the
rules' limits were set on) and read on a local Dask cluster of one worker process.
"""

from __future__ import annotations

import json
from pathlib import Path
import shutil
import subprocess
import sys

from ladrc_bags import open_bag
from ladrc_bags.provenance import (
    MACHINE_KEY,
    PARAMS_KEY,
    START_KEY,
    param_hash,
    read_provenance,
)
from ladrc_fleet.bag_task import bag_row
from ladrc_fleet.discover import find_bags
from ladrc_fleet.generate import FleetSpec, plan, write_bag, write_truth
from ladrc_fleet.run import run_fleet
from ladrc_tools.offline.report import analyse
import pytest

EXPECTED_RULE = {'gain_drift': 'sensor_gain', 'slow_axis': 'slow_axis',
                 'noisy_sensor': 'sensor_noise'}


@pytest.fixture(scope='module')
def fleet(tmp_path_factory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp('fleet') / 'bags'
    spec = FleetSpec(machines=4, days=3, bags_per_day=1, bag_s=6.0, seed=7, change_day=2)
    fp = plan(spec)
    for item in fp.bags:
        write_bag(item, root)
    write_truth(fp, root)
    return root, fp.truth


@pytest.fixture(scope='module')
def result(fleet, tmp_path_factory):
    root, _ = fleet
    out = tmp_path_factory.mktemp('out') / 'fleet'
    return out, run_fleet([str(root)], out, workers=1)


def test_a_generated_bag_says_where_it_comes_from_and_carries_no_truth(fleet):
    root, truth = fleet
    bag_dir = sorted((root / 'cutter-01').iterdir())[0]
    with open_bag(bag_dir) as bag:
        prov = read_provenance(bag)
        assert not bag.has('sim/truth')
        assert prov.machine_id == 'cutter-01' and prov.fallback == ()
        assert prov.start_utc.startswith(truth['spec']['first_day'])
        assert prov.param_hash == param_hash(
            next(m for _, m in bag.messages('run/parameters')).data)
        assert bag.custom_data[MACHINE_KEY] == 'cutter-01'


def test_an_older_bag_falls_back_per_key(fleet, tmp_path):
    root, _ = fleet
    old = tmp_path / 'old'
    shutil.copytree(sorted((root / 'cutter-02').iterdir())[0], old)
    meta = old / 'metadata.yaml'
    text = meta.read_text()
    for key in (MACHINE_KEY, START_KEY, PARAMS_KEY, 'ladrc.version'):
        text = '\n'.join(line for line in text.splitlines() if key not in line) + '\n'
    meta.write_text(text)
    with open_bag(old) as bag:
        prov = read_provenance(bag)
        params = next(m for _, m in bag.messages('run/parameters')).data
    assert prov.machine_id == 'unknown' and prov.start_utc == '' and prov.day == 'unknown'
    assert prov.param_hash == param_hash(params)  # from the run/parameters text
    assert set(prov.fallback) == {'machine_id', 'start_utc', 'param_hash', 'version'}


def test_every_degraded_machine_is_flagged_with_its_rule_and_no_healthy_one(fleet, result):
    _, truth = fleet
    _, res = result
    flagged: dict[str, set[str]] = {}
    for f in res.flags:
        flagged.setdefault(f['machine_id'], set()).add(f['rule'])
    for machine, how in truth['degraded'].items():
        assert EXPECTED_RULE[how] in flagged.get(machine, set()), (machine, how, flagged)
    assert set(flagged) == set(truth['degraded']), flagged
    assert res.summary['ok'] == 12 and res.summary['failed'] == 0


def test_the_parameter_change_is_found_on_every_machine(fleet, result):
    out, _ = result
    data = json.loads((out / 'fleet.json').read_text())
    changes = data['param_changes']
    assert sorted(c['machine_id'] for c in changes) == [f'cutter-0{k}' for k in (1, 2, 3, 4)]
    assert all(c['at'].startswith('2026-11-04') and c['bags_before'] == 2
               and c['bags_after'] == 1 for c in changes)


def test_a_bags_figures_in_the_table_equal_the_report_on_that_bag(fleet, result):
    import pyarrow.parquet as pq

    out, _ = result
    table = pq.read_table(out / 'bags.parquet').to_pylist()
    assert len(table) == 12
    row = next(r for r in table if '/cutter-03/' in r['bag'])
    with open_bag(row['bag']) as bag:
        report, _ = analyse(bag)
    m = report['metrics']
    assert row['error_rms_mm'] == m['error_rms_mm']
    assert row['error_max_mm'] == m['error_max_mm']
    assert row['ticks'] == report['ticks'] and row['duration_s'] == report['duration_s']
    assert row['void_lock_count'] == report['holds'].get('void_lock', {}).get('count', 0)
    days = pq.read_table(out / 'machine_days.parquet').to_pylist()
    assert len(days) == 12 and {d['bags'] for d in days} == {1}
    assert (out / 'heatmap.png').stat().st_size > 0 and (out / 'fleet.md').is_file()


def test_a_rerun_computes_only_new_bags_whatever_their_path(fleet, result, tmp_path):
    root, _ = fleet
    out, _ = result
    moved = tmp_path / 'moved'
    shutil.copytree(sorted((root / 'cutter-04').iterdir())[0], moved / 'a_copy')
    again = run_fleet([str(root), str(moved)], out, workers=1)
    assert again.summary['computed'] == 0 and again.summary['cached'] == 13
    spec = FleetSpec(machines=4, days=1, bags_per_day=1, bag_s=6.0, seed=99)
    write_bag(plan(spec).bags[0], moved)
    third = run_fleet([str(root), str(moved)], out, workers=1)
    assert third.summary['computed'] == 1 and third.summary['cached'] == 13


def test_bad_bags_are_rows_with_their_reason_and_the_exit_code_says_so(fleet, tmp_path):
    root, _ = fleet
    tree = tmp_path / 'tree'
    good = sorted((root / 'cutter-01').iterdir())[0]
    shutil.copytree(good, tree / 'good')
    (tree / 'foreign').mkdir()
    (tree / 'foreign' / 'metadata.yaml').write_text('not: [a bag\n')
    trunc = tree / 'truncated'
    shutil.copytree(good, trunc)
    mcap = next(trunc.glob('*.mcap'))
    mcap.write_bytes(mcap.read_bytes()[:4000])
    (tree / '.writing.partial').mkdir()
    (tree / '.writing.partial' / 'metadata.yaml').write_text('x: 1\n')
    assert [p.name for p in find_bags([str(tree)]).writing] == ['.writing.partial']
    row = bag_row(tree / 'foreign')
    assert row['status'] == 'error' and 'foreign' in row['error']
    out = tmp_path / 'out'
    proc = subprocess.run([sys.executable, '-m', 'ladrc_tools.cli', 'fleet', str(tree), '-o',
                           str(out), '--workers', '1'], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 1, proc.stderr
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary['ok'] == 1 and summary['failed'] == 2 and summary['writing'] == 1
    md = (out / 'fleet.md').read_text()
    assert 'foreign' in md and 'truncated' in md and '.writing.partial' in md
    bad = subprocess.run([sys.executable, '-m', 'ladrc_tools.cli', 'fleet', str(tree), '-o',
                          str(good)], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1
    assert 'Traceback' not in bad.stderr
    gen = subprocess.run([sys.executable, '-m', 'ladrc_tools.cli', 'fleet-gen',
                          str(tmp_path / 'gen'), '--days', '0'], capture_output=True,
                         text=True, timeout=60)
    assert gen.returncode == 2 and gen.stderr.count('\n') == 1 and 'days = 0' in gen.stderr
    assert not (tmp_path / 'gen').exists() and not (tmp_path / '.gen.partial').exists()


def test_the_recorder_writes_machine_start_version_and_the_first_parameter_sets_hash(tmp_path):
    from ladrc_bags.recorder_node import Recorder
    from ladrc_bags.typestore import ladrc_typestore
    from ladrc_bags.writer import string_msg

    store = ladrc_typestore()

    def cdr(text: str) -> bytes:
        return bytes(store.serialize_cdr(string_msg(text, store), 'std_msgs/msg/String'))

    rec = Recorder(tmp_path / 'bag', machine_id='cutter-17')
    rec.enqueue('run/parameters', cdr('law:\n  kp: 12.0\n'), 1_800_000_000_000_000_000)
    rec.enqueue('run/parameters', cdr('law:\n  kp: 20.0\n'), 1_800_000_001_000_000_000)
    rec.close()
    with open_bag(tmp_path / 'bag') as bag:
        prov = read_provenance(bag)
    assert prov.machine_id == 'cutter-17' and prov.fallback == ()
    assert prov.param_hash == param_hash('law:\n  kp: 12.0\n')  # the set it started with
    assert prov.start_utc.endswith('Z') and prov.version


def test_a_sweep_in_parts_on_the_engine_equals_the_sweep_on_one_core():
    from ladrc_follow.control.params import ControllerParams
    from ladrc_tools.offline.engine import client
    from ladrc_tools.offline.tune import sweep, sweep_on

    base = ControllerParams()
    args = (base, [30.0, 80.0, 150.0], [4.0, 12.0, 24.0], [0.8, 1.2], ['step', 'sine_5hz'])
    one = sweep(*args)
    with client(workers=1) as c:
        parts = sweep_on(c, *args, chunk=5)  # 18 points in 4 parts
    assert [x.point for x in parts] == [x.point for x in one]
    assert [x.scores for x in parts] == [x.scores for x in one]  # bit for bit
    assert [x.front for x in parts] == [x.front for x in one] and any(x.front for x in one)
    assert [x.rejected for x in parts] == [x.rejected for x in one]
    assert all(x.params is None for x in parts) and any(x.passed for x in parts)


def test_the_front_is_the_set_no_other_point_beats_in_every_score():
    from ladrc_tools.offline.tune import Candidate, _dominates, mark_front
    import numpy as np

    rng = np.random.default_rng(3)
    cands = []
    for v in np.round(rng.uniform(0, 1, (400, 3)), 1):  # rounded: ties and equal points
        c = Candidate(0.0, 0.0, 0.0, 0.0, None, passed=True)
        c.scores = dict(zip(('a', 'b', 'c'), map(float, v), strict=True))
        cands.append(c)
    mark_front(cands)
    brute = [not any(_dominates(o, c) for o in cands) for c in cands]
    assert [c.front for c in cands] == brute and 0 < sum(brute) < len(cands)


def test_tune_on_the_engine_writes_the_set_tune_on_one_core_writes(tmp_path):
    """The engine's parts drop the sets; the chosen one is rebuilt from its grid point.

    The CLI's two paths on a small grid (2 x 2 points, one scenario): the engine's equality
    on a larger grid, in parts, over two scenarios, is the sweep test's above.
    """
    args = ['tune', '--w0', '40:120:2', '--kp', '5:20:2', '--scenarios', 'step']
    outs = []
    for extra, name in (([], 'one'), (['--workers', '1'], 'engine')):
        proc = subprocess.run([sys.executable, '-m', 'ladrc_tools.cli', *args, *extra, '-o',
                               str(tmp_path / name)], capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 0, proc.stderr
        outs.append(tmp_path / name)
    one, engine = outs
    assert (one / 'tuned.yaml').read_text() == (engine / 'tuned.yaml').read_text()
    assert (json.loads((one / 'tune.json').read_text())
            == json.loads((engine / 'tune.json').read_text()))


def test_the_fleet_shows_its_progress_on_a_terminal_and_nothing_piped(monkeypatch):
    import io

    from ladrc_fleet.cli import progress_line

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    for stream, shown in ((Terminal(), True), (io.StringIO(), False)):
        monkeypatch.setattr('sys.stderr', stream)
        show = progress_line('ladrc fleet')
        for done in (1, 2, 3):
            show(done, 3)
        assert stream.getvalue() == ('\rladrc fleet: 1/3 bags\rladrc fleet: 2/3 bags'
                                     '\rladrc fleet: 3/3 bags\n' if shown else '')


def test_an_existing_cluster_by_address_gives_the_rows_of_the_local_one(fleet, result, tmp_path):
    """A scheduler and a worker started apart (as on a cluster); killed by PID at the end."""
    import os
    import signal
    import time

    from ladrc_tools.offline.engine import client

    root, _ = fleet
    tree = tmp_path / 'tree'
    for bag in sorted((root / 'cutter-03').iterdir()):
        shutil.copytree(bag, tree / bag.name)
    sched_file = tmp_path / 'scheduler.json'
    procs = []
    try:
        procs.append(subprocess.Popen(
            [sys.executable, '-m', 'distributed.cli.dask_scheduler', '--scheduler-file',
             str(sched_file), '--host', '127.0.0.1', '--port', '0', '--no-dashboard'],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
        deadline = time.monotonic() + 60
        while not sched_file.is_file() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(sched_file.read_text())['address']
        procs.append(subprocess.Popen(
            [sys.executable, '-m', 'distributed.cli.dask_worker', address, '--nworkers', '1',
             '--nthreads', '1', '--no-dashboard'],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
        with client(address) as c:
            c.wait_for_workers(1, timeout=60)
        remote = run_fleet([str(tree)], tmp_path / 'out', scheduler=address, use_cache=False)
    finally:
        for p in procs:  # each with its children (the worker's nanny starts the worker)
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            p.wait(timeout=30)
    _, local = result
    assert remote.summary['workers'] == 1 and remote.summary['ok'] == 3
    by_key = {r['key']: r for r in local.rows}
    skip = {'bag', 'task_s'}
    for row in remote.rows:
        assert {k: v for k, v in row.items() if k not in skip} == {
            k: v for k, v in by_key[row['key']].items() if k not in skip}
    bad = subprocess.run([sys.executable, '-m', 'ladrc_tools.cli', 'fleet', str(tree), '-o',
                          str(tmp_path / 'out2'), '--scheduler', 'tcp://127.0.0.1:9'],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.count('\n') == 1, bad.stderr
    assert 'cannot reach the scheduler' in bad.stderr and 'Traceback' not in bad.stderr
