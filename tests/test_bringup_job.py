"""``bringup --job``: the node set of a cutting job, its parameters, its refusals (no ROS)."""

from __future__ import annotations

from ladrc_bringup import bringup
from ladrc_bringup.bringup import job_params_file, node_specs
from ladrc_follow.control.params import load_params
from ladrc_sim.job.jobfile import shipped_jobs


def test_a_job_gives_the_follow_node_its_own_parameters_over_the_set(tmp_path):
    base = load_params(bringup.default_params_file())
    path = job_params_file('thin_warped', None, tmp_path)  # {cnc.feed_override_min: 0.5}
    params = load_params(path)
    assert base.cnc.feed_override_min != 0.5 and params.cnc.feed_override_min == 0.5
    assert params.law == base.law and params.eso == base.eso  # the rest is the set as given


def test_the_sim_node_plays_the_job_instead_of_a_scenario():
    specs = {s.name: s for s in node_specs('showcase', bag='b', job='plate_holes',
                                           lockstep=True)}
    assert specs['ladrc_sim'].parameters['job'] == 'plate_holes'
    assert 'scenario' not in specs['ladrc_sim'].parameters
    assert specs['ladrc_recorder'].parameters['scenario'] == 'plate_holes'


def test_a_separate_cnc_is_the_cnc_node_beside_the_sim():
    specs = {s.name: s for s in node_specs('showcase', job='plate_holes', lockstep=True,
                                           separate_cnc=True)}
    assert specs['ladrc_sim'].parameters['separate_cnc'] is True
    cnc = specs['ladrc_cnc']
    assert (cnc.package, cnc.executable) == ('ladrc_sim', 'cnc_node')
    assert cnc.parameters == {'job': 'plate_holes', 'lockstep': True}
    assert 'ladrc_cnc' not in {s.name for s in node_specs('showcase', job='plate_holes')}


def test_a_separate_cnc_without_a_job_is_one_line(capsys, monkeypatch):
    started = []
    monkeypatch.setattr(bringup.Bringup, 'start', lambda self: started.append(self))
    assert bringup.main(['--separate-cnc']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ['bringup: --separate-cnc needs --job (a scenario has no CNC)']
    assert not started


def test_an_unknown_job_or_a_bad_override_is_one_line_and_nothing_starts(tmp_path, capsys,
                                                                          monkeypatch):
    started = []
    monkeypatch.setattr(bringup.Bringup, 'start', lambda self: started.append(self))
    assert bringup.main(['--job', 'no_such_job']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [err[0]] and 'no_such_job: no such job file or shipped job' in err[0]
    shipped = shipped_jobs()['thin_warped']
    job = tmp_path / 'bad.yaml'  # the shipped job with an override out of its range
    job.write_text(shipped.read_text().replace('dxf: plate_holes.dxf',
                                               f'dxf: {shipped.parent / "plate_holes.dxf"}')
                   .replace('cnc.feed_override_min: 0.5', 'cnc.feed_override_min: 7.0'))
    assert bringup.main(['--job', str(job)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f'bringup: {job}: controller: ')
    assert 'feed_override_min = 7' in err[0]
    assert not started
