"""Bag library, headless-run bags, report, CSV export and the ladrc CLI's error handling."""

from __future__ import annotations

import csv
from dataclasses import fields
import json
import math
import os

from ladrc_bags import (
    Bag,
    BagError,
    BagWriter,
    RowPacker,
    count_lost,
    open_bag,
    seq_of,
    string_msg,
    write_run_bag,
)
from ladrc_bags.columns import CdrColumns, NoColumns, fields_of
from ladrc_bags.typestore import ladrc_typestore
from ladrc_sim.headless.runner import run
from ladrc_sim.headless.scenario import scenario_from_dict
from ladrc_tools.cli import main as ladrc
import numpy as np
import pytest
from rosbags.highlevel import AnyReader, AnyReaderError

H_S = 0.0005


class PController:
    """Minimal follow controller for the runner: u = -k (gap - target) while following."""

    def __init__(self, k: float = 40.0) -> None:
        self.k, self.target = k, None

    def command(self, name, **kw):
        if 'target_gap_mm' in kw:
            self.target = kw['target_gap_mm']
        if name == 'stop_follow':
            self.target = None

    def step(self, tick):
        if self.target is None or not tick.gap_valid:
            return 0.0
        return -self.k * (tick.gap_mm - self.target)


SCENARIO = {'name': 'bag_test', 'duration_s': 0.6, 'initial_gap_mm': 2.0,
            'timeline': [{'t_s': 0.05, 'do': 'start_follow', 'target_gap_mm': 1.0},
                         {'t_s': 0.1, 'do': 'sensor_dropout', 'duration_s': 0.01},
                         {'t_s': 0.3, 'do': 'set_target', 'target_gap_mm': 1.2}]}


@pytest.fixture(scope='module')
def run_bag(tmp_path_factory):
    result = run(scenario_from_dict(SCENARIO), PController())
    path = tmp_path_factory.mktemp('bags') / 'run'
    write_run_bag(result, path, 'limits: {v_max_mm_s: 150.0}\n', 'name: bag_test\n')
    return result, path


def test_row_packer_equals_rosbags_serializer():
    store = ladrc_typestore()
    rng = np.random.default_rng(3)
    for typename in ('ladrc_msgs/msg/FollowStatus', 'ladrc_msgs/msg/CapacitiveHeight',
                     'ladrc_msgs/msg/AxisFeedback', 'ladrc_msgs/msg/SimTruth',
                     'ladrc_msgs/msg/VelocityCommand'):
        packer = RowPacker(typename, store)
        cols = {}
        for f in packer.fields:
            kind = packer.dtype[f].kind
            cols[f] = (rng.normal(size=4) if kind == 'f' else rng.integers(0, 2, 4).astype(bool)
                       if kind == 'b' else rng.integers(0, 200, 4))
        rows = packer.pack(4, cols)
        for i, row in enumerate(rows):
            msg = store.deserialize_cdr(row, typename)
            assert bytes(store.serialize_cdr(msg, typename)) == row
            for f in ('seq', 'tick', 'gap_mm', 'true_gap_mm', 'velocity_mm_s'):
                if f in cols:
                    assert getattr(msg, f) == cols[f][i]
        buf, start, size = _flat(rows)
        assert CdrColumns(typename, store).decode(buf, start, size)[
            'header.stamp.sec'].tolist() == list(cols['header.stamp.sec'])


def test_seq_counting():
    assert count_lost(np.array([0, 1, 2, 5, 6, 10])) == 2 + 3
    assert count_lost(np.array([4, 4, 5])) == 0
    store = ladrc_typestore()
    T = store.types
    for frame in ('', 'a', 'sensor_0', 'abcdefgh'):  # the seq moves with the frame_id length
        msg = T['ladrc_msgs/msg/SimTruth'](
            header=T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](
                sec=3, nanosec=4), frame_id=frame), seq=2**40 + 7, true_gap_mm=1.0,
            sheet_mm=0.0, nozzle_mm=1.0, edge_coverage=1.0, plate_velocity_mm_s=0.0,
            collision=False, x_mm=0.0, y_mm=0.0)
        assert seq_of(store.serialize_cdr(msg, 'ladrc_msgs/msg/SimTruth')) == 2**40 + 7


def _write_velocity_rows(w, clock, at=None, check=None, n=50):
    """Write ``n`` VelocityCommand rows 0.1 s (mocked clock) apart; ``check()`` at ``at``."""
    rows = RowPacker('ladrc_msgs/msg/VelocityCommand').pack(
        n, {'seq': np.arange(n), 'velocity_mm_s': np.arange(n) * 0.5})
    for i, row in enumerate(rows):
        clock[0] = i * 0.1
        w.write_raw('axis/velocity_command', 10**9 + i * 10**8, row)
        if i == at:
            check()


