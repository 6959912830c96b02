"""The live view (view_node, docs/live-view.md): what a Foxglove client receives, and calls.

* The decimation alone (no ROS): every interval's min and max are numpy's over its samples,
  every change is kept, a 2 ms spike is on screen, batch boundaries change nothing.
* A lock-step run of the ``faults`` scenario with the view beside it (the view started first,
  a WebSocket client speaking the Foxglove protocol subscribed, then ``bringup --lockstep
  --bag``): every status message received equals the bag's message of the same tick; in each
  display interval the view received whole, the min and max of the gap, target, fused gap and
  commands equal numpy's over the bag's samples of that interval; every fault reason of the
  bag arrives (status and log); every event arrives, and a client connecting after the run
  gets them all too.
* Beside a free-running node set: the operator's calls (start, stop, lift, a malformed one)
  reach the follow node through the view's services and come back with its answers; the
  server listens on 127.0.0.1 only (the node-socket check of docs/safety.md) and the view uses
  no ROS endpoint the SROS2 policy does not allow.
* A port in use: one line, exit 2 (view_node and ``bringup --view``).
* The shipped layout: every panel's settings are ones the pinned foxglove-sdk's layout
  classes know, and every path reads a field both of the live channel and of the bag's topic.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import re
import socket
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip('ladrc_msgs', reason='needs the built workspace (make test)')
pytest.importorskip('foxglove', reason='needs foxglove-sdk (requirements/python.txt)')
pytest.importorskip('websockets', reason='needs websockets (requirements/dev.txt)')
from foxglove_client import FoxgloveClient, ServiceCallFailure  # noqa: E402
from ladrc_bags import open_bag  # noqa: E402
from ladrc_bags.layouts import TITLE, config_dir, foxglove_json  # noqa: E402
from ladrc_bringup.bringup import (  # noqa: E402
    Bringup,
    executable_path,
    isolated_env,
    node_specs,
)
from ladrc_tools.node.view_channels import (  # noqa: E402
    STATUS,
    VIEWS,
    XY_CHANNEL,
    Decimator,
    TopicView,
    select,
)
from rosnodes import NodeProcesses, Probe  # noqa: E402
from sockets import exposed, sockets  # noqa: E402
import sros2_policy  # noqa: E402

pytestmark = pytest.mark.ros
SCENARIOS = Path(__file__).parent / 'scenarios'
BIN = Path(executable_path('ladrc_bringup', 'bringup')).parent
INTERVAL_NS = 20_000_000  # the default display rate, 50 Hz


# ---- the decimation alone ------------------------------------------------------------------
def _synthetic(n: int, spike_at: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(4)
    t_ns = np.arange(n, dtype=np.int64) * 500_000 + 3_000_000_123
    gap = 1.0 + 0.01 * rng.standard_normal(n)
    gap[spike_at:spike_at + 4] = 0.2  # 2 ms
    gap[7] = np.nan
    state = np.where(np.arange(n) < n // 3, 3, 4).astype(np.uint8)
    reason = np.full(n, '', dtype=object)
    reason[n // 2:n // 2 + 3] = 'a'
    reason[n // 2 + 3:] = 'b'
    return {'header.stamp.sec': (t_ns // 1_000_000_000).astype(np.int32),
            'header.stamp.nanosec': (t_ns % 1_000_000_000).astype(np.uint32),
            'gap_mm': gap, 'state': state, 'fault_reason': reason}


VIEW = TopicView('x', 'x', ('header.stamp.sec', 'header.stamp.nanosec', 'gap_mm', 'state',
                            'fault_reason'), extremes=('gap_mm',),
                 changes=('state', 'fault_reason'))


def test_decimation_keeps_every_extreme_and_every_change_across_batches():
    n = 4000  # 2 s at 2 kHz
    cols = _synthetic(n, spike_at=1234)
    whole, _, lengths = select(cols, INTERVAL_NS, VIEW.extremes, VIEW.changes)
    dec = Decimator(VIEW, INTERVAL_NS)
    got, counts, closed = [], [], 0  # closed rows come in order: their offset is a count
    cuts = [0, 1, 57, 58, 600, 1233, 1236, 2999, 3500, n]  # batch edges inside intervals
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        rows, index, view_ticks = dec.push({k: v[a:b] for k, v in cols.items()})
        got += (closed + index).tolist()
        counts += view_ticks.tolist()
        closed += len(rows['gap_mm'])
    rows, index, view_ticks = dec.flush()
    got += (closed + index).tolist()
    counts += view_ticks.tolist()
    assert got == whole.tolist()  # batches change nothing
    assert dec.received == n and dec.sent == len(got)
    t_ns = cols['header.stamp.sec'].astype(np.int64) * 10**9 + cols['header.stamp.nanosec']
    bucket = t_ns // INTERVAL_NS
    sent = np.zeros(n, bool)
    sent[got] = True
    for b in np.unique(bucket):
        inside = bucket == b
        mine = inside & sent
        assert np.nanmin(cols['gap_mm'][mine]) == np.nanmin(cols['gap_mm'][inside])
        assert np.nanmax(cols['gap_mm'][mine]) == np.nanmax(cols['gap_mm'][inside])
    assert sent[1234:1238].any()  # the 2 ms spike is on screen at its value
    changes = np.flatnonzero(np.r_[True, cols['state'][1:] != cols['state'][:-1]]
                             | np.r_[True, cols['fault_reason'][1:] != cols['fault_reason'][:-1]])
    assert sent[changes].all()
    assert set(counts) <= {int(c) for c in np.bincount(bucket - bucket[0]) if c}
    assert len(got) <= len(np.unique(bucket)) * 3 + len(changes)  # what a screen shows


# ---- live ----------------------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def _start_view(nodes: NodeProcesses, port: int) -> tuple[subprocess.Popen, FoxgloveClient]:
    proc = nodes.start('view', 'ladrc_tools', 'view_node', '-p', f'port:={port}')
    client = FoxgloveClient(f'ws://127.0.0.1:{port}', connect_timeout_s=60.0)
    assert client.wait_for(lambda: '/follow/status' in client.messages
                           and len(client.services) == 4, 30.0), (
        client.channels, client.services, nodes.log('view'))
    return proc, client


def _stamp_ns(d: dict) -> int:
    return d['header']['stamp']['sec'] * 1_000_000_000 + d['header']['stamp']['nanosec']


def _same(live, recorded) -> bool:
    if live is None:
        return isinstance(recorded, float) and not np.isfinite(recorded)
    if isinstance(recorded, (float, np.floating)):
        return float(live) == float(recorded)
    return live == recorded


def test_the_view_of_a_lockstep_run_equals_its_bag(tmp_path):
    nodes = NodeProcesses()
    port = _free_port()
    bag = tmp_path / 'bag'
    try:
        _proc, client = _start_view(nodes, port)
        res = subprocess.run(
            [str(BIN / 'bringup'), '--scenario', 'faults', '--lockstep', '--bag', str(bag),
             '--domain-id', os.environ['ROS_DOMAIN_ID'], '--logs', str(tmp_path / 'logs')],
            capture_output=True, text=True, timeout=600)
        assert res.returncode == 0, res.stderr[-3000:]
        with open_bag(bag) as b:
            fields = [f for f in STATUS.fields]
            st = b.columns('follow/status', fields)
            n_events = b.columns('follow/events', ['tick'])['tick'].size
        last_tick = int(st['tick'][-1])
        status = client.messages['/follow/status']
        assert client.wait_for(lambda: status and status[-1].data['tick'] >= last_tick, 30.0), (
            last_tick, status[-1].data if status else None, nodes.log('view'))
        kinds = [m.data['kind_name'] for m in client.messages['/follow/events']]
        # a client that comes late gets the events so far (the parameter set in force first;
        # the clients subscribed before get them again then)
        late = FoxgloveClient(f'ws://127.0.0.1:{port}', topics=['/follow/events'])
        try:
            assert late.wait_for(lambda: len(late.messages.get('/follow/events', []))
                                 >= n_events, 30.0)
            late_kinds = [m.data['kind_name'] for m in late.messages['/follow/events']]
        finally:
            late.close()
    finally:
        nodes.close()
        client.close()
    by_tick = {int(t): i for i, t in enumerate(st['tick'].tolist())}
    assert len(status) < 0.2 * st['tick'].size  # decimated
    # each message received is the bag's message of that tick, field by field, at its stamp
    for m in status:
        i = by_tick[m.data['tick']]
        assert m.log_time_ns == _stamp_ns(m.data)
        for f in fields:
            parts = f.split('.')
            live = m.data
            for p in parts:
                live = live[p]
            assert _same(live, st[f][i]), (m.data['tick'], f, live, st[f][i])
    # per display interval the view saw whole: min and max are numpy's over the bag's samples
    t_ns = st['header.stamp.sec'].astype(np.int64) * 10**9 + st['header.stamp.nanosec']
    bucket = t_ns // INTERVAL_NS
    received: dict[int, list] = {}
    for m in status:
        received.setdefault(m.log_time_ns // INTERVAL_NS, []).append(m.data)
    whole = 0
    for b, msgs in received.items():
        inside = bucket == b
        if msgs[0]['view_ticks'] != int(inside.sum()):
            continue  # a sample the best-effort reader lost: not comparable
        whole += 1
        for f in STATUS.extremes:
            live = np.array([np.nan if d[f] is None else d[f] for d in msgs], dtype=float)
            ref = st[f][inside].astype(float)
            if np.all(np.isnan(ref)):
                continue
            assert np.nanmin(live) == np.nanmin(ref) and np.nanmax(live) == np.nanmax(ref), (
                b, f)
    # (the buckets with a sample the best-effort reader lost are left out, a sixth of them
    # beside a busy machine; the comparison needs enough whole ones)
    assert whole >= 0.5 * len(np.unique(bucket)), (whole, len(np.unique(bucket)))
    # every fault reason of the bag arrives, on the status and in the log
    reasons = {r for r in st['fault_reason'].tolist() if r}
    assert reasons, 'the faults scenario faults'
    assert reasons <= {m.data['fault_reason'] for m in status}
    logged = {m.data['message'] for m in client.messages['/view/log']}
    assert {'FAULT: ' + r for r in reasons} <= logged
    # every event arrives, not decimated; a late client gets them too
    assert len(kinds) == n_events and late_kinds == kinds and kinds[0] == 'PARAMETERS', kinds


def test_operator_calls_reach_the_follow_node_and_the_view_stays_on_loopback(tmp_path):
    domain = int(os.environ['ROS_DOMAIN_ID'])
    nodes = NodeProcesses()
    probe = Probe()
    port = _free_port()
    # in lock step, paced: a loaded machine makes the run slower, never a timing fault
    up = Bringup(node_specs(str(SCENARIOS / 'follow_sine.yaml'), lockstep=True),
                 isolated_env(domain), tmp_path / 'logs')
    client = None
    try:
        proc, client = _start_view(nodes, port)
        up.start()
        status = client.messages['/follow/status']
        # the controller has the sim's samples (an enabled drive)
        assert client.wait_for(lambda: status and status[-1].data['drive_enabled'], 60.0), (
            nodes.log('view'))
        # stop from IDLE, start, then stop: each answered by the follow node itself
        answer = client.call('/follow/start', {'target_gap_mm': 1.0})
        assert answer['accepted'], answer
        assert client.wait_for(lambda: status[-1].data['state'] in (3, 4), 30.0), [
            (m.data['state'], m.data['fault_reason']) for m in status[-30:]]
        refused = client.call('/follow/start', {'target_gap_mm': 500.0})
        assert refused['accepted'] is False and refused['message'], refused
        lift = client.call('/follow/lift', {'mode': 1, 'value_mm': 2.0, 'velocity_mm_s': 0.0})
        assert lift['accepted'], lift
        assert client.wait_for(lambda: status[-1].data['substate'] == 5, 30.0)  # SUB_LIFT
        assert client.call('/follow/stop')['accepted']
        assert client.wait_for(lambda: status[-1].data['state'] == 0, 30.0)
        with pytest.raises(ServiceCallFailure, match='target_gap_mm'):
            client.call('/follow/start', {'gap': 1.0})  # not a field of the request
        events = client.messages['/follow/events']
        client.wait_for(lambda: events and events[-1].data['kind_name'] == 'STOP_FOLLOW', 10.0)
        kinds = [m.data['kind_name'] for m in events]
        assert kinds[-3:] == ['START_FOLLOW', 'LIFT', 'STOP_FOLLOW'], kinds
        logged = [m.data['message'] for m in client.messages['/view/log']]
        assert any(line.startswith('operator follow/start') for line in logged), logged
        # the node-socket check: the WebSocket server listens on 127.0.0.1 only, and the
        # process binds nothing else outside loopback
        opened = sockets(proc.pid)
        assert ('tcp', '127.0.0.1', port, True) in opened, opened
        assert not exposed(proc.pid), exposed(proc.pid)
        # the view uses no endpoint the SROS2 policy does not give it (operator enclave)
        graph = probe.graph()
        assert '/ladrc_view' in graph, sorted(graph)
        missing = sros2_policy.uncovered({'/ladrc_view': graph['/ladrc_view']},
                                         sros2_policy.profiles())
        assert not missing, '\n'.join(missing)
        assert sros2_policy.profiles()['/ladrc_view'].enclave == '/ladrc/operator'
    finally:
        try:
            probe.close()
        finally:
            up.stop()
            if client is not None:
                client.close()
            nodes.close()


def test_a_port_in_use_is_one_line_and_exit_2(tmp_path):
    with socket.socket() as busy:
        busy.bind(('127.0.0.1', 0))
        busy.listen()
        port = busy.getsockname()[1]
        res = subprocess.run([executable_path('ladrc_tools', 'view_node'), '--port', str(port)],
                             capture_output=True, text=True, timeout=120)
        assert res.returncode == 2, res
        lines = res.stderr.strip().splitlines()
        assert len(lines) == 1 and f'cannot listen on 127.0.0.1:{port}' in lines[0], res.stderr
        res = subprocess.run([str(BIN / 'bringup'), '--view', '--view-port', str(port)],
                             capture_output=True, text=True, timeout=60)
        assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
        assert f'127.0.0.1:{port}' in res.stderr


# ---- the shipped layout ----------------------------------------------------------------------
def _config_classes() -> dict[str, type]:
    import foxglove.layouts as fl

    return {'Plot': fl.PlotConfig, 'StateTransitions': fl.StateTransitionsConfig,
            'Log': fl.LogConfig, 'RawMessages': fl.RawMessagesConfig,
            'ServiceCall': fl.ServiceCallConfig}


def _keys(cls: type) -> set[str]:
    import dataclasses

    inst = cls(**{f.name: None for f in dataclasses.fields(cls) if f.default is
                  dataclasses.MISSING and f.default_factory is dataclasses.MISSING})
    return set(inst._to_dict())


def test_the_shipped_layout_uses_known_settings_and_fields_of_both_sources():
    import foxglove.layouts as fl
    from ladrc_bags.typestore import ladrc_typestore

    layout = json.loads((config_dir() / 'foxglove_layout.json').read_text())
    assert layout == json.loads(foxglove_json())
    classes = _config_classes()
    series_keys = {'Plot': _keys(fl.PlotSeries), 'StateTransitions':
                   _keys(fl.StateTransitionsSeries)}
    live = {v.channel: v for v in VIEWS}
    store = ladrc_typestore()
    paths = []
    for pid, config in layout['configById'].items():
        kind = pid.split('!')[0]
        assert kind in classes, pid
        known = _keys(classes[kind]) | {TITLE}  # the layout file keeps a panel's title there
        assert set(config) <= known, (pid, set(config) - known)
        for s in config.get('paths', []):
            assert set(s) <= series_keys[kind], (pid, set(s) - series_keys[kind])
            paths += [s['value']] + ([s['xValuePath']] if 'xValuePath' in s else [])
    assert any(p.startswith(XY_CHANNEL) for p in paths)
    for path in paths:
        m = re.match(r'^(/[a-z_/]+?)(\{[^}]*\})?\.([a-z_0-9]+)$', path)
        assert m, path
        topic, _, field = m.groups()
        if topic in live:  # a contract topic: the bag's field, and the live channel carries it
            names = [f[0] for f in store.fielddefs[live[topic].msgtype][1]]
            assert field in names and field in live[topic].fields, path
        else:
            assert topic == XY_CHANNEL, path


if __name__ == '__main__':  # pragma: no cover
    sys.exit(pytest.main([__file__, '-q']))
