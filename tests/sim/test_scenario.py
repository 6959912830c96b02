"""Scenario files: every shipped file loads; each broken file gives a clear one-line error."""

from pathlib import Path

from ladrc_sim.headless.scenario import (
    COMMANDS,
    ScenarioError,
    list_scenarios,
    load_scenario,
    scenario_from_dict,
)
import pytest

BROKEN = sorted((Path(__file__).parent / 'broken').glob('*.yaml'))
NOTES_TESTS = {'sine_1hz', 'step_sine_1hz', 'step', 'high_step_1_10', 'chirp_0_5hz', 'square',
               'triangle_ridge', 'feedback_gain_noise', 'edge_step_2_5', 'edge_step_3_1',
               'edge_open_10_1', 'thin_sheet', 'sine_5hz', 'showcase'}


def test_the_library_covers_the_notes_test_plan():
    names = {p.stem for p in list_scenarios()}
    assert NOTES_TESTS <= names


@pytest.mark.parametrize('path', list_scenarios(), ids=lambda p: p.stem)
def test_every_shipped_scenario_loads(path):
    sc = load_scenario(path)
    assert sc.name == path.stem
    assert sc.description
    assert any(e.name == 'start_follow' for e in sc.timeline)
    assert all(0 <= e.t_s <= sc.duration_s for e in sc.timeline)


def test_showcase_has_the_demo_ingredients():
    sc = load_scenario('showcase')
    kinds = {type(p).__name__ for p in sc.sheet.profiles}
    assert {'Waviness', 'PlateParams'} <= kinds
    assert 20.0 <= sc.duration_s <= 30.0 and sc.initial_gap_mm == 10.0
    assert any(e.name == 'coverage' and e.args['value'] < 1 for e in sc.timeline)


@pytest.mark.parametrize('path', BROKEN, ids=lambda p: p.stem)
def test_broken_file_gives_one_line_error_naming_file_and_key(path):
    expect = path.read_text().splitlines()[0].removeprefix('# expect:').strip()
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    msg = str(info.value)
    assert '\n' not in msg
    assert msg.startswith(f'{path}: ')
    assert f': {expect}' in msg, msg
    assert len(msg) < 400


def test_enough_broken_files():
    assert len(BROKEN) >= 12


def test_defaults_and_event_sorting():
    sc = scenario_from_dict({'name': 'x', 'duration_s': 1, 'timeline': [
        {'t_s': 0.5, 'do': 'gradient_follow', 'target_gap_mm': 2},
        {'t_s': 0.1, 'do': 'start_follow', 'target_gap_mm': 1}]})
    assert [e.name for e in sc.timeline] == ['start_follow', 'gradient_follow']
    assert sc.timeline[1].args == {'target_gap_mm': 2.0, 'delay_s': 0.0}
    assert sc.duration_s == 1.0 and isinstance(sc.duration_s, float)
    assert set(COMMANDS) == {'start_follow', 'set_target', 'stop_follow', 'reset_fault',
                             'machining', 'height_compensation', 'gradient_follow',
                             'target_wave', 'pierce', 'lift', 'hold', 'leapfrog'}
    pierce = scenario_from_dict({'name': 'p', 'duration_s': 1, 'timeline': [
        {'t_s': 0.0, 'do': 'pierce', 'heights_mm': [3, 2.5], 'dwell_s': [0.1, 0.1],
         'cut_gap_mm': 1}]})
    assert pierce.timeline[0].args == {'heights_mm': (3.0, 2.5), 'dwell_s': (0.1, 0.1),
                                       'cut_gap_mm': 1.0, 'thc_delay_s': 0.0, 'locked': False}
    with pytest.raises(ScenarioError, match='heights_mm: expected a list of numbers'):
        scenario_from_dict({'name': 'p', 'duration_s': 1, 'timeline': [
            {'t_s': 0.0, 'do': 'pierce', 'heights_mm': 3, 'dwell_s': [0.1], 'cut_gap_mm': 1}]})
    wave = scenario_from_dict({'name': 'w', 'duration_s': 1, 'timeline': [
        {'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1},
        {'t_s': 0.2, 'do': 'target_wave', 'amp_mm': 0.1, 'freq_hz': 5}]})
    assert wave.timeline[1].args == {'kind': 'sine', 'amp_mm': 0.1, 'freq_hz': 5.0,
                                     'freq_end_hz': 0.0, 'duration_s': 0.0}
    with pytest.raises(ScenarioError, match=r"timeline\[1\]\.kind: 'triangle' is not one of sine"):
        scenario_from_dict({'name': 'w', 'duration_s': 1, 'timeline': [
            {'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1},
            {'t_s': 0.2, 'do': 'target_wave', 'kind': 'triangle', 'amp_mm': 0.1,
             'freq_hz': 5}]})


def test_missing_file_and_empty_file(tmp_path):
    with pytest.raises(ScenarioError, match='cannot read'):
        load_scenario(tmp_path / 'nope.yaml')
    empty = tmp_path / 'empty.yaml'
    empty.write_text('')
    with pytest.raises(ScenarioError, match='empty'):
        load_scenario(empty)


def test_binary_and_deeply_nested_files_are_one_line_errors(tmp_path):
    binary = tmp_path / 'binary.yaml'
    binary.write_bytes(bytes(range(256)) * 8)
    deep = tmp_path / 'deep.yaml'
    deep.write_text('x: ' + '[' * 5000 + ']' * 5000)
    for path, expect in ((binary, 'not a text (UTF-8) file'), (deep, 'nested too deeply')):
        with pytest.raises(ScenarioError) as info:
            load_scenario(path)
        assert expect in str(info.value) and '\n' not in str(info.value)


def test_the_live_sim_forwards_every_scenario_command_to_a_follow_service():
    from ladrc_contract.services import FOLLOW_SERVICES

    assert set(FOLLOW_SERVICES) == set(COMMANDS)