def test_sqlite3_writer_lists_every_complete_segment(tmp_path, monkeypatch):
    clock = [0.0]
    monkeypatch.setattr('ladrc_bags.writer.time.monotonic', lambda: clock[0])
    path = tmp_path / 'split'
    w = BagWriter(path, storage='sqlite3', split_s=1.0)

    def mid_run():
        # a segment closes on the write at which it is split_s old: 11 messages each;
        # mid-run, the bag on disk already holds the two closed segments (and no more)
        with AnyReader([path]) as r:
            assert r.message_count == 22

    _write_velocity_rows(w, clock, 25, mid_run)
    w.write('run/scenario', 10**9, string_msg('name: x\n'))
    w.close()
    files = sorted(p.name for p in path.iterdir())
    assert files == ['metadata.yaml'] + [f'split_{i}.db3' for i in range(5)]
    _check_velocity_bag(path)


def _check_velocity_bag(path, n=50):
    with AnyReader([path]) as r:
        conns = [c for c in r.connections if c.topic == '/axis/velocity_command']
        seqs = [r.deserialize(d, c.msgtype).seq for c, _, d in r.messages(conns)]
        qos = conns[0].ext.offered_qos_profiles[0]
    assert seqs == list(range(n))
    assert (qos.depth, qos.reliability.name, qos.durability.name) == (100, 'BEST_EFFORT',
                                                                     'VOLATILE')
    with open_bag(path) as b:
        assert not b.recovered
        assert b.seq_loss('axis/velocity_command') == (n, 0)
        cols = b.columns('/axis/velocity_command')  # with or without the leading slash
        assert np.allclose(cols['velocity_mm_s'], np.arange(n) * 0.5)


@pytest.mark.parametrize('compression', ['zstd', 'lz4', 'none'])
def test_mcap_writer_streams_one_file_a_killed_writer_stays_readable(tmp_path, monkeypatch,
                                                                     compression):
    clock = [0.0]
    monkeypatch.setattr('ladrc_bags.writer.time.monotonic', lambda: clock[0])
    path = tmp_path / 'run'
    w = BagWriter(path, flush_s=0.25, compression=compression)

    def mid_run():
        # mid-run (as after a SIGKILL): the file has no summary yet; the tools read it
        # by a scan, up to the last flush (every 0.25 s of writing: message 24)
        with open_bag(path) as b:
            assert b.recovered
            seq = b.columns('axis/velocity_command')['seq']
            assert seq.tolist() == list(range(int(seq[-1]) + 1))
            assert 23 <= seq[-1] <= 25
        with pytest.raises(AnyReaderError):
            AnyReader([path]).open()  # rosbags needs the summary

    _write_velocity_rows(w, clock, 25, mid_run)
    w.write('run/scenario', 10**9, string_msg('name: x\n'))
    w.close()
    assert sorted(p.name for p in path.iterdir()) == ['metadata.yaml', 'run_0.mcap']
    _check_velocity_bag(path)
    # the channel metadata rosbag2's mcap plugin writes
    from mcap.reader import make_reader
    with open(path / 'run_0.mcap', 'rb') as f:
        summary = make_reader(f).get_summary()
    ch = next(c for c in summary.channels.values() if c.topic == '/axis/velocity_command')
    assert set(ch.metadata) == {'offered_qos_profiles', 'topic_type_hash'}
    assert ch.metadata['topic_type_hash'].startswith('RIHS01_')
    assert summary.schemas[ch.schema_id].encoding == 'ros2msg'
    chunks = {c.compression for c in summary.chunk_indexes}
    assert chunks == {'' if compression == 'none' else compression}


def test_mcap_writer_splits_by_time(tmp_path, monkeypatch):
    clock = [0.0]
    monkeypatch.setattr('ladrc_bags.writer.time.monotonic', lambda: clock[0])
    path = tmp_path / 'split'
    w = BagWriter(path, split_s=1.0)
    _write_velocity_rows(w, clock)
    w.close()
    files = sorted(p.name for p in path.iterdir())
    assert files == ['metadata.yaml'] + [f'split_{i}.mcap' for i in range(5)]
    _check_velocity_bag(path)


def test_writer_refuses_existing_path_and_bad_storage(tmp_path):
    with pytest.raises(BagError, match='exists already'):
        BagWriter(tmp_path)
    with pytest.raises(BagError, match='unknown storage'):
        BagWriter(tmp_path / 'x', storage='rosbag1')


