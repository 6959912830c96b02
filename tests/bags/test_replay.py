"""``ladrc replay``: headless bags replay bit for bit; perturbed inputs or other parameters not.

The reference is the producer itself: the headless runner stepped the same
:class:`FollowController` on these inputs, so an exact replay must reproduce every float64 bit
of every command (and of every recorded internal). A replay that applied an event one tick late,
mapped an event field to the wrong argument or lost the parameter set would show mismatches.
"""

from __future__ import annotations

from dataclasses import fields, is_dataclass, replace
import json
import math
from pathlib import Path

from ladrc_bags import BagWriter, open_bag, rosbags_qos, string_msg, write_run_bag
from ladrc_contract.qos import TOPIC_QOS
from ladrc_follow.control.follow import COMMANDS, FollowController
from ladrc_follow.control.params import ControllerParams, dump_params
from ladrc_sim.headless.runner import run
from ladrc_sim.headless.scenario import scenario_from_dict
from ladrc_tools.cli import main as ladrc
from ladrc_tools.offline.replay import (
    KIND_NAMES,
    RecordedEvent,
    ReplayError,
    compare,
    event_command,
    load_recording,
    parse_set,
    replay,
    whatif_params,
)
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

# Every kind of event the replay must re-apply at its tick: a start, a machining flag on and
# off (PID <-> LADRC hand-overs), a target change above the re-interpolation threshold, a
# height compensation with its queue, a target wave, a gradient follow with a delay and a
# drive fault.
SCENARIO = {
    'name': 'replay_test', 'duration_s': 2.6, 'seed': 3, 'initial_gap_mm': 2.0,
    'sensor': {'noise_std_mm': 0.005, 'quant_mm': 0.001},
    'sheet': {'profiles': [{'kind': 'sine', 'amp_mm': 0.1, 'freq_hz': 2.0}]},
    'timeline': [
        {'t_s': 0.02, 'do': 'start_follow', 'target_gap_mm': 1.0},
        {'t_s': 0.5, 'do': 'machining', 'on': True},
        {'t_s': 0.7, 'do': 'set_target', 'target_gap_mm': 1.3},
        {'t_s': 1.2, 'do': 'height_compensation', 'offset_mm': 0.1},
        {'t_s': 1.4, 'do': 'machining', 'on': False},
        {'t_s': 1.45, 'do': 'target_wave', 'kind': 'chirp', 'amp_mm': 0.05, 'freq_hz': 5.0,
         'freq_end_hz': 20.0, 'duration_s': 0.1},
        {'t_s': 1.6, 'do': 'gradient_follow', 'target_gap_mm': 1.0, 'delay_s': 0.05},
        {'t_s': 1.9, 'do': 'sensor_dropout', 'duration_s': 0.004},
        {'t_s': 2.3, 'do': 'drive', 'enabled': True, 'fault': True},
    ]}
STATE_PREINTERP, STATE_PID, STATE_LADRC, STATE_FAULT = 2, 3, 4, 5


@pytest.fixture(scope='module')
def headless(tmp_path_factory):
    params = ControllerParams()
    result = run(scenario_from_dict(SCENARIO), FollowController(params, mode='ladrc'),
                 record_internals=True)
    path = tmp_path_factory.mktemp('replay') / 'run'
    write_run_bag(result, path, dump_params(params), 'name: replay_test\n',
                  controller='ladrc')
    return result, path


def _json_line(text: str) -> dict:
    return json.loads(text.strip().splitlines()[-1])


def test_scenario_exercises_every_event(headless):
    # The test is only as strong as the run: check it went through the hand-overs and events.
    result, _ = headless
    state = result.internals['state']
    assert {STATE_PREINTERP, STATE_PID, STATE_LADRC, STATE_FAULT} <= set(state.astype(int))
    target = result.internals['target_gap_mm']
    h = result.h_s
    assert target[int(1.1 / h)] == pytest.approx(1.3)
    assert target[int(1.3 / h)] == pytest.approx(1.4)  # compensation applied
    td = result.internals['td_x1_mm']  # the target wave (a chirp, SIN_GEN) moved the TD
    assert np.ptp(td[int(1.46 / h):int(1.55 / h)]) > 0.02
    assert target[int(1.7 / h)] == pytest.approx(1.1)  # gradient target + compensation
    machining = result.internals['machining']
    assert machining[int(0.6 / h)] == 1 and machining[int(1.5 / h)] == 0


