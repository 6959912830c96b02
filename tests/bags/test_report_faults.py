"""A run's faults, holds and states: the run log, and the report that names every fault."""

from __future__ import annotations

import json
from pathlib import Path

from ladrc_contract.codes import FaultCode, FollowState, SubState
from ladrc_contract.run_log import RunLog, verdict
import ladrc_sim.headless
from ladrc_tools.cli import main as ladrc
import numpy as np
import pytest
import yaml

H_S = 0.0005


def _random_run(n: int, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    state = np.repeat(rng.integers(0, len(FollowState), n // 50 + 1), 50)[:n]
    sub = np.repeat(rng.integers(0, len(SubState), n // 30 + 1), 30)[:n]
    t = np.arange(n) * H_S
    reason = np.array([f'reason {k}' if s == FollowState.FAULT else ''
                       for k, s in enumerate(state)], dtype=object)
    return {'t': t, 'state': state, 'sub': sub, 'reason': reason,
            'gap_age': rng.uniform(0, 0.02, n), 'enc_age': rng.uniform(0, 0.02, n)}


def test_tick_by_tick_equals_columns_in_slices():
    r = _random_run(3000, 3)
    live = RunLog(H_S)
    for i in range(r['t'].size):
        live.tick(float(r['t'][i]), int(r['state'][i]), r['reason'][i], float(r['gap_age'][i]),
                  float(r['enc_age'][i]), int(r['sub'][i]))
    bag = RunLog()
    for a, b in ((0, 7), (7, 1234), (1234, 3000)):
        bag.add(r['t'][a:b], r['state'][a:b], r['reason'][a:b], r['gap_age'][a:b],
                r['enc_age'][a:b], r['sub'][a:b])
    assert live.summary() == bag.summary()
    s = live.summary()
    entries = np.flatnonzero((r['state'] == FollowState.FAULT)
                             & (np.r_[-1, r['state'][:-1]] != FollowState.FAULT))
    assert [f['t_s'] for f in s['faults']] == [round(float(r['t'][i]), 4) for i in entries]
    assert [f['reason'] for f in s['faults']] == [f'reason {i}' for i in entries]
    assert sum(s['state_s'].values()) == pytest.approx(3000 * H_S)


def test_verdict_fails_an_undeclared_fault_at_the_end_only():
    log = RunLog(H_S)
    for i, st in enumerate([0, 4, 4, 5, 5, 0, 4]):  # a fault, reset, following at the end
        log.tick(i * H_S, st, 'stale input' if st == 5 else '', 0.011, 0.0)
    ok, text = verdict(log.summary())
    assert ok and '1 fault(s)' in text
    log.tick(7 * H_S, 5, 'drive fault', 0.0, 0.0)
    assert not verdict(log.summary())[0]
    assert verdict(log.summary(), expect_fault=True)[0]
    assert log.summary()['final_state'] == 'FAULT'
    assert [f['state_before'] for f in log.summary()['faults']] == ['LADRC', 'LADRC']


@pytest.fixture(scope='module')
def faults_report(tmp_path_factory):
    """``ladrc simulate faults`` (the real controller; a 20 ms sensor dropout) and its report."""
    base = tmp_path_factory.mktemp('faults')
    assert ladrc(['simulate', 'faults', '-o', str(base / 'bag')]) == 0
    assert ladrc(['report', str(base / 'bag'), '-o', str(base / 'rep'), '-q']) == 0
    return base / 'rep'


def test_the_report_names_the_injected_fault_in_json_md_and_html(faults_report):
    rep = json.loads((faults_report / 'report.json').read_text())
    assert len(rep['faults']) == 1
    fault = rep['faults'][0]
    # the dropout starts at 1.0 s: the gap's age passes the 10 ms stale limit 10 ms later
    assert fault['t_s'] == pytest.approx(1.0095, abs=0.002)
    assert fault['state_before'] == 'LADRC' and fault['reason']
    assert fault['gap_age_ms'] >= 10.0 and fault['encoder_age_ms'] < 1.0
    assert rep['final_state'] == 'FAULT' and rep['states']['FAULT'] > 2.5
    assert rep['ok']  # the faults scenario declares its faults (expect_fault)
    base = rep['metrics_time_base']
    assert 0 < base['followed_s'] < base['run_s']
    md = (faults_report / 'report.md').read_text()
    assert f'| F1 | {fault["t_s"]:.4f} | LADRC | {fault["reason"]}' in md
    assert f'{base["followed_s"]:g} s of {base["run_s"]:g} s' in md
    html = (faults_report / 'report.html').read_text()
    meta = json.loads(html.split('id="ladrc-meta">', 1)[1].split('</script>', 1)[0])
    assert meta['faults'] == [{'t': fault['t_s'], 'label': 'F1'}]
    assert meta['title'] == f'Report: {rep["title"]}' and rep['title'].startswith('faults (')


def test_an_undeclared_fault_fails_the_run(tmp_path):
    shipped = Path(ladrc_sim.headless.__file__).parent / 'scenarios' / 'faults.yaml'
    data = {**yaml.safe_load(shipped.read_text()), 'expect_fault': False, 'name': 'undeclared'}
    (tmp_path / 'undeclared.yaml').write_text(yaml.safe_dump(data))
    assert ladrc(['simulate', str(tmp_path / 'undeclared.yaml'), '-o', str(tmp_path / 'b')]) == 0
    assert ladrc(['report', str(tmp_path / 'b'), '-o', str(tmp_path / 'r'), '-q']) == 0
    rep = json.loads((tmp_path / 'r' / 'report.json').read_text())
    assert not rep['ok'] and rep['final_state'] == 'FAULT' and len(rep['faults']) == 1
    assert (tmp_path / 'r' / 'report.md').read_text().splitlines()[2].startswith('**1 fault')


@pytest.mark.parametrize('event,code', [
    ({'do': 'sensor_dropout', 'duration_s': 0.05}, FaultCode.STALE_INPUT),
    ({'do': 'drive', 'enabled': True, 'fault': True}, FaultCode.DRIVE),
    ({'do': 'coverage', 'value': 0.0, 'ramp_s': 0.05}, FaultCode.SENSOR),
])
def test_the_controller_names_each_fault_by_its_code(event, code):
    """A fault's FaultCode comes from where it is raised; the run log keeps it with the reason."""
    from ladrc_follow.control.follow import FollowController
    from ladrc_follow.control.params import ControllerParams
    from ladrc_sim.headless.runner import run
    from ladrc_sim.headless.scenario import scenario_from_dict

    sc = scenario_from_dict({'name': 'one_fault', 'duration_s': 1.5, 'initial_gap_mm': 1.0,
                             'timeline': [{'t_s': 0.0, 'do': 'start_follow',
                                           'target_gap_mm': 1.0}, {'t_s': 0.8, **event}]})
    ctl = FollowController(ControllerParams())
    log = RunLog(H_S)

    class Logged:
        def command(self, name, **kw):
            return ctl.command(name, **kw)

        def step(self, tick):
            u = ctl.step(tick)
            st = ctl.internals()
            log.tick(tick.t_s, st['state'], st['fault_reason'], tick.t_s - tick.gap_stamp_s,
                     tick.t_s - tick.encoder_stamp_s, st['substate'], ctl.fault_code)
            return u

    run(sc, Logged())
    faults = log.summary()['faults']
    assert [f['code'] for f in faults] == [code.name], faults
    assert ctl.fault_code == code