def test_run_bag_has_live_layout_and_run_series(run_bag):
    result, path = run_bag
    n = result.t_s.size
    dropout = 20  # 0.01 s at 2 kHz without a fresh capacitive sample
    with open_bag(path) as b:
        assert b.count('follow/status') == n
        assert b.count('axis/capacitive_height') == n - dropout
        assert b.custom_data['ladrc.source'] == 'headless'
        st = b.columns('follow/status')
        assert np.array_equal(st['tick'], np.arange(n))
        assert np.allclose(st['stamp_s'], result.t_s, atol=1e-9)
        assert np.array_equal(st['velocity_mm_s'], result.command_mm_s)
        assert np.array_equal(st['gap_mm'], result.reading_mm)
        # during the dropout the status keeps using the last sample (same seq, old stamp)
        i0 = int(round(0.1 / H_S))
        assert st['gap_seq'][i0 + 5] == st['gap_seq'][i0 - 1]
        assert st['gap_stamp_s'][i0 + 5] == pytest.approx(result.t_s[i0 - 1])
        # a dropout is not a loss: the sensor published nothing, every sample is counted
        assert b.seq_loss('axis/capacitive_height') == (n - dropout, 0)
        tr = b.columns('sim/truth')
        assert np.array_equal(tr['true_gap_mm'], result.true_gap_mm)
        events = [(m.tick, m.kind, m.value_mm) for _, m in b.messages('follow/events')]
        assert events[0][:2] == (0, 8)
        assert events[1:] == [(100, 1, 1.0), (600, 3, 1.2)]
        params = next(m.data for _, m in b.messages('run/parameters'))
        assert 'v_max_mm_s' in params


def test_report_metrics_match_the_runs(run_bag, tmp_path):
    result, path = run_bag
    out = tmp_path / 'rep'
    assert ladrc(['report', str(path), '-o', str(out), '-q']) == 0
    assert sorted(p.name for p in out.iterdir()) == [
        'command.png', 'eso.png', 'gap.png', 'report.html', 'report.json', 'report.md',
        'state.png']  # report.html: tests/bags/test_html_report.py
    report = json.loads((out / 'report.json').read_text())
    m = result.metrics.as_dict()
    for key in ('followed_at_s', 'error_rms_mm', 'error_max_mm', 'itae_mm_s2', 'collisions'):
        if isinstance(m[key], float) and math.isnan(m[key]):
            assert report['metrics'][key] is None
        else:
            assert report['metrics'][key] == pytest.approx(m[key], rel=1e-6, abs=1e-9), key
    assert report['messages_lost'] == 0
    assert report['timing']['period_us']['p50'] == pytest.approx(500.0)
    md = (out / 'report.md').read_text()
    assert '(gap.png)' in md and 'error_rms_mm' in md
    assert (out / 'gap.png').read_bytes()[:4] == b'\x89PNG'


def test_export_one_csv_per_topic(run_bag, tmp_path):
    result, path = run_bag
    out = tmp_path / 'csv'
    assert ladrc(['export', str(path), '-o', str(out), '-q']) == 0
    names = sorted(p.name for p in out.iterdir())
    assert 'follow__status.csv' in names and 'sim__truth.csv' in names and len(names) == 8
    with (out / 'sim__truth.csv').open() as f:
        rows = list(csv.reader(f))
    assert rows[0][:4] == ['timestamp_ns', 'header.stamp.sec', 'header.stamp.nanosec',
                           'header.frame_id']
    col = rows[0].index('true_gap_mm')
    assert np.allclose([float(r[col]) for r in rows[1:]], result.true_gap_mm)


