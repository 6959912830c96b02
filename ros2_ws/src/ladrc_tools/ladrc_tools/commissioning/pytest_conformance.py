"""A pytest plugin for driver authors: the conformance kit in their own CI.

In the driver's test suite (``conftest.py``)::

    pytest_plugins = ['ladrc_tools.commissioning.pytest_conformance']

and in a test::

    def test_my_driver_conforms(driver_conformance):
        result = driver_conformance('ros2 run my_axis_driver driver --ros-args -p sim:=true')
        assert result.passed, result.summary()
        assert result['watchdog_fault'].figure <= 7.0   # ms

``driver_conformance(cmd, *options, sim=False, domain_id=None, timeout_s=300)`` runs
``ladrc conform --driver-cmd CMD`` (or ``--sim``) in its own process, on an isolated DDS domain
(random 1..101 unless ``domain_id``), into a fresh folder under pytest's ``tmp_path``, and
returns the :class:`~ladrc_tools.commissioning.conformance.ConformanceResult` read back from
its ``conform.json`` (``result.output`` is the folder: report.md, bag/, driver.log).
``options`` are more ``ladrc conform`` arguments (``'--min-gap-mm', '3'``). A run that cannot
be made (bad options, a driver that exits at once) fails the test with the kit's one-line
error. The kit ends the driver it started; on a timeout this fixture interrupts the kit (which
then stops the driver) and kills it after a grace period.

Pure: no rclpy here; the kit's process does the ROS work.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import signal
import subprocess
import sys
from typing import Callable

import pytest

from .conformance import ConformanceResult

EXIT_USAGE = 2


def run_kit(output: Path, cmd: str | None = None, *options: str, sim: bool = False,
            domain_id: int | None = None, timeout_s: float = 300.0,
            drive: str | None = None) -> ConformanceResult:
    """Run ``ladrc conform`` into ``output`` (must not exist); return its result.

    One of ``cmd`` (a driver command), ``sim=True`` or ``drive`` (a drive path of the project:
    ``'cia402'``).
    """
    if sum((cmd is not None, bool(sim), bool(drive))) != 1:
        raise ValueError('give one of a driver command, sim=True or drive')
    argv = [sys.executable, '-m', 'ladrc_tools.cli', 'conform', '-o', str(output)]
    argv += (['--sim'] if sim else ['--drive', drive] if drive else ['--driver-cmd', cmd])
    if domain_id is not None:
        argv += ['--domain-id', str(int(domain_id))]
    argv += [str(o) for o in options]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env=dict(os.environ))
    try:
        stdout, stderr = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)  # the kit stops its driver and removes its output
        try:
            stdout, stderr = proc.communicate(timeout=20.0)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            stdout, stderr = proc.communicate()
        raise TimeoutError(f'ladrc conform did not finish within {timeout_s:g} s: '
                           f'{stderr.strip().splitlines()[-1:] or ""}') from None
    report = Path(output) / 'conform.json'
    if proc.returncode == EXIT_USAGE or not report.is_file():
        lines = stderr.strip().splitlines()
        raise RuntimeError(lines[-1] if lines else f'ladrc conform exited with '
                           f'{proc.returncode} and wrote no result')
    result = ConformanceResult.from_dict(json.loads(report.read_text(encoding='utf-8')))
    result.extra['output'] = str(output)
    result.extra['stdout'] = stdout
    return result


@pytest.fixture()
def driver_conformance(tmp_path: Path) -> Callable[..., ConformanceResult]:
    """Return a function that runs the conformance kit on a driver command (see the module)."""
    runs = [0]

    def run(cmd: str | None = None, *options: str, sim: bool = False,
            domain_id: int | None = None, timeout_s: float = 300.0,
            drive: str | None = None) -> ConformanceResult:
        runs[0] += 1
        out = tmp_path / f'conform-{runs[0]}'
        try:
            result = run_kit(out, cmd, *options, sim=sim, domain_id=domain_id,
                             timeout_s=timeout_s, drive=drive)
        except (RuntimeError, TimeoutError) as exc:
            pytest.fail(f'driver conformance could not run: {exc}', pytrace=False)
        result.output = out  # type: ignore[attr-defined]
        return result

    return run
