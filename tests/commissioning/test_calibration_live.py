"""Capacitive calibration live: real processes over DDS (sim node, calibration, follow node).

* ``ladrc calibrate`` against the sim node builds a table within the sensor noise of the sim's
  truth and leaves the axis at its start;
* the calibration node's ``calibrate`` service: accepted, a second request rejected while the
  sweep runs, the result on ``calibration/result``;
* the follow node with ``sensor.table_file`` on a raw-only sim node (``gap_mm`` NaN) follows
  as with the published gap; a broken table is rejected at start-up and at a parameter set
  with its reason, and no table changes while following.

Every node set runs in lock step with the sim node (docs/follow-node.md): the outcome is the same
on a loaded machine and a quiet one, only slower.

The ROS environment (own ROS_DOMAIN_ID, localhost discovery) is the one of tests/ros/conftest.py,
loaded from there; topics and services go through the probe process (tests/support/rosnodes.py:
``Probe``); every process is ended by its PID.
"""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path
import subprocess
import time

import numpy as np
import pytest

pytest.importorskip('ladrc_msgs', reason='needs the built workspace (make test)')
_spec = importlib.util.spec_from_file_location(
    'ros_conftest_for_calibration', Path(__file__).parents[1] / 'ros' / 'conftest.py')
_ros = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_ros)  # sets ROS_DOMAIN_ID / localhost discovery for this session

from ladrc_bringup.bringup import executable_path  # noqa: E402
from ladrc_msgs.msg import (  # noqa: E402
    AxisFeedback,
    CapacitiveHeight,
    FollowStatus,
    SimTruth,
)
from ladrc_msgs.srv import Calibrate, StartFollow, StopFollow  # noqa: E402
from ladrc_tools.commissioning.calibration import (  # noqa: E402
    SweepMotion,
    run_headless,
    sim_scenario,
)
from ladrc_tools.commissioning.calibration_output import write_calibration  # noqa: E402
from ladrc_tools.commissioning.calibration_table import build_table  # noqa: E402
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402
from rosnodes import LATCHED, RELIABLE, NodeProcesses, Probe  # noqa: E402
from std_msgs.msg import String  # noqa: E402
import yaml  # noqa: E402

pytestmark = pytest.mark.ros
ROOT = Path(__file__).resolve().parents[2]
FOLLOW_SCENARIO = ROOT / 'tests' / 'ros' / 'scenarios' / 'follow_sine.yaml'
NOISE_MM = 0.005
# the product's stale limit: in lock step time is the sim's, so nothing needs relaxing
TIMEOUT_S = 0.01
# A bound on a hang, not on speed: lock step is slower on a loaded machine, never different.
HANG_S = 300.0


def _sim_scenario_file(tmp_path: Path, start_gap_mm: float, motion: SweepMotion) -> Path:
    path = tmp_path / 'calibrate_sensor.yaml'
    path.write_text(yaml.safe_dump(sim_scenario(start_gap_mm, motion)))
    return path


def _start_sim(nodes: NodeProcesses, scenario: Path, *extra: str) -> None:
    nodes.start('sim', 'ladrc_sim', 'sim_node', '-p', f'scenario:={scenario}', '-p',
                'lockstep:=true', '-p', 'realtime:=false', *extra)


@pytest.fixture()
def nodes():
    n = NodeProcesses()
    probe = Probe()
    try:
        yield n, probe
    finally:
        try:
            probe.close()  # raises with the probe's exit and output if it did not end cleanly
        finally:
            n.close()