def _bad(tmp_path, argv, capsys, out):
    code = ladrc(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and 'Traceback' not in err, err
    assert not out.exists()
    assert not any(p.name.endswith('.partial') for p in out.parent.iterdir())
    return err


@pytest.mark.parametrize('command', ['report', 'export'])
def test_broken_bags_give_one_line(run_bag, tmp_path, capsys, command):
    _, good = run_bag
    out = tmp_path / 'out'
    err = _bad(tmp_path, [command, str(tmp_path / 'missing'), '-o', str(out), '-q'], capsys, out)
    assert 'no such file' in err
    # truncated storage file
    trunc = tmp_path / 'trunc'
    trunc.mkdir()
    (trunc / 'metadata.yaml').write_bytes((good / 'metadata.yaml').read_bytes())
    data = (good / 'run_0.mcap').read_bytes()
    (trunc / 'run_0.mcap').write_bytes(data[:len(data) // 2])
    _bad(tmp_path, [command, str(trunc), '-o', str(out), '-q'], capsys, out)
    # random bytes
    rnd = tmp_path / 'random'
    rnd.mkdir()
    (rnd / 'metadata.yaml').write_bytes(os.urandom(3000))
    _bad(tmp_path, [command, str(rnd), '-o', str(out), '-q'], capsys, out)
    # a file that is no bag
    junk = tmp_path / 'junk.mcap'
    junk.write_bytes(os.urandom(100))
    _bad(tmp_path, [command, str(junk), '-o', str(out), '-q'], capsys, out)


def test_report_needs_follow_status(tmp_path, capsys):
    path = tmp_path / 'nostatus'
    with BagWriter(path, split_s=None) as w:
        w.write('run/scenario', 1, string_msg('name: x\n'))
    out = tmp_path / 'out'
    err = _bad(tmp_path, ['report', str(path), '-o', str(out)], capsys, out)
    assert "no 'follow/status'" in err


def test_cli_help_and_missing_bag(capsys):
    assert ladrc(['replay', 'no/such/bag']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'no/such/bag' in err and 'Traceback' not in err
    for sub in ('report', 'export', 'simulate', 'replay', 'suite'):
        with pytest.raises(SystemExit) as exc:
            ladrc([sub, '--help'])
        assert exc.value.code == 0
    with pytest.raises(SystemExit) as exc:
        ladrc(['frobnicate'])
    assert exc.value.code == 2


def test_simulate_rejects_bad_input(tmp_path, capsys):
    out = tmp_path / 'sim'
    _bad(tmp_path, ['simulate', str(tmp_path / 'nope.yaml'), '-o', str(out)], capsys, out)
    params = tmp_path / 'p.yaml'
    params.write_text('no_such_section: {x: 1}\n')
    _bad(tmp_path, ['simulate', 'step', '--params', str(params), '-o', str(out)], capsys, out)


def test_columns_stream_in_chunks_with_mixed_layouts(tmp_path, monkeypatch):
    """Chunked decoding equals one pass, also when some messages carry strings (slow path)."""
    store = ladrc_typestore()
    packer = RowPacker('ladrc_msgs/msg/FollowStatus', store)
    rows = packer.pack(40, {'tick': np.arange(40), 'gap_mm': np.linspace(0, 1, 40),
                            'gap_seq': np.arange(40) + 2**40})
    path = tmp_path / 'b'
    with BagWriter(path) as w:
        for i, row in enumerate(rows):
            if i in (9, 10, 31):  # a fault reason: not the fixed layout
                msg = store.deserialize_cdr(row, 'ladrc_msgs/msg/FollowStatus')
                msg.fault_reason = f'fault {i}'
                w.write('follow/status', i, msg)
            else:
                w.write_raw('follow/status', i, row)
    with open_bag(path) as b:
        whole = b.columns('follow/status')
        monkeypatch.setattr('ladrc_bags.reader.COLUMN_CHUNK', 7)
        chunked = b.columns('follow/status')
        some = b.columns('follow/status', ['tick', 'stamp_s'])
    assert whole.keys() == chunked.keys()
    for k in whole:
        assert whole[k].dtype == chunked[k].dtype, k
        assert np.array_equal(whole[k], chunked[k]), k
    assert chunked['gap_seq'].dtype == np.uint64 and chunked['gap_seq'][-1] == 2**40 + 39
    assert chunked['fault_reason'][10] == 'fault 10' and chunked['fault_reason'][11] == ''
    assert set(some) == {'timestamp_ns', 'tick', 'header.stamp.sec', 'header.stamp.nanosec',
                         'stamp_s'}


def test_read_topics_in_one_pass_equals_columns(run_bag):
    _, path = run_bag
    with open_bag(path) as b:
        wanted = {'follow/status': ['tick', 'gap_mm', 'stamp_s'], 'sim/truth': None,
                  'axis/feedback': ['seq'], 'no/such/topic': None}
        data = b.read_topics(wanted)
        assert set(data) == {'follow/status', 'sim/truth', 'axis/feedback'}
        for topic in data:
            one = b.columns(topic, wanted[topic])
            assert data[topic].keys() == one.keys()
            for k in one:
                eq_nan = one[k].dtype.kind == 'f'
                assert np.array_equal(data[topic][k], one[k], equal_nan=eq_nan), (topic, k)


def test_plot_envelope_keeps_every_extreme():
    from ladrc_tools.offline.envelope import envelope

    n = 200_000
    t = np.arange(n) * 5e-4
    y = np.sin(t)
    y[123_457] = 9.0   # a one-sample spike must survive the decimation
    y[150_001] = -7.0
    y[10:20] = np.nan
    out = envelope({'t_s': t, 'y': y}, buckets=1000)
    assert out['t_s'].size == out['y'].size == 2000
    assert np.nanmax(out['y']) == 9.0 and np.nanmin(out['y']) == -7.0
    assert out['t_s'][0] == 0.0 and out['t_s'][-1] == t[-1]
    assert np.all(np.diff(out['t_s']) >= 0)
    short = {'t_s': t[:100], 'y': y[:100]}
    assert envelope(short, buckets=1000) is short


@pytest.mark.parametrize('compression', ['zstd', 'lz4', 'none'])
def test_indexed_reader_equals_the_message_by_message_reader(tmp_path, compression):
    """Through the MCAP message indexes (numpy rows per chunk) = through rosbags, per message.

    Messages of one topic with strings (other sizes) mixed into the fixed layout, several
    chunks, every compression: the same columns, types and values; the indexed path is the
    one taken (it is not silently the other one).
    """
    from ladrc_bags import reader as B

    store = ladrc_typestore()
    rows = RowPacker('ladrc_msgs/msg/FollowStatus').pack(
        3000, {'tick': np.arange(3000), 'gap_mm': np.linspace(0, 1, 3000)})
    cmd = RowPacker('ladrc_msgs/msg/VelocityCommand').pack(
        3000, {'seq': np.arange(3000), 'velocity_mm_s': np.cos(np.arange(3000))})
    path = tmp_path / 'bag'
    with BagWriter(path, compression=compression) as w:
        for i in range(3000):
            if i % 997 == 5:
                msg = store.deserialize_cdr(rows[i], 'ladrc_msgs/msg/FollowStatus')
                msg.fault_reason = f'fault {i}'
                w.write('follow/status', i * 500_000, msg)
            else:
                w.write_raw('follow/status', i * 500_000, rows[i])
            w.write_raw('axis/velocity_command', i * 500_000 + 1, cmd[i])
            if i % 1000 == 999:
                w._mcap.flush()  # end the chunk: several chunks
    with open_bag(path) as b:
        assert b._indexed_files() is not None
        fast = b.read_topics({'follow/status': None, 'axis/velocity_command': None})
        b._indexed_files = lambda: None
        slow = b.read_topics({'follow/status': None, 'axis/velocity_command': None})
    for topic in fast:
        assert fast[topic].keys() == slow[topic].keys()
        for k in fast[topic]:
            assert fast[topic][k].dtype == slow[topic][k].dtype, (topic, k)
            assert np.array_equal(fast[topic][k], slow[topic][k]), (topic, k)
    assert fast['follow/status']['fault_reason'][5] == 'fault 5'
    assert np.array_equal(fast['follow/status']['tick'], np.arange(3000))
    assert B.COLUMN_CHUNK > 0


@pytest.mark.parametrize('indexed', [True, False])
def test_time_slices_hold_consecutive_bag_time(tmp_path, monkeypatch, indexed):
    """Bag.stream yields every topic's messages of one stretch of bag time per slice."""
    st = RowPacker('ladrc_msgs/msg/FollowStatus').pack(4000, {'tick': np.arange(4000)})
    tr = RowPacker('ladrc_msgs/msg/SimTruth').pack(4000, {'seq': np.arange(4000)})
    path = tmp_path / 'bag'
    with BagWriter(path) as w:
        for i in range(4000):
            w.write_raw('follow/status', i * 500_000, st[i])
            w.write_raw('sim/truth', i * 500_000 + 7, tr[i])
            if i % 400 == 399:
                w._mcap.flush()  # ten chunks
    monkeypatch.setattr('ladrc_bags.reader.COLUMN_CHUNK', 1000)
    with open_bag(path) as b:
        if not indexed:
            b._indexed_files = lambda: None
        parts = list(b.stream({'follow/status': ['tick'], 'sim/truth': ['seq']}))
    assert len(parts) >= 4
    ends = [max(c['timestamp_ns'][-1] for c in p.values()) for p in parts]
    starts = [min(c['timestamp_ns'][0] for c in p.values()) for p in parts]
    assert all(s > e for s, e in zip(starts[1:], ends, strict=False))
    for topic, field in (('follow/status', 'tick'), ('sim/truth', 'seq')):
        got = np.concatenate([p[topic][field] for p in parts if topic in p])
        assert np.array_equal(got, np.arange(4000)), topic


def test_envelope_fed_in_slices_equals_the_whole():
    from ladrc_tools.offline.envelope import Envelope, envelope

    n = 123_457
    rng = np.random.default_rng(4)
    series = {'t_s': np.arange(n) * 5e-4, 'y': rng.normal(size=n)}
    series['y'][77_777] = 50.0
    whole = envelope(series, buckets=1000)
    env = Envelope(n, buckets=1000)
    cuts = [0, 1, 999, 65_536, 65_537, 100_000, n]
    for a, b in zip(cuts, cuts[1:], strict=False):
        env.add({k: v[a:b] for k, v in series.items()})
    got = env.result()
    for k in whole:
        assert np.array_equal(whole[k], got[k]), k
    assert got['y'].max() == 50.0 and got['t_s'][-1] == series['t_s'][-1]


def test_timing_quantiles_exact_then_within_their_bin_width(monkeypatch):
    from ladrc_tools.offline import quantiles as Q

    rng = np.random.default_rng(5)
    x = np.concatenate([rng.normal(500.0, 3.0, 30_000), [-20.0, 9000.0, np.nan]])
    exact = Q.Quantiles()
    exact.add(x)
    fin = x[np.isfinite(x)]
    assert exact.stats() == {'p50': float(np.percentile(fin, 50)),
                             'p99': float(np.percentile(fin, 99)), 'max': 9000.0}
    monkeypatch.setattr(Q, 'EXACT_MAX', 1000)  # the histogram past EXACT_MAX values
    hist = Q.Quantiles()
    for part in np.array_split(x, 7):
        hist.add(part)
    assert hist.values is None
    for key, q in (('p50', 50), ('p99', 99)):
        assert hist.stats()[key] == pytest.approx(np.percentile(fin, q), rel=6e-4), key
    assert hist.stats()['max'] == 9000.0


def test_report_in_small_slices_equals_one_slice(run_bag, tmp_path, monkeypatch):
    """The report's one pass (truth join, metrics, loss, plot envelope) across many slices."""
    _, path = run_bag
    assert ladrc(['report', str(path), '-o', str(tmp_path / 'one'), '-q']) == 0
    monkeypatch.setattr('ladrc_bags.reader.COLUMN_CHUNK', 333)
    with open_bag(path) as b:
        b._indexed_files = lambda: None  # message by message: many slices
        from ladrc_tools.offline.report import analyse

        sliced, series = analyse(b)
    one = json.loads((tmp_path / 'one' / 'report.json').read_text())
    for k, v in one['metrics'].items():
        assert sliced['metrics'][k] == pytest.approx(v, rel=1e-9, nan_ok=True) or (
            v is None and math.isnan(sliced['metrics'][k])), k
    assert sliced['messages_lost'] == one['messages_lost'] == 0
    assert sliced['ticks'] == one['ticks']
    assert series['t_s'].size == series['true_gap_mm'].size == series['gap_mm'].size


def test_segment_close_cost_does_not_grow_with_the_segments(tmp_path, monkeypatch):
    """Closing the 1500th file renders as much YAML as closing the 20th did.

    The work, not a time (a timed ratio is not stable under load): every
    ``yaml.safe_dump`` of a close is counted in characters. A rewrite that renders every closed
    file's entry again (as before) dumps ~150 characters more per file already closed; the
    writer dumps the new file's entries and the constant-size head only. Speed:
    bench/bag_scale.py.
    """
    import yaml

    clock = [0.0]
    monkeypatch.setattr('ladrc_bags.writer.time.monotonic', lambda: clock[0])
    real_dump = yaml.safe_dump
    dumped: list[int] = []  # characters rendered by yaml.safe_dump since the last close

    def counting_dump(data, *args, **kwargs):
        text = real_dump(data, *args, **kwargs)
        dumped[-1] += len(text)
        return text
    monkeypatch.setattr(yaml, 'safe_dump', counting_dump)
    rows = RowPacker('ladrc_msgs/msg/VelocityCommand').pack(1, {'seq': 1})
    path = tmp_path / 'split'
    dumped.append(0)
    w = BagWriter(path, split_s=0.01, compression='none')
    closes: list[int] = []
    real_close = w._close_segment

    def counted_close():
        dumped.append(0)
        real_close()
        closes.append(dumped[-1])
    monkeypatch.setattr(w, '_close_segment', counted_close)
    n = 1500
    for i in range(n):
        clock[0] = i * 0.01
        w.write_raw('axis/velocity_command', i * 10_000_000, rows[0])
    w.close()
    monkeypatch.undo()
    first, last = max(closes[20:70]), max(closes[-51:-1])
    assert 0 < first and last <= first + 40, (first, last)  # a few digits more, no entries
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    files = sorted(p.name for p in path.glob('*.mcap'))
    assert len(closes) > 500 and len(info['files']) == len(files) == len(closes)
    assert info['relative_file_paths'] == [f['path'] for f in info['files']]
    assert sorted(info['relative_file_paths']) == files
    assert info['message_count'] == n == sum(f['message_count'] for f in info['files'])
    f7 = info['files'][7]
    assert f7['path'] == 'split_7.mcap' and f7['message_count'] >= 1
    assert f7['duration']['nanoseconds'] == 10_000_000 * (f7['message_count'] - 1)
    assert info['duration']['nanoseconds'] == (n - 1) * 10_000_000
    with open_bag(path) as b:
        assert b.count('axis/velocity_command') == n


def test_messages_of_one_topic_with_other_sizes_in_other_chunks(tmp_path):
    """A topic whose chunks hold messages of different (string) sizes reads as one column."""
    store = ladrc_typestore()
    path = tmp_path / 'bag'
    with BagWriter(path) as w:
        for i, text in enumerate(['a' * 2000, 'b', 'cc' * 30]):
            row = RowPacker('ladrc_msgs/msg/FollowEvent').pack(1, {'tick': i, 'kind': 8})[0]
            msg = store.deserialize_cdr(row, 'ladrc_msgs/msg/FollowEvent')
            msg.text = text
            w.write('follow/events', i, msg)
            w._mcap.flush()  # one chunk each
    with open_bag(path) as b:
        assert b._indexed_files() is not None
        cols = b.columns('follow/events')
    assert cols['text'].tolist() == ['a' * 2000, 'b', 'cc' * 30]
    assert cols['tick'].tolist() == [0, 1, 2]


def test_report_of_a_bag_that_starts_idle_for_longer_than_a_slice(tmp_path, monkeypatch):
    """No target while IDLE, even when the first non-IDLE tick is many slices in."""
    from ladrc_tools.offline.report import analyse

    n = 4000
    tick = np.arange(n)
    t = tick * 5e-4
    state = np.where(tick < 2000, 0, 4)
    gap = np.where(tick < 2000, 1.0, 1.0 + 2.0 * np.exp(-(t - 1.0) / 0.05))
    rows = RowPacker('ladrc_msgs/msg/FollowStatus').pack(n, {
        'tick': tick, 'stamp_s': t, 'state': state, 'target_gap_mm': np.full(n, 1.0),
        'gap_mm': gap, 'period_us': np.full(n, 500.0)})
    path = tmp_path / 'bag'
    with BagWriter(path, compression='none') as w:
        for i in range(n):
            w.write_raw('follow/status', int(round(t[i] * 1e9)), rows[i])

    def metrics(chunk: int) -> dict:
        monkeypatch.setattr('ladrc_bags.reader.COLUMN_CHUNK', chunk)
        with open_bag(path) as b:
            b._indexed_files = lambda: None  # message by message: slices of `chunk`
            return analyse(b)[0]['metrics']
    one, sliced = metrics(65536), metrics(500)
    assert one['followed_at_s'] > 1.0  # the IDLE second has no target
    for k, v in one.items():
        assert sliced[k] == pytest.approx(v, rel=1e-9, nan_ok=True), k


# ---- strings in columns (the 2 kHz topics carry text) -------------------------------------------
def _flat(rows: list[bytes]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Messages as the column decoder takes them: one buffer, starts, sizes."""
    size = np.array([len(r) for r in rows], dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(size[:-1])]).astype(np.int64)
    return np.frombuffer(b''.join(rows), dtype=np.uint8), start, size


TEXTS = ('', '', 'a', 'corner lock: feed 3.1 < 30 % of 100 mm/s', 'Höhe ±0,1 mm', 'abc',
         'abcd', 'x' * 301, '/ladrc_follow', '/ladrc_follow')


def _status_messages(store, n: int, seed: int = 5) -> list:
    """FollowStatus messages with random numbers and texts of every length and alignment."""
    rng = np.random.default_rng(seed)
    cls = store.types['ladrc_msgs/msg/FollowStatus']
    base = store.deserialize_cdr(RowPacker('ladrc_msgs/msg/FollowStatus', store).pack(1, {})[0],
                                 'ladrc_msgs/msg/FollowStatus')
    out = []
    for i in range(n):
        kw = {}
        for f in fields(cls):
            v = getattr(base, f.name)
            if isinstance(v, bool):
                kw[f.name] = bool(rng.integers(0, 2))
            elif isinstance(v, float):
                kw[f.name] = float(rng.normal()) if i % 7 else math.nan
            elif isinstance(v, int):
                kw[f.name] = int(rng.integers(0, 250))
            elif isinstance(v, str):
                kw[f.name] = TEXTS[int(rng.integers(0, len(TEXTS)))]
            else:
                kw[f.name] = v
        kw['header'] = store.types['std_msgs/msg/Header'](
            stamp=store.types['builtin_interfaces/msg/Time'](sec=i, nanosec=7 * i),
            frame_id=TEXTS[i % len(TEXTS)])
        out.append(cls(**kw))
    return out


def test_column_decoder_equals_rosbags_with_strings_of_every_length():
    """Every field of messages with texts of any length (and UTF-8) decodes as rosbags does."""
    store = ladrc_typestore()
    typename = 'ladrc_msgs/msg/FollowStatus'
    msgs = _status_messages(store, 300)
    rows = [bytes(store.serialize_cdr(m, typename)) for m in msgs]
    assert len({len(r) for r in rows}) > 10  # the fields after the strings move
    cols = CdrColumns(typename, store).decode(*_flat(rows))
    for i, m in enumerate(msgs):
        for key, kind in fields_of(typename, store):
            want = m
            for part in key.split('.'):
                want = getattr(want, part)
            got = cols[key][i]
            if kind == 'string':
                assert isinstance(got, str) and got == want, key
            elif isinstance(want, float) and math.isnan(want):
                assert math.isnan(got), key
            else:
                assert got == want, key
    # a subset of the fields: the same values, only those
    some = CdrColumns(typename, store).decode(*_flat(rows), names=['tick', 'hold_reason'])
    assert list(some) == ['tick', 'hold_reason']
    assert some['hold_reason'].tolist() == cols['hold_reason'].tolist()


def test_column_decoder_refuses_what_is_not_the_message():
    """A short message or a string length running past its end: None, never wrong columns."""
    store = ladrc_typestore()
    typename = 'ladrc_msgs/msg/VelocityCommand'
    msgs = _status_messages(store, 1)  # any header
    cmd = store.types[typename](header=msgs[0].header, seq=3, velocity_mm_s=-1.5, enable=True,
                                sample_seq=2, commander='/ladrc_follow', session=9,
                                release=False)
    row = bytes(store.serialize_cdr(cmd, typename))
    dec = CdrColumns(typename, store)
    assert dec.decode(*_flat([row, row]))['commander'].tolist() == ['/ladrc_follow'] * 2
    assert dec.decode(*_flat([row, row[:-9]])) is None  # truncated
    at = row.index(b'/ladrc_follow') - 4
    long_len = row[:at] + (10**6).to_bytes(4, 'little') + row[at + 4:]
    assert dec.decode(*_flat([row, long_len])) is None
    bad_utf8 = row.replace(b'/ladrc_follow', b'/ladrc_\xff\xfeollow')
    assert dec.decode(*_flat([row, bad_utf8])) is None
    with pytest.raises(NoColumns):
        CdrColumns('diagnostic_msgs/msg/DiagnosticArray', store)


def test_text_topics_are_read_in_columns_not_message_by_message(tmp_path, monkeypatch):
    """A bag whose 2 kHz topics carry text is read without one rosbags call per message."""
    store = ladrc_typestore()
    msgs = _status_messages(store, 2000, seed=9)
    path = tmp_path / 'bag'
    with BagWriter(path) as w:
        for i, m in enumerate(msgs):
            w.write('follow/status', 10**9 + i * 500_000, m)
    with open_bag(path) as b:
        b._indexed_files = lambda: None  # rosbags' reader: the column decoder per batch
        plain = b.columns('follow/status')
    calls = []
    monkeypatch.setattr(Bag, '_slow_columns', lambda *a: calls.append(a) or {})
    for indexed in (True, False):
        with open_bag(path) as b:
            if not indexed:
                b._indexed_files = lambda: None
            else:
                assert b._indexed_files() is not None
            cols = b.columns('follow/status')
        assert not calls
        assert cols['hold_reason'].tolist() == [m.hold_reason for m in msgs]
        assert cols['fault_reason'].tolist() == [m.fault_reason for m in msgs]
        assert cols['cnc_contour'].tolist() == [m.cnc_contour for m in msgs]
        assert list(cols) == list(plain)
