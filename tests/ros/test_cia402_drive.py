"""The CiA 402 drive path end to end: the follow node, the driver node, the emulated drive.

``bringup --drive cia402`` starts the test bus (python-can-remote on 127.0.0.1, ended by PID),
the sim node with its drive on the bus (``drive:=cia402``: the emulated CiA 402 drive over the
scenario's world), the CiA 402 driver node (``ladrc_cia402 driver_node``: SDO configuration,
RPDO + SYNC + TPDOs per period, the power state machine) and the unchanged follow node and
recorder. In lock step the drive advances one period per SYNC and the driver sends the next SYNC
when the controller has answered, so the verdict does not depend on load.

Checked: every process exits cleanly; nothing is lost; the samples came over the bus (positions
in whole encoder increments, the gap in whole analog counts); no contact; the bag replays bit
for bit; the error RMS equals the headless loop behind the bus's integer units and the drive's
power-up (bench/cia402_units.py) and is within 10 % of the simulator's own drive (headless,
equal to the sim node in lock step bit for bit: tests/ros/test_lockstep.py; docs/cia402.md).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import signal
import subprocess

import numpy as np
import pytest

pytest.importorskip('rclpy')

ROOT = Path(__file__).resolve().parents[2]
BIN = ROOT / 'ros2_ws' / 'install' / 'ladrc_bringup' / 'lib' / 'ladrc_bringup'
TOOLS = ROOT / 'ros2_ws' / 'install' / 'ladrc_tools' / 'lib' / 'ladrc_tools'
pytestmark = pytest.mark.ros
HANG_S = 900  # a hang, not a speed: lock step is slower on a loaded machine, never different


def run(cmd: list[str]) -> subprocess.CompletedProcess:
    """Run a command in its own process group; end the group by its PID if it hangs."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True, env=dict(os.environ))
    try:
        out, _ = proc.communicate(timeout=HANG_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        raise AssertionError(f'{cmd[0]} hung for {HANG_S} s:\n{out[-3000:]}') from None
    return subprocess.CompletedProcess(cmd, proc.returncode, out, '')


def last_json(text: str) -> dict:
    return json.loads(text.strip().splitlines()[-1])


def test_the_step_scenario_through_the_cia402_drive_in_lock_step(tmp_path):
    from ladrc_bags import open_bag

    bag, logs = tmp_path / 'bag', tmp_path / 'logs'
    res = run([str(BIN / 'bringup'), '--drive', 'cia402', '--scenario', 'step', '--lockstep',
               '--unpaced', '--bag', str(bag), '--logs', str(logs),
               '--domain-id', os.environ['ROS_DOMAIN_ID']])
    logs_text = '\n'.join(f'--- {p.name}\n{p.read_text(errors="replace")[-1500:]}'
                          for p in sorted(logs.glob('*.log')))
    assert res.returncode == 0, res.stdout[-2000:] + logs_text
    assert last_json(res.stdout)['exit_codes'] == {
        'ladrc_follow': 0, 'ladrc_driver': 0, 'ladrc_sim': 0, 'ladrc_recorder': 0}, logs_text
    driver_log = (logs / 'ladrc_driver.log').read_text()
    assert 'CSV, SYNC 500 us, RPDO deadline 10 ms, operational' in driver_log
    summary = json.loads((bag / 'recording.json').read_text())
    assert summary['messages_lost'] == 0 and summary['messages_dropped'] == 0, summary
    n = summary['messages']['/axis/feedback']  # one sample pair per SYNC
    assert n >= 8000, summary  # 4 s at 2 kHz, then the sim's wind-down

    b = open_bag(bag)
    fb = b.columns('axis/feedback', ['position_mm', 'drive_enabled', 'seq'])
    gap = b.columns('axis/capacitive_height', ['gap_mm', 'valid'])
    assert np.array_equal(fb['seq'], np.arange(n))
    # through the bus: whole increments (1000/mm) and whole analog counts (1000/mm)
    assert np.allclose(fb['position_mm'] * 1000, np.round(fb['position_mm'] * 1000), atol=1e-6)
    ok = gap['valid'].astype(bool)
    assert ok.mean() > 0.99
    assert np.allclose(gap['gap_mm'][ok] * 1000, np.round(gap['gap_mm'][ok] * 1000), atol=1e-6)
    # the drive powers up in its first SYNCs (one transition per period), then stays enabled
    en = fb['drive_enabled'].astype(bool)
    assert not en[0] and en[10:].all()

    rep = run([str(TOOLS / 'ladrc'), 'report', str(bag), '-q'])
    assert rep.returncode == 0, rep.stdout[-2000:]
    live = last_json(rep.stdout)
    assert live['collisions'] == 0 and live['messages_lost'] == 0

    replay = run([str(TOOLS / 'ladrc'), 'replay', str(bag)])
    line = last_json(replay.stdout)
    assert replay.returncode == 0 and line['mismatches'] == 0 and line['ticks'] == n, \
        replay.stdout[-2000:]

    # the same loop headless: the simulator's own drive, and behind the bus's integer units
    # and the drive's power-up (bench/cia402_units.py): the live run equals the latter to the
    # last bit, and differs from the former by what those cost (the power-up, here 3 %)
    from cia402_units import BusUnits
    from ladrc_sim.headless.runner import run as run_headless

    own = run_headless('step', BusUnits('baseline')).metrics.error_rms_mm
    bus = run_headless('step', BusUnits('all')).metrics.error_rms_mm
    assert live['error_rms_mm'] == pytest.approx(bus, rel=1e-12, abs=0.0), (live, bus)
    assert abs(live['error_rms_mm'] / own - 1) <= 0.10, (live, own)


def test_a_drive_that_is_not_ours_from_its_device_file_in_lock_step(tmp_path):
    """Drive C: heartbeat watchdog, arrays per motor, the gap on a CiA 401 node (same SYNC)."""
    from ladrc_bags import open_bag
    from ladrc_cia402.device_file import load_device, make_plan

    device = ROOT / 'ros2_ws' / 'src' / 'ladrc_cia402' / 'examples' / 'hub_c_io401.yaml'
    bag, logs = tmp_path / 'bag', tmp_path / 'logs'
    res = run([str(BIN / 'bringup'), '--drive', 'cia402', '--device', str(device),
               '--scenario', 'step', '--lockstep', '--unpaced', '--bag', str(bag), '--logs',
               str(logs), '--domain-id', os.environ['ROS_DOMAIN_ID']])
    logs_text = '\n'.join(f'--- {p.name}\n{p.read_text(errors="replace")[-1500:]}'
                          for p in sorted(logs.glob('*.log')))
    assert res.returncode == 0, res.stdout[-2000:] + logs_text
    assert last_json(res.stdout)['exit_codes'] == {
        'ladrc_follow': 0, 'ladrc_driver': 0, 'ladrc_sim': 0, 'ladrc_recorder': 0}, logs_text
    driver_log = (logs / 'ladrc_driver.log').read_text()
    assert 'gap node, CSV, SYNC 500 us, heartbeat consumer 100 ms, operational' in driver_log
    summary = json.loads((bag / 'recording.json').read_text())
    n = summary['messages']['/axis/feedback']  # 4 s at 2 kHz and the sim's wind-down
    assert summary['messages_lost'] == 0 and n >= 8000, summary
    gap = open_bag(bag).columns('axis/capacitive_height', ['valid'])
    assert gap['valid'].astype(bool).mean() > 0.99  # the I/O node's TPDO of every SYNC

    rep = run([str(TOOLS / 'ladrc'), 'report', str(bag), '-q'])
    live = last_json(rep.stdout)
    assert rep.returncode == 0 and live['collisions'] == 0
    replay = run([str(TOOLS / 'ladrc'), 'replay', str(bag)])
    line = last_json(replay.stdout)
    assert replay.returncode == 0 and line['mismatches'] == 0 and line['ticks'] == n

    # the headless loop behind this drive's own units equals the live run to the last bit
    from cia402_units import BusUnits
    from ladrc_sim.headless.runner import run as run_headless

    plan = make_plan(load_device(device))
    ctrl = BusUnits('all')
    ctrl.units, ctrl.analog = plan.units, plan.analog
    assert live['error_rms_mm'] == pytest.approx(
        run_headless('step', ctrl).metrics.error_rms_mm, rel=1e-12, abs=0.0)