def test_ladrc_calibrate_on_the_sim_node(nodes, tmp_path):
    n, probe = nodes
    motion = SweepMotion(descent_mm_s=1.0, min_start_gap_mm=1.0)
    start_gap_mm = 3.0  # the scenario's sheet is flat at 0 mm: the axis starts at 3.0 mm
    _start_sim(n, _sim_scenario_file(tmp_path, start_gap_mm, motion))
    # the samples of the run (the sim steps only while the calibration answers it; the probe
    # may match the sim's writers a few steps after the calibration did)
    fbs = probe.record(AxisFeedback, 'axis/feedback', fields='position_mm', qos=RELIABLE)
    gaps = probe.record(CapacitiveHeight, 'axis/capacitive_height',
                        fields=['raw_hz', 'gap_mm'], qos=RELIABLE)
    out = tmp_path / 'cal'
    cmd = [executable_path('ladrc_tools', 'ladrc'), 'calibrate', '-o', str(out),
           '--descent-mm-s', '1', '--min-start-gap-mm', '1',
           '--stale-ms', str(TIMEOUT_S * 1e3), '--lockstep']
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        stdout, stderr = proc.communicate(timeout=HANG_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stdout + stderr + n.log('sim')
    result = json.loads(stdout.strip().splitlines()[-1])
    assert result['ok'] and result['grade'] == 'A', result
    assert result['contact'] == 'collision status'
    # within the noise of the truth (sim/truth recorded by the tool), the noise as configured
    assert result['max_error_mm'] < NOISE_MM
    assert result['noise_mm'] == pytest.approx(NOISE_MM, rel=0.2)
    assert result['points'] >= 40 and result['range_mm'] > 2.5
    assert (out / 'cap_table.yaml').is_file() and (out / 'calibration.png').is_file()
    # the axis went back to its start
    assert probe.spin_until(lambda: len(fbs) > 1000, HANG_S)
    probe.spin_for(0.5)
    assert fbs[-1] == pytest.approx(start_gap_mm, abs=0.02)
    # the table reads the sim's gap: the sim's raw value is its reading's oscillator, so the
    # table of a raw value is that reading up to the table's own error (not the noise)
    from ladrc_follow.control.cap_table import load_table

    conv = load_table(out / 'cap_table.yaml')
    assert conv.gap_max_mm == pytest.approx(3.0, abs=0.01)  # up to the start height
    # every sample of the sweep, through the table: within the sensor noise (the bar)
    raw, gap = np.array(gaps[:]).T
    table_gap = conv.gaps_mm(raw)
    inside = np.isfinite(table_gap)
    assert inside.sum() > 1000
    assert np.abs(table_gap[inside] - gap[inside]).max() < NOISE_MM


def test_calibrate_service(nodes, tmp_path):
    n, probe = nodes
    _start_sim(n, _sim_scenario_file(tmp_path, 2.5, SweepMotion()))
    n.start('calibrate', 'ladrc_bringup', 'calibrate_node', '-p', 'descent_mm_s:=1.0',
            '-p', 'min_start_gap_mm:=1.0', '-p', f'stale_timeout_s:={TIMEOUT_S}',
            '-p', f'output_root:={tmp_path}', '-p', 'lockstep:=true')
    results: list[dict] = []
    probe.subscribe(String, 'calibration/result', lambda m: results.append(json.loads(m.data)),
                    LATCHED)
    fbs = probe.record(AxisFeedback, 'axis/feedback', fields='position_mm')
    assert probe.spin_until(lambda: len(fbs) > 100, HANG_S), n.log('sim')
    out = tmp_path / 'by_service'
    # the node refuses until its own subscriptions have fresh samples (matching takes a moment
    # on a loaded machine): ask again while that is the reason
    deadline = time.monotonic() + 30.0
    while True:
        res = probe.call(Calibrate, 'calibrate', Calibrate.Request(output_dir=str(out)),
                         timeout_s=30.0)
        if res.accepted or 'no recent samples' not in res.message \
                or time.monotonic() > deadline:
            break
        probe.spin_for(0.5)
    assert res.accepted, res.message + n.log('calibrate')
    again = probe.call(Calibrate, 'calibrate', Calibrate.Request(output_dir=''))
    assert not again.accepted and 'running' in again.message
    assert probe.spin_until(lambda: results, HANG_S), n.log('calibrate') + n.log('sim')
    r = results[-1]
    assert r['ok'] and r['grade'] == 'A' and r['output'] == str(out), r
    assert r['max_error_mm'] < NOISE_MM
    exists = probe.call(Calibrate, 'calibrate', Calibrate.Request(output_dir=str(out)))
    assert not exists.accepted and 'exists already' in exists.message
    assert n.interrupt('calibrate') == 0


def _table_for(sensor: dict, tmp_path: Path) -> Path:
    """Write a table from a headless sweep of the sim sensor these scenarios use."""
    motion = SweepMotion(descent_mm_s=1.0, retract_mm_s=4.0, min_start_gap_mm=1.0)
    proc = run_headless(sim_scenario(5.0, motion, **sensor), motion)
    assert proc.succeeded, proc.reason
    cal = build_table(proc.record)
    assert not cal.problems, cal.problems
    return write_calibration(cal, tmp_path / 'table') / 'cap_table.yaml'


def _set_table(probe: Probe, path: str):
    req = SetParameters.Request(parameters=[Parameter(
        name='sensor.table_file', value=ParameterValue(type=ParameterType.PARAMETER_STRING,
                                                       string_value=path))])
    return probe.call(SetParameters, '/ladrc_follow/set_parameters', req).results[0]


def _broken_copy(table: Path, tmp_path: Path) -> Path:
    d = yaml.safe_load(table.read_text())
    d['points'][10], d['points'][20] = [d['points'][20][0], d['points'][10][1]], d['points'][20]
    bad = tmp_path / 'broken.yaml'
    bad.write_text(yaml.safe_dump(d))
    return bad


def test_follow_with_the_table_on_a_raw_only_sim(nodes, tmp_path):
    n, probe = nodes
    sensor = yaml.safe_load(FOLLOW_SCENARIO.read_text())['sensor']
    table = _table_for(sensor, tmp_path)
    n.start('follow', 'ladrc_follow', 'follow_node', '-p', 'loop:=lockstep',
            '-p', f'sensor.table_file:={table}')
    _start_sim(n, FOLLOW_SCENARIO, '-p', 'raw_only:=true')
    S = FollowStatus
    status = probe.record(FollowStatus, 'follow/status',
                          fields=['state', 'gap_mm', 'gap_valid', 'gap_seq', 'fault_reason'],
                          qos=RELIABLE)
    truth = probe.record(SimTruth, 'sim/truth', fields=['seq', 'true_gap_mm'], qos=RELIABLE)
    sent = probe.record(CapacitiveHeight, 'axis/capacitive_height',
                        fields=['seq', 'gap_mm', 'raw_hz'], qos=RELIABLE)
    assert probe.spin_until(lambda: len(status) > 200 and status[-1][3] > 0 and len(truth) > 200,
                            HANG_S), n.log('follow') + n.log('sim')
    # the driver publishes raw values only; the controller reads a gap from its table
    seq, published, raw = sent[-1]
    assert math.isnan(published) and raw > 0
    state, gap, valid, gseq, _ = status[-1]
    assert state == S.STATE_IDLE and valid and gap == pytest.approx(3.0, abs=0.05)

    res = probe.call(StartFollow, 'follow/start', StartFollow.Request(target_gap_mm=1.0))
    assert res.accepted, res.message
    assert probe.spin_until(lambda: status[-1][0] == S.STATE_LADRC, HANG_S), status[-1]
    # no table change while following
    busy = _set_table(probe, str(table))
    assert not busy.successful and 'stop follow first' in busy.reason
    # follow the sine sheet (0.3 mm, 1 Hz from t = 4 s of the scenario) from 6 s to 8 s
    assert probe.spin_until(lambda: truth[-1][0] > 2000 * 8.0, HANG_S)
    seqs = [s for s, _ in truth]
    k, m = seqs.index(2000 * 6), seqs.index(2000 * 8)
    assert status[-1][0] == S.STATE_LADRC, status[-1]
    true_gap = np.array([g for _, g in truth[k:m]])
    assert len(true_gap) == 4000
    assert abs(true_gap.mean() - 1.0) < 0.03, true_gap.mean()
    assert true_gap.min() > 0.7  # no contact, close to the target throughout
    assert all(not s[4] for s in status[-2000:])  # no fault

    res = probe.call(StopFollow, 'follow/stop', StopFollow.Request())
    assert res.accepted, res.message
    assert probe.spin_until(lambda: status[-1][0] == S.STATE_IDLE, HANG_S)
    # a broken table is rejected with its reason, the running one stays in use
    bad = _set_table(probe, str(_broken_copy(table, tmp_path)))
    assert not bad.successful and 'not monotonic' in bad.reason, bad.reason
    missing = _set_table(probe, str(tmp_path / 'missing.yaml'))
    assert not missing.successful and 'cannot read' in missing.reason
    n_before = len(status)
    assert probe.spin_until(lambda: len(status) > n_before + 200, HANG_S)
    assert all(s[2] for s in status[n_before:])  # readings still valid through the table
    ok = _set_table(probe, '')  # back to gap_mm as published: NaN from this driver
    assert ok.successful, ok.reason
    n_before = len(status)
    assert probe.spin_until(lambda: len(status) > n_before + 200, HANG_S)
    assert not any(s[2] and s[1] == s[1] for s in status[n_before + 10:])
    assert n.interrupt('follow') == 0


def test_follow_node_refuses_to_start_with_a_broken_table(tmp_path):
    table = tmp_path / 'bad.yaml'
    table.write_text('format: ladrc-cap-table/1\nnoise_mm: 0.005\npoints: [[1.0, 0.1]]\n')
    proc = subprocess.run([executable_path('ladrc_follow', 'follow_node'), '--ros-args', '-p',
                           f'sensor.table_file:={table}'], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and 'sensor.table_file' in lines[0] and 'too few points' in lines[0]