def test_headless_bag_replays_bit_for_bit(headless, capsys):
    result, path = headless
    rec = load_recording(path)
    assert rec.params_source == 'follow/events PARAMETERS at tick 0'
    assert rec.mode == 'ladrc' and rec.source == 'headless'
    res = replay(rec)
    # the replayed commands are the runner's commands, bit for bit
    assert np.array_equal(res.velocity.view(np.uint64),
                          np.asarray(result.command_mm_s, dtype=np.float64).view(np.uint64))
    s = compare(rec, res)
    assert s['ticks'] == result.t_s.size
    assert s['mismatches'] == 0 and s['first_mismatch_tick'] is None
    assert s['missing_ticks'] == 0 and s['internal_mismatch_ticks'] == 0
    assert res.rejected == []
    # the CLI says the same and exits 0; the summary ends with one JSON line
    assert ladrc(['replay', str(path)]) == 0
    line = _json_line(capsys.readouterr().out)
    assert line['ticks'] == result.t_s.size and line['mismatches'] == 0
    assert line['missing_ticks'] == 0 and line['first_mismatch_tick'] is None
    assert line['params_source'] == rec.params_source


def test_a_perturbed_input_is_detected_at_its_tick(headless):
    _, path = headless
    rec = load_recording(path)
    k = int(1.0 / rec.h_s)  # following (LADRC or PID)
    gap = rec.inputs['gap_mm'].copy()
    gap[k] = np.nextafter(gap[k], math.inf)  # one ulp
    rec.inputs['gap_mm'] = gap
    s = compare(rec, replay(rec, record_internals=False))
    assert s['mismatches'] > 0
    assert s['first_mismatch_tick'] == k


def test_another_parameter_set_mismatches(headless, capsys, tmp_path):
    _, path = headless
    rec = load_recording(path)
    kp = rec.params.law.kp
    res = replay(rec, whatif_params(rec, overrides={'law.kp': kp * 1.5}),
                 overrides={'law.kp': kp * 1.5})
    s = compare(rec, res)
    assert s['mismatches'] > 0
    # before the LADRC first runs, the law gain plays no part: identical commands
    first_ladrc = int(np.argmax(rec.status['state'] == STATE_LADRC))
    assert s['first_mismatch_tick'] >= first_ladrc
    # the CLI what-if exits 0 and writes its comparison
    out = tmp_path / 'wi'
    assert ladrc(['replay', str(path), '--set', f'law.kp={kp * 1.5}', '-o', str(out)]) == 0
    printed = capsys.readouterr().out
    assert 'open loop' in printed
    line = _json_line(printed)
    assert line['mode'] == 'what-if' and line['open_loop'] is True
    assert line['command_max_difference_mm_s'] > 0
    assert {p.name for p in out.iterdir()} == {'whatif.png', 'whatif.md', 'whatif.json',
                                                'params.yaml'}
    table = json.loads((out / 'whatif.json').read_text())
    a, b = rec.command, res.velocity
    assert table['command_rms_difference_mm_s'] == pytest.approx(
        float(np.sqrt(np.mean((b - a) ** 2))))
    assert f'kp: {kp * 1.5}' in (out / 'params.yaml').read_text()


def test_own_replay_exits_1_on_mismatch(headless, tmp_path, capsys, monkeypatch):
    _, path = headless
    import ladrc_tools.offline.recording as R

    real = R._stream_batches

    def perturbed(*args, **kwargs):
        for batch in real(*args, **kwargs):
            batch.inputs['encoder_mm'] = batch.inputs['encoder_mm'] + 1e-9
            yield batch
    monkeypatch.setattr(R, '_stream_batches', perturbed)
    assert ladrc(['replay', str(path), '--no-internals']) == 1
    line = _json_line(capsys.readouterr().out)
    assert line['mismatches'] > 0 and line['first_mismatch_tick'] is not None


