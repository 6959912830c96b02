"""What each process loads: the follow node runs on rclpy + messages + the core alone.

Importing a node module in a fresh interpreter (the source tree first on the path) must not
pull in another layer's libraries: the follow node serializes with its own CDR packer (no
rosbags), and neither node imports the tools, matplotlib or the other package.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import subprocess
import sys

import pytest

pytest.importorskip('rclpy')

SRC = Path(__file__).resolve().parents[2] / 'ros2_ws' / 'src'
PROBE = """
import importlib, json, sys
mod = importlib.import_module(sys.argv[1])
print(json.dumps({'file': mod.__file__,
                  'loaded': sorted({m.split('.')[0] for m in sys.modules})}))
"""


@pytest.mark.parametrize(('module', 'package', 'forbidden'), [
    ('ladrc_follow.node.follow_node', 'ladrc_follow',
     {'rosbags', 'ladrc_sim', 'ladrc_bags', 'ladrc_tools', 'ladrc_bringup', 'ladrc_fleet',
      'matplotlib', 'scipy'}),
    ('ladrc_sim.node.sim_node', 'ladrc_sim',
     {'rosbags', 'ladrc_follow', 'ladrc_bags', 'ladrc_tools', 'ladrc_bringup', 'ladrc_fleet',
      'matplotlib'}),
])
def test_node_module_loads_only_its_layer(module, package, forbidden):
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(SRC / package),
                                                      env.get('PYTHONPATH')]))
    proc = subprocess.run([sys.executable, '-c', PROBE, module], capture_output=True,
                          text=True, env=env, timeout=60)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    # the source tree's module (not some other installed copy), or the check would be void
    assert Path(out['file']).resolve() == (SRC / package).joinpath(
        *module.split('.')).with_suffix('.py').resolve()
    loaded = set(out['loaded'])
    assert not loaded & forbidden, f'{module} imports {sorted(loaded & forbidden)}'



COMMANDS_PROBE = """
import json, sys
from ladrc_tools.cli import commands
table = commands(sys.argv[1] or None)
print(json.dumps({'commands': {n: c.run.__module__ for n, c in table.items()},
                  'loaded': sorted({m.split('.')[0] for m in sys.modules})}))
"""


def _commands(only: str) -> dict:
    proc = subprocess.run([sys.executable, '-c', COMMANDS_PROBE, only], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_the_packages_above_the_tools_add_their_subcommands():
    """The ``ladrc`` command takes the subcommands of ladrc_bringup and ladrc_fleet.

    conform, calibrate and fleet, fleet-gen come from the entry-point group ladrc.commands of the
    built workspace; a subcommand of ladrc_tools imports neither package.
    """
    every = _commands('')['commands']
    assert {n: every[n] for n in ('conform', 'calibrate', 'fleet', 'fleet-gen')} == {
        'conform': 'ladrc_bringup.cli', 'calibrate': 'ladrc_bringup.cli',
        'fleet': 'ladrc_fleet.cli', 'fleet-gen': 'ladrc_fleet.cli'}
    own = _commands('report')
    assert 'fleet' not in own['commands']
    assert not {'ladrc_bringup', 'ladrc_fleet'} & set(own['loaded'])
    fleet = _commands('fleet')
    assert 'fleet' in fleet['commands'] and 'ladrc_bringup' not in fleet['loaded']
