"""Live in lock step equals headless: same scenario and seed, every message bit for bit.

The sim node and the follow node run as real processes over DDS in lock step (the sim publishes
step k and steps the plant only when the command answering k has arrived; the controller ticks
on the sim's clock), with the recorder; ``ladrc simulate`` runs the same scenario headless and
writes the same bag layout. Every field of every message of the contract topics must be equal,
except those listed in ``WALL_TIME``. Nothing here depends on how the processes get scheduled:
a loaded machine makes the run slower, never different.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import signal
import subprocess
import time

from bagdiff import diff_bags
from ladrc_bags import open_bag
import pytest

pytest.importorskip('rclpy')
from ladrc_sim.node.drive_bridge import WIND_DOWN_TICKS  # noqa: E402 (after the skip)

ROOT = Path(__file__).resolve().parents[2]
BIN = ROOT / 'ros2_ws' / 'install' / 'ladrc_bringup' / 'lib' / 'ladrc_bringup'
TOOLS = ROOT / 'ros2_ws' / 'install' / 'ladrc_tools' / 'lib' / 'ladrc_tools'
pytestmark = pytest.mark.ros

TOPICS = ['axis/capacitive_height', 'axis/feedback', 'axis/velocity_command', 'follow/status',
          'sim/truth', 'follow/events']
# Fields that measure wall time (the tick's period, its compute time, the late-tick flag), the
# bag's own receive time, and the commander's session (drawn at random when the follow node
# starts: docs/interfaces.md, "One commander"). Everything else, stamps and input ages
# included, is the sim's time in lock step and equal.
WALL_TIME = {'period_us', 'compute_us', 'overrun', 'timestamp_ns', 'session'}
# No lock-step run may hang: it is slower on a loaded machine, never different, so this is a
# bound on a hang, not on speed.
HANG_S = 900


def run(cmd: list[str], **kw) -> subprocess.CompletedProcess:
    """Run a command in its own process group; end the group by its PID if it hangs."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True, env=dict(os.environ), **kw)
    try:
        out, _ = proc.communicate(timeout=HANG_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        raise AssertionError(f'{cmd[0]} hung for {HANG_S} s:\n{out[-3000:]}') from None
    return subprocess.CompletedProcess(cmd, proc.returncode, out, '')


def lockstep_run(scenario: str, bag: Path, logs: Path, what: str = '--scenario',
                 extra: tuple[str, ...] = ()) -> dict:
    """``bringup --lockstep`` (sim, follow node, recorder as processes) into ``bag``.

    ``what``: ``--job`` plays ``scenario`` as a cutting job; ``extra``: more bringup
    arguments. Return bringup's last line.
    """
    res = run([str(BIN / 'bringup'), what, scenario, '--lockstep', '--unpaced',
               '--bag', str(bag), '--logs', str(logs),
               '--domain-id', os.environ['ROS_DOMAIN_ID'], *extra])
    logs_text = '\n'.join(f'--- {p.name}\n{p.read_text(errors="replace")[-2000:]}'
                          for p in sorted(logs.glob('*.log')))
    assert res.returncode == 0, res.stdout[-2000:] + logs_text
    codes = {'ladrc_follow': 0, 'ladrc_sim': 0, 'ladrc_recorder': 0}
    if '--separate-cnc' in extra:
        codes['ladrc_cnc'] = 0
    last = json.loads(res.stdout.strip().splitlines()[-1])
    assert last['exit_codes'] == codes, logs_text
    # a run that ended normally did not end in FAULT (unless its scenario or job declares it)
    assert last['ok'] and last['run']['final_state'] in ('IDLE', 'FAULT'), last
    summary = json.loads((bag / 'recording.json').read_text())
    assert summary['messages_lost'] == 0 and summary['messages_dropped'] == 0, summary
    return last


def assert_equal_bags(headless: Path, live: Path, n: int, wind_down: bool = False) -> None:
    """Every field of every message of ``TOPICS`` equal but ``WALL_TIME``; ``n`` ticks.

    ``wind_down``: the live run of a scenario ends with the sim's wind-down (the controller
    stopped, then WIND_DOWN_TICKS more steps): the live bag has those steps and the
    stop_follow event more; the headless run's messages are compared with the live run's first.
    """
    with open_bag(headless) as b:
        headless_counts = {t: b.count(t) for t in TOPICS}
    limit = {t: headless_counts[t] for t in TOPICS}
    limit['axis/velocity_command'] = n
    diffs = diff_bags(headless, live, TOPICS, WALL_TIME, limit=limit)
    for d in diffs:
        assert not d.missing and not d.differing, (d.topic, d.missing, d.differing)
        if d.topic == 'axis/velocity_command':
            assert d.count_a == n and d.count_b >= n, (d.count_a, d.count_b)
            continue
        extra = 0
        if wind_down:
            extra = 1 if d.topic == 'follow/events' else WIND_DOWN_TICKS
        assert d.count_b == d.count_a + extra, (d.topic, d.count_a, d.count_b)
    status = next(d for d in diffs if d.topic == 'follow/status')
    assert status.compared == n  # every tick of the run


@pytest.mark.parametrize('scenario', ['showcase', 'faults', 'thin_sheet'])
def test_live_lockstep_equals_headless(tmp_path, scenario):
    live, headless = tmp_path / 'live', tmp_path / 'headless'
    live_run = lockstep_run(scenario, live, tmp_path / 'logs')
    res = run([str(TOOLS / 'ladrc'), 'simulate', scenario, '-o', str(headless)])
    assert res.returncode == 0, res.stdout[-2000:]

    # the headless run has one command per tick; the live controller adds its zero commands
    # with enable off on the way down (SIGINT), after the last tick
    with_ticks = json.loads(res.stdout.strip().splitlines()[-1])
    n = int(round(with_ticks['duration_s'] / 0.0005))
    assert_equal_bags(headless, live, n, wind_down=True)
    final = 'FAULT' if scenario == 'faults' else 'IDLE'  # faults declares its FAULT
    assert live_run['run']['final_state'] == final, live_run['run']

    if scenario == 'showcase':
        # a live bag replays through the core bit for bit (ladrc replay), its wind-down too
        rep = run([str(TOOLS / 'ladrc'), 'replay', str(live)])
        line = json.loads(rep.stdout.strip().splitlines()[-1])
        assert rep.returncode == 0 and line['mismatches'] == 0, rep.stdout[-2000:]
        assert line['missing_ticks'] == 0 and line['ticks'] == n + WIND_DOWN_TICKS, line


JOB_FIGURES = ('job_time_s', 'contacts', 'faults', 'pierces', 'holds', 'feed_hold_s',
               'min_gap_over_target_cutting', 'min_true_gap_per_contour_mm', 'finished',
               'aborted')


SMALL_JOB = """name: lockstep_small
description: A 60 x 40 mm part with a round and a square hole on a wavy 100 x 70 mm sheet.
dxf: small.dxf
sheet:
  width_mm: 100
  height_mm: 70
  surface: {tilt_x: 0.0005, wave_amp_mm: 0.2, wave_length_mm: 60}
cut: {kerf_mm: 0.2, lead_in_mm: 2.0}
cnc: {feed_mm_s: 120, rapid_mm_s: 500, accel_mm_s2: 2000, cut_gap_mm: 1.0,
      pierce_heights_mm: [3.0, 2.0], pierce_dwell_s: [0.05, 0.05], thc_delay_s: 0.05,
      lift_mm: 6.0, leapfrog: true}
controller: {cnc.feed_override_min: 0.5}
sensor: {noise_std_mm: 0.003, quant_mm: 0.001}
start_xy: [5.0, 5.0]
seed: 7
"""


def small_job(folder: Path) -> str:
    """Write a 6 s job (three contours, two leapfrogs, its own controller parameters)."""
    import ezdxf

    doc = ezdxf.new('R2010')
    doc.header['$INSUNITS'] = 4  # mm
    msp = doc.modelspace()
    msp.add_lwpolyline([(20, 15), (80, 15), (80, 55), (20, 55)], close=True)
    msp.add_circle((35, 35), 6)
    msp.add_lwpolyline([(55, 28), (67, 28), (67, 42), (55, 42)], close=True)
    doc.saveas(str(folder / 'small.dxf'))
    (folder / 'small.yaml').write_text(SMALL_JOB)
    return str(folder / 'small.yaml')


@pytest.mark.parametrize('job,separate', [('tipping_pair', False), ('small', False),
                                          ('small', True)])
def test_live_lockstep_job_equals_headless(tmp_path, job, separate):
    """A cutting job live in lock step equals ``ladrc job``: its figures and its bag.

    The sim node plays the simulated CNC (cnc/motion out, the follow services called, the
    controller's answers read from follow/status); the controller's tick waits for the CNC's
    sample the step names, the CNC for the status answering the step. tipping_pair (shipped):
    a pierce, a part tipping up, the collision retract, the FAULT and its feed hold; small:
    three contours with pierce stages and leapfrogs, parts dropping out, corner and edge-ahead
    holds, the job's own controller parameters over the shipped set. ``separate``: the CNC
    node plays the CNC (three processes in lock step: the CNC's step k, then the sim's, then
    the controller's tick), equal to ``ladrc job --separate-cnc``.
    """
    name = small_job(tmp_path) if job == 'small' else job
    live, headless = tmp_path / 'live', tmp_path / 'headless'
    flag = ('--separate-cnc',) if separate else ()
    figures = lockstep_run(name, live, tmp_path / 'logs', '--job', flag)
    res = run([str(TOOLS / 'ladrc'), 'job', name, '-o', str(headless), *flag])
    assert res.returncode == 0, res.stdout[-2000:]
    head = json.loads(res.stdout.strip().splitlines()[-1])
    for key in JOB_FIGURES:  # (JSON: the contours' keys are text in both)
        assert figures[key] == head[key], (key, figures[key], head[key])
    assert_equal_bags(headless / 'bag', live, int(round(head['job_time_s'] / 0.0005)))
    if job == 'tipping_pair':
        assert figures['contacts'] >= 1 and figures['faults'] == 1
    else:
        assert figures['finished'] and figures['contacts'] == 0 and figures['pierces'] == 3
        assert figures['holds']['corner_lock']['count'] > 0


SHORT = """name: lockstep_end
description: 3 s, an approach from 3 mm to a 1 mm follow (tests/ros/test_lockstep.py).
duration_s: 3.0
seed: 5
initial_gap_mm: 3.0
sensor: {noise_std_mm: 0.003, quant_mm: 0.001}
timeline:
  - {t_s: 0.2, do: start_follow, target_gap_mm: 1.0}
"""


def _wait_for_line(path: Path, text: str, proc: subprocess.Popen) -> None:
    """Wait (at most HANG_S) for ``text`` in the log ``path``; fail if ``proc`` ended first."""
    end = time.monotonic() + HANG_S
    while text not in (path.read_text(errors='replace') if path.exists() else ''):
        assert proc.poll() is None, f'{path.name} ended before {text!r}:\n{path.read_text()}'
        assert time.monotonic() < end, f'no {text!r} in {path.name} within {HANG_S} s'
        time.sleep(0.05)


def test_a_recorder_behind_at_the_end_of_a_run_loses_nothing(tmp_path):
    """The sim does not go down before every reader has its messages (qos.wait_acknowledged).

    The recorder is stopped (SIGSTOP) for the whole run and continued only after the sim has
    played its scenario: a reliable writer repairs only while it exists, so without the wait
    the bag would lose the run's last samples.
    """
    from ladrc_bags import open_bag
    from ladrc_bringup.bringup import Bringup, isolated_env, node_specs

    scenario = tmp_path / 'lockstep_end.yaml'
    scenario.write_text(SHORT)
    bag, logs = tmp_path / 'bag', tmp_path / 'logs'
    specs = node_specs(str(scenario), bag=str(bag), lockstep=True, paced=False)
    # The repair of 3 s of five 2 kHz topics to the continued recorder can take more than the
    # sim's default 10 s end wait on a loaded machine: the wait, not its length, is the subject.
    next(s for s in specs if s.name == 'ladrc_sim').parameters['lockstep_timeout_s'] = 120.0
    up = Bringup(specs, isolated_env(int(os.environ['ROS_DOMAIN_ID'])), logs)
    try:
        up.start()
        sim, rec = up.procs['ladrc_sim'], up.procs['ladrc_recorder']
        _wait_for_line(logs / 'ladrc_sim.log', 'scenario lockstep_end:', sim)  # recorder seen
        os.kill(rec.pid, signal.SIGSTOP)
        _wait_for_line(logs / 'ladrc_sim.log', 'scenario done', sim)
        time.sleep(1.0)
        # the sim waits for the stopped recorder's acknowledgements (up to lockstep_timeout_s)
        assert sim.poll() is None, (logs / 'ladrc_sim.log').read_text()
        os.kill(rec.pid, signal.SIGCONT)
        assert up.wait('ladrc_sim', HANG_S) == 0, (logs / 'ladrc_sim.log').read_text()
    finally:
        os.kill(up.procs['ladrc_recorder'].pid, signal.SIGCONT)
        codes = up.stop()
    assert codes['ladrc_recorder'] == 0, codes
    steps = 6000 + WIND_DOWN_TICKS  # 3 s at 2 kHz, every sample fresh, and the wind-down
    with open_bag(bag) as b:
        for topic, seq in (('axis/capacitive_height', 'seq'), ('axis/feedback', 'seq'),
                           ('sim/truth', 'seq'), ('follow/status', 'tick')):
            got = b.columns(topic, [seq])[seq]
            assert len(got) == steps and got[-1] == steps - 1, (topic, len(got), got[-1:])
    assert 'not acknowledged' not in (logs / 'ladrc_sim.log').read_text()