def test_missing_ticks_break_exact_replay_after_the_gap(headless):
    _, path = headless
    rec = load_recording(path)
    gap_at = int(1.0 / rec.h_s)
    keep = np.ones(rec.ticks.size, dtype=bool)
    keep[gap_at:gap_at + 3] = False  # three ticks lost
    cut = replace(rec, ticks=rec.ticks[keep], command=rec.command[keep],
                  command_enable=rec.command_enable[keep],
                  command_present=rec.command_present[keep],
                  inputs={k: v[keep] for k, v in rec.inputs.items()},
                  status={k: v[keep] for k, v in rec.status.items()})
    s = compare(cut, replay(cut, record_internals=False))
    assert s['missing_ticks'] == 3
    assert s['exact_until_tick'] == gap_at - 1
    assert s['mismatches'] == 0  # exact up to the gap
    assert s['mismatches_after_gap'] > 0  # the controller skipped three ticks of dynamics


def test_event_fields_map_to_the_command_arguments():
    # Every command kind maps onto the controller's command signature (names and count).
    ev = RecordedEvent(tick=0, kind=0, value_mm=1.25, delay_s=0.5, velocity_mm_s=30.0,
                       accel_mm_s2=400.0, flag=True,
                       text='{"kind": "chirp", "freq_hz": 1.0, "freq_end_hz": 5.0, '
                            '"duration_s": 2.0}')
    for kind, name in KIND_NAMES.items():
        if name == 'parameters':
            continue
        text = {  # the CNC's pierce and leapfrog carry their arguments as JSON too
            'pierce': '{"heights_mm": [3.0], "dwell_s": [0.2], "thc_delay_s": 0.1}',
            'leapfrog': '{"lift_mm": 8.0, "rapid_length_mm": 100.0, "rapid_feed_mm_s": 500.0}',
        }.get(name, ev.text)
        got, kwargs = event_command(replace(ev, kind=kind, text=text))
        assert got == name
        assert set(kwargs) == set(COMMANDS[name])
    assert event_command(replace(ev, kind=6))[1] == {
        'target_gap_mm': 1.25, 'delay_s': 0.5, 'velocity_mm_s': 30.0, 'accel_mm_s2': 400.0}
    assert event_command(replace(ev, kind=4))[1] == {'on': True}
    assert event_command(replace(ev, kind=5))[1] == {'offset_mm': 1.25, 'delay_s': 0.5}
    assert event_command(replace(ev, kind=9))[1] == {  # the wave: amplitude + JSON text
        'amp_mm': 1.25, 'kind': 'chirp', 'freq_hz': 1.0, 'freq_end_hz': 5.0, 'duration_s': 2.0}


def test_set_overrides_are_checked(headless):
    _, path = headless
    rec = load_recording(path)
    assert parse_set(['law.kp=12', 'follow.controller=pid']) == {
        'law.kp': 12, 'follow.controller': 'pid'}
    with pytest.raises(ReplayError, match='key=value'):
        parse_set(['law.kp'])
    with pytest.raises(ReplayError, match='unknown parameter law.kq'):
        whatif_params(rec, overrides={'law.kq': 1.0})
    with pytest.raises(ReplayError, match='h_s'):
        whatif_params(rec, overrides={'h_s': 0.001})


def _bad(argv: list[str], capsys, out=None) -> str:
    code = ladrc(argv)
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert code == 2, (captured.out, err)
    assert len(err.splitlines()) == 1 and 'Traceback' not in err, err
    if out is not None:
        assert not out.exists()
        assert not any(p.name.endswith('.partial') for p in out.parent.iterdir())
    return err


