"""The README is tested: every command of its command blocks runs and exits 0.

The commands are read from README.md's fenced blocks as a user would copy them (a ``#``
comment at the end of a line is not part of the command), run one after the other from the
repository root in one shell each, with ``out/`` pointing into this test's temporary folder
(the README's own short inputs: a 4 s scenario, the smallest job). ``make test`` is the command
that runs this test: it is the one not run here. A command that needs a system package the
machine lacks (LinuxCNC) is skipped with the set-up's line (tests/support/system.py), and
``make test`` lists it at its end. A renamed flag, a moved file or a tool that fails makes
this test fail. The conformance kit judges real-time behaviour at the product's 5 ms watchdog:
on a loaded machine (this test runs beside the others) its verdict may be a failed rule, so
here it must run to its verdict and write its report (its own tests check the verdict).

These start ROS nodes (``make demo``, ``bringup``): marker ``readme`` (scripts/run-tests runs
them beside the lock-step tests, on their own DDS domains).
"""

from __future__ import annotations

import os
from pathlib import Path
import re
import signal
import subprocess

import pytest
from system import missing

pytest.importorskip('rclpy', reason='needs the built workspace (make test)')
_BASE = int(os.environ.get('LADRC_TEST_DOMAIN_BASE', '1'))
_SPAN = int(os.environ.get('LADRC_TEST_DOMAIN_SPAN',
                           50 if 'LADRC_TEST_DOMAIN_BASE' in os.environ else 101))
os.environ['ROS_DOMAIN_ID'] = str(_BASE + (os.getpid() + 7) % _SPAN)  # as tests/ros/conftest.py

ROOT = Path(__file__).resolve().parents[1]
pytestmark = [pytest.mark.ros, pytest.mark.readme]
HANG_S = 900  # a hang, not a speed


def readme_commands() -> list[str]:
    """Return the commands of README.md's fenced blocks, in order (comments stripped)."""
    text = (ROOT / 'README.md').read_text(encoding='utf-8')
    out = []
    for block in re.findall(r'```[a-z]*\n(.*?)```', text, re.S):
        for line in block.splitlines():
            cmd = re.split(r'\s+#\s', ' ' + line.strip(), maxsplit=1)[0].strip()
            if cmd and not cmd.startswith('#'):
                out.append(cmd)
    return out


COMMANDS = readme_commands()
NOT_HERE = {'make test'}  # the command that runs this test
# real-time checks whose pass or fail is the machine's timing (tests/commissioning runs them
# with bounds from bench/stalls.py): exit 0 (passed) or 1 (a rule failed) with its report
RUN_TO_VERDICT = ('ladrc conform',)


def test_the_readme_has_commands():
    assert 'make demo' in COMMANDS and 'make test' in COMMANDS
    assert len(COMMANDS) >= 10, COMMANDS


@pytest.mark.parametrize('cmd', [c for c in COMMANDS if c not in NOT_HERE])
def test_a_readme_command_runs(cmd, tmp_path_factory):
    if 'linuxcnc' in cmd and missing('linuxcnc'):
        pytest.skip(f'could not run, needs linuxcnc: {missing("linuxcnc")}')
    out = _shared_out(tmp_path_factory)
    env = dict(os.environ)
    # every node set of these commands on this test's domain (bringup, conform, the demo draw
    # theirs at random otherwise: one of the other lane's)
    env['LADRC_DOMAIN_ID'] = os.environ['ROS_DOMAIN_ID']
    shell = cmd.replace('out/', f'{out}/')
    proc = subprocess.Popen(['bash', '-c', shell], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        text, _ = proc.communicate(timeout=HANG_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            text, _ = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            text, _ = proc.communicate()
        pytest.fail(f'{cmd!r} hung for {HANG_S} s:\n{text[-3000:]}')
    if any(v in cmd for v in RUN_TO_VERDICT):
        # a real-time check: its verdict is the driver's under this machine's load (the kit's
        # own tests pass it with their stall-measured bounds); here: it ran, judged, wrote
        assert proc.returncode in (0, 1) and 'written:' in text, \
            f'{cmd!r} exited {proc.returncode}:\n{text[-3000:]}'
        return
    assert proc.returncode == 0, f'{cmd!r} exited {proc.returncode}:\n{text[-3000:]}'


_OUT: list[Path] = []


def _shared_out(factory) -> Path:
    """One ``out/`` for the whole README (its commands read what earlier ones wrote)."""
    if not _OUT:
        _OUT.append(factory.mktemp('readme') / 'out')
        _OUT[0].mkdir()
    return _OUT[0]
