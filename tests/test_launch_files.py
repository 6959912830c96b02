"""The launch files, run against stand-ins of launch / launch_ros (not installable from PyPI).

The stand-ins record what the launch files build: their arguments (each with a description),
the nodes with parameters passed the launch_ros way, and the stop chain (docs/follow-node.md,
"Launch files").
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
import signal
import sys
import types

from ladrc_bringup.bringup import LAUNCH_ARGUMENTS
import pytest

LAUNCH_DIR = Path(__file__).resolve().parents[1] / 'ros2_ws' / 'src' / 'ladrc_bringup' / 'launch'


class _Rec:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


def _stubs() -> dict[str, types.ModuleType]:
    mods = {}

    def mod(name, **attrs):
        m = types.ModuleType(name)
        m.__dict__.update(attrs)
        mods[name] = m
        return m

    class LaunchDescription(_Rec):
        pass

    class LaunchConfiguration:
        values: dict[str, str] = {}

        def __init__(self, name):
            self.name = name

        def perform(self, context):
            return context[self.name]

    names = ('DeclareLaunchArgument', 'OpaqueFunction', 'EmitEvent', 'RegisterEventHandler')
    mod('launch', LaunchDescription=LaunchDescription)
    mod('launch.actions', **{n: type(n, (_Rec,), {}) for n in names})
    mod('launch.substitutions', LaunchConfiguration=LaunchConfiguration)
    mod('launch.event_handlers', OnProcessExit=type('OnProcessExit', (_Rec,), {}))
    mod('launch.events', Shutdown=type('Shutdown', (_Rec,), {}),
        matches_action=lambda action: ('matches', action))
    mod('launch.events.process', SignalProcess=type('SignalProcess', (_Rec,), {}))
    mod('launch_ros')
    mod('launch_ros.actions', Node=type('Node', (_Rec,), {}))
    return mods


def _load(name: str, monkeypatch) -> types.ModuleType:
    for mname, m in _stubs().items():
        monkeypatch.setitem(sys.modules, mname, m)
    spec = importlib.util.spec_from_file_location(name, LAUNCH_DIR / name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _run(module, **given):
    ld = module.generate_launch_description()
    actions = ld.args[0]
    declared = {a.args[0]: a.kwargs for a in actions if type(a).__name__ ==
                'DeclareLaunchArgument'}
    context = {n: kw['default_value'] for n, kw in declared.items()}
    context.update(given)
    opaque = [a for a in actions if type(a).__name__ == 'OpaqueFunction']
    assert len(opaque) == 1
    built = opaque[0].kwargs['function'](context)
    return declared, built


def _chain(built) -> list[tuple[str, str]]:
    """(node that exits, what follows: a node name or 'shutdown')."""
    names = {id(n): n.kwargs['name'] for n in built if type(n).__name__ == 'Node'}
    out = []
    for h in built:
        if type(h).__name__ != 'RegisterEventHandler':
            continue
        on_exit = h.args[0]
        event = on_exit.kwargs['on_exit'][0].kwargs['event']
        who = names[id(on_exit.kwargs['target_action'])]
        if type(event).__name__ == 'Shutdown':
            out.append((who, 'shutdown'))
        else:
            assert event.kwargs['signal_number'] == signal.SIGINT
            out.append((who, names[id(event.kwargs['process_matcher'][1])]))
    return out


def test_bringup_launch_matches_bringup_and_stops_in_order(monkeypatch, tmp_path):
    module = _load('bringup.launch.py', monkeypatch)
    declared, built = _run(module, bag=str(tmp_path / 'bag'), hardware_id='head_3')
    assert set(declared) == set(LAUNCH_ARGUMENTS)
    assert all(kw['description'] for kw in declared.values())
    nodes = {n.kwargs['name']: n.kwargs for n in built if type(n).__name__ == 'Node'}
    assert set(nodes) == {'ladrc_recorder', 'ladrc_follow', 'ladrc_sim'}
    follow = nodes['ladrc_follow']['parameters']
    assert follow[0].endswith('follow.yaml')  # the parameter file, the launch_ros way
    assert follow[1] == {'loop': LAUNCH_ARGUMENTS['loop'][0], 'hardware_id': 'head_3'}
    assert nodes['ladrc_sim']['parameters'][-1]['scenario'] == 'showcase'
    assert nodes['ladrc_recorder']['parameters'][-1]['output'] == str(tmp_path / 'bag')
    # the scenario ends -> controller stops (zero command) -> recorder stops -> launch ends
    assert _chain(built) == [('ladrc_sim', 'ladrc_follow'), ('ladrc_follow', 'ladrc_recorder'),
                             ('ladrc_recorder', 'shutdown')]


def test_bringup_launch_in_lock_step(monkeypatch):
    module = _load('bringup.launch.py', monkeypatch)
    _, built = _run(module, bag='/tmp/x', lockstep='true')
    nodes = {n.kwargs['name']: n.kwargs['parameters'][-1] for n in built
             if type(n).__name__ == 'Node'}
    assert nodes['ladrc_follow']['loop'] == 'lockstep'
    assert nodes['ladrc_sim']['lockstep'] is True
    assert nodes['ladrc_recorder']['reliable'] is True  # lock step's writers are reliable


def test_axis_launch_has_no_simulator(monkeypatch):
    module = _load('axis.launch.py', monkeypatch)
    declared, built = _run(module)
    assert 'scenario' not in declared and {'params', 'bag', 'hardware_id'} <= set(declared)
    assert 'lockstep' not in declared  # the sim node's alone: refused against a real axis
    nodes = {n.kwargs['name'] for n in built if type(n).__name__ == 'Node'}
    assert nodes == {'ladrc_follow'}  # no bag given: no recorder
    assert _chain(built) == [('ladrc_follow', 'shutdown')]
    declared, built = _run(module, bag='/tmp/x')
    assert _chain(built) == [('ladrc_follow', 'ladrc_recorder'), ('ladrc_recorder', 'shutdown')]


@pytest.mark.parametrize('name', ['bringup.launch.py', 'axis.launch.py'])
def test_launch_files_are_installed(name):
    setup = (LAUNCH_DIR.parent / 'setup.py').read_text()
    assert "glob('launch/*.launch.py')" in setup
    assert (LAUNCH_DIR / name).is_file()