def test_bad_input_gives_one_line(headless, tmp_path, capsys):
    _, good = headless
    out = tmp_path / 'out'
    assert 'no such file' in _bad(['replay', str(tmp_path / 'missing'), '-o', str(out)],
                                  capsys, out)
    # truncated storage file
    trunc = tmp_path / 'trunc'
    trunc.mkdir()
    (trunc / 'metadata.yaml').write_bytes((good / 'metadata.yaml').read_bytes())
    data = (good / 'run_0.mcap').read_bytes()
    (trunc / 'run_0.mcap').write_bytes(data[:len(data) // 2])
    _bad(['replay', str(trunc), '-o', str(out)], capsys, out)
    # a foreign file
    junk = tmp_path / 'junk.mcap'
    junk.write_bytes(b'\x89MCAP0\r\n' + bytes(range(200)))
    _bad(['replay', str(junk)], capsys)
    # no follow/status
    nostatus = tmp_path / 'nostatus'
    with BagWriter(nostatus, split_s=None) as w:
        w.write('run/scenario', 1, string_msg('name: x\n'))
    assert "no 'follow/status'" in _bad(['replay', str(nostatus), '-o', str(out)], capsys, out)
    # no parameter set (no PARAMETERS event, empty run/parameters)
    result = run(scenario_from_dict({**SCENARIO, 'duration_s': 0.1,
                                     'timeline': SCENARIO['timeline'][:1]}),
                 FollowController(ControllerParams()))
    noparams = tmp_path / 'noparams'
    write_run_bag(result, noparams, '', 'name: x\n')
    assert 'no parameter set' in _bad(['replay', str(noparams), '-o', str(out)], capsys, out)
    # unknown parameter keys, in --set and in --params
    assert 'law.kq' in _bad(['replay', str(good), '--set', 'law.kq=3', '-o', str(out)],
                            capsys, out)
    pfile = tmp_path / 'p.yaml'
    pfile.write_text('law: {kq: 3.0}\n')
    assert 'kq' in _bad(['replay', str(good), '--params', str(pfile), '-o', str(out)],
                        capsys, out)
    assert 'cannot read' in _bad(['replay', str(good), '--params', str(tmp_path / 'nope.yaml'),
                                  '-o', str(out)], capsys, out)
    # an existing output is never overwritten
    out.mkdir()
    assert 'exists already' in _bad(['replay', str(good), '--set', 'law.kp=3', '-o', str(out)],
                                    capsys)


def _rewrite(src, dst, slash: bool, storage: str = 'mcap'):
    """Copy a bag with a plain rosbags writer, topics as ros2 bag record names them (slash)."""
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    with AnyReader([src]) as r, Writer(dst, version=9, storage_plugin=plugin) as w:
        conns = {}
        for c in r.connections:
            name = c.topic if slash else c.topic.lstrip('/')
            conns[c.id] = w.add_connection(
                name, c.msgtype, typestore=r.typestore,
                offered_qos_profiles=[rosbags_qos(TOPIC_QOS.get(c.topic.lstrip('/'),
                                                                TOPIC_QOS['/diagnostics']))])
        for c, ts, data in r.messages():
            w.write(conns[c.id], ts, data)


@pytest.mark.parametrize('slash', [True, False])
def test_tools_read_bags_ros2_bag_would_write(headless, tmp_path, capsys, slash):
    """Fully qualified names (ros2 bag record) and the older relative names both work."""
    result, path = headless
    other = tmp_path / 'foreign'
    _rewrite(path, other, slash)
    with AnyReader([other]) as r:
        assert any(c.topic.startswith('/') for c in r.connections) == slash
    assert ladrc(['replay', str(other)]) == 0
    line = _json_line(capsys.readouterr().out)
    assert line['ticks'] == result.t_s.size and line['mismatches'] == 0
    assert ladrc(['report', str(other), '-o', str(tmp_path / 'rep'), '-q']) == 0
    assert ladrc(['export', str(other), '-o', str(tmp_path / 'csv'), '-q']) == 0
    assert (tmp_path / 'csv' / 'follow__status.csv').is_file()


def test_replay_in_small_batches_is_the_same(headless, monkeypatch):
    """Batch boundaries (events, parameter sets, internals) change nothing, bit for bit."""
    _, path = headless
    rec = load_recording(path)
    whole = replay(rec)
    monkeypatch.setattr('ladrc_tools.offline.recording.CHUNK_TICKS', 777)
    batched = replay(rec)
    assert np.array_equal(whole.velocity.view(np.uint64), batched.velocity.view(np.uint64))
    assert np.array_equal(whole.enable, batched.enable)
    for k, v in whole.internals.items():
        assert np.array_equal(v, batched.internals[k], equal_nan=True), k
    assert compare(rec, batched)['mismatches'] == 0


def test_streamed_replay_equals_the_whole_run_replay(headless, monkeypatch):
    """The CLI's path (bag read, stepped and compared a batch at a time) = the whole-run one.

    Commands recorded later than their status ticks must still be joined: the bag's slices
    end between a status tick and its command.
    """
    from ladrc_tools.offline.replay import Replay, open_recording, run_streamed

    _, path = headless
    rec = load_recording(path)
    whole = compare(rec, replay(rec))
    monkeypatch.setattr('ladrc_bags.reader.COLUMN_CHUNK', 301)
    # message by message: many slices
    monkeypatch.setattr('ladrc_bags.Bag._indexed_files', lambda self: None)
    monkeypatch.setattr('ladrc_tools.offline.recording.CHUNK_TICKS', 257)
    srec = open_recording(path)
    assert srec.ticks is None and srec.n_ticks == rec.ticks.size
    summary, _ = run_streamed(srec, Replay(srec), whatif=False)
    for k in ('ticks', 'mismatches', 'missing_ticks', 'commands_missing',
              'internal_mismatch_ticks', 'exact_until_tick', 'end_tick'):
        assert summary[k] == whole[k], k
    assert summary['mismatches'] == 0 and summary['commands_missing'] == 0
    assert summary['ticks'] == rec.ticks.size


def test_comparison_across_batches_finds_the_gap_where_the_whole_run_does(headless,
                                                                          monkeypatch):
    from ladrc_tools.offline.replay import Comparison, Replay

    _, path = headless
    rec = load_recording(path)
    for gap_at in (1000, 1028, 1029, 1030):  # in a batch, at its first and last tick
        keep = np.ones(rec.ticks.size, dtype=bool)
        keep[gap_at:gap_at + 2] = False
        cut = replace(rec, ticks=rec.ticks[keep], command=rec.command[keep],
                      command_enable=rec.command_enable[keep],
                      command_present=rec.command_present[keep],
                      inputs={k: v[keep] for k, v in rec.inputs.items()},
                      status={k: v[keep] for k, v in rec.status.items()})
        whole = compare(cut, replay(cut))
        monkeypatch.setattr('ladrc_tools.offline.recording.CHUNK_TICKS', 1029)
        cmp = Comparison(live=False)
        run = Replay(cut)
        for rb, pb in run.batches():
            cmp.add(rb, pb)
        monkeypatch.undo()
        got = cmp.summary(run)
        for k in ('mismatches', 'mismatches_after_gap', 'missing_ticks', 'exact_until_tick',
                  'internal_mismatch_ticks', 'first_mismatch_tick'):
            assert got[k] == whole[k], (gap_at, k)
        assert got['missing_ticks'] == 2 and got['exact_until_tick'] == gap_at - 1


def test_streamed_join_finds_late_out_of_order_and_repeated_commands(tmp_path, monkeypatch):
    """Commands up to 4 ms late, out of order, some missing, some re-sent (the last wins).

    The streamed join, in slices of 37 messages, equals the join over the whole run.
    """
    from ladrc_bags import RowPacker, open_bag
    import ladrc_tools.offline.recording as R

    rng = np.random.default_rng(7)
    n = 3000
    tick = np.arange(n) + 100
    st = RowPacker('ladrc_msgs/msg/FollowStatus').pack(
        n, {'tick': tick, 'velocity_mm_s': np.full(n, -1.0)})
    events = [(i * 500_000, 'follow/status', st[i]) for i in range(n)]
    cmds = []
    for i in range(n):
        if rng.random() < 0.05:
            continue  # lost
        late = int(rng.integers(0, 8)) * 500_000 + 3
        cmds.append((i * 500_000 + late, tick[i], float(i)))
        if rng.random() < 0.02:  # re-sent 3 ms later with another value
            cmds.append((i * 500_000 + late + 6 * 500_000, tick[i], float(-i)))
    rows = RowPacker('ladrc_msgs/msg/VelocityCommand').pack(len(cmds), {
        'seq': np.array([c[1] for c in cmds]), 'velocity_mm_s': np.array([c[2] for c in cmds]),
        'enable': np.ones(len(cmds), bool)})
    events += [(c[0], 'axis/velocity_command', rows[j]) for j, c in enumerate(cmds)]
    events.sort(key=lambda e: e[0])
    path = tmp_path / 'bag'
    with BagWriter(path, compression='none') as w:
        for ts, topic, data in events:
            w.write_raw(topic, ts, data)
    with open_bag(path) as b:
        ref = R._join_commands(b.columns('follow/status', R.REPLAY_FIELDS),
                               b.columns('axis/velocity_command', R.CMD_FIELDS))
    monkeypatch.setattr('ladrc_bags.Bag._indexed_files', lambda self: None)
    monkeypatch.setattr('ladrc_bags.reader.COLUMN_CHUNK', 37)
    parts = list(R._stream_batches(path, None))
    assert len(parts) > 1
    assert np.array_equal(np.concatenate([p.command for p in parts]), ref.command)
    assert np.array_equal(np.concatenate([p.command_present for p in parts]),
                          ref.command_present)
    assert 0 < np.count_nonzero(~ref.command_present) < n


# ---- bags of an older contract revision -------------------------------------------------------
REV1_MSGS = Path(__file__).resolve().parents[1] / 'data' / 'ladrc_msgs_rev1'
"""The ladrc_msgs .msg files of revision 1 (before the lock step and the CNC interface)."""


def _revision_1_store():
    store = get_typestore(Stores.ROS2_JAZZY)
    for f in sorted(REV1_MSGS.glob('*.msg')):
        store.register(get_types_from_msg(f.read_text(encoding='utf-8'),
                                          f'ladrc_msgs/msg/{f.stem}'))
    return store


def _in_revision(msg, store, typename: str):
    """``msg`` as ``store``'s definition of ``typename``: the fields both revisions have."""
    cls = store.types[typename]
    kw = {}
    for f in fields(cls):
        if f.name == '__msgtype__':
            continue
        value = getattr(msg, f.name)
        kw[f.name] = (_in_revision(value, store, value.__msgtype__) if is_dataclass(value)
                      else value)
    return cls(**kw)


def test_a_revision_1_bag_reads_in_columns_and_replays_bit_for_bit(headless, tmp_path, capsys):
    """A bag with revision 1's definitions stored: read by them (not the installed ones)."""
    _, path = headless
    old = _revision_1_store()
    rev1 = tmp_path / 'rev1'
    with open_bag(path) as b:
        custom = b.custom_data
    with AnyReader([path]) as r, BagWriter(rev1, typestore=old, custom_data=custom) as w:
        for c in r.connections:
            w.add_topic(c.topic, c.msgtype)
        for c, ts, data in r.messages():
            if c.msgtype.startswith('ladrc_msgs/'):
                msg = _in_revision(r.deserialize(data, c.msgtype), old, c.msgtype)
                data = bytes(old.serialize_cdr(msg, c.msgtype))
            w.write_raw(c.topic, ts, data)
    with open_bag(rev1) as b:
        assert b._indexed_files() is not None  # the tools' path: MCAP indexes + columns
        cols = b.read_topics({t: None for t in b.topics})
        msgs = {t: [m for _, m in b.messages(t)] for t in b.topics}
    st, cmd = cols['/follow/status'], cols['/axis/velocity_command']
    assert 'substate' not in st and 'hold_reason' not in st and 'commander' not in cmd
    assert any(st['fault_reason'])  # the drive fault's text, after the strings' fields move
    for topic, ms in msgs.items():  # every field as rosbags reads it by the bag's definitions
        for key, col in cols[topic].items():
            if key in ('timestamp_ns', 'stamp_s'):
                continue
            want = []
            for m in ms:
                for part in key.split('.'):
                    m = getattr(m, part)
                want.append(m)
            got = col.tolist()
            assert len(got) == len(want) and all(
                g == w or (isinstance(w, float) and math.isnan(w) and math.isnan(g))
                for g, w in zip(got, want, strict=True)), (topic, key)
    capsys.readouterr()
    assert ladrc(['replay', str(rev1)]) == 0
    line = _json_line(capsys.readouterr().out)
    assert line['mismatches'] == 0 and line['ticks'] == st['tick'].size
    assert line['internal_mismatch_ticks'] == 0
