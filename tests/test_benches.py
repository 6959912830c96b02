"""Smoke tests of the benches (issue "benches cannot break silently").

Each ``bench/*.py`` runs once, at a tiny size, as a process of its own
(``sys.executable bench/NAME.py ARGS``, the repository root as its working directory, the
test's environment): it must exit 0, its last stdout line must be a JSON object, and that
object must hold the keys its docstring documents, each with a value of the right kind.
Nothing here looks at a figure's size: the benches measure time, the tests only that they run
(a loaded machine makes them slower, never failed); the timeouts are bounds on a hang.

The benches that start ROS nodes (``stalls``, ``loop_timing``, ``live_jobs``, ``view_load``,
``linuxcnc_jobs``, ``cia402_timing``) carry the ``ros`` marker and run in the isolation of the
ROS tests: the
ROS_DOMAIN_ID and localhost discovery of tests/ros/conftest.py (loaded from there, as
tests/commissioning/test_calibration_live.py does), passed to the bench's own ``--domain-id``
where it has one. Not run here: the live part of ``bag_scale`` (``--part live``) and the live
rows of ``fault_matrix``, which pick their own domains at random (1..101, the tests' range)
and are too long for a smoke test.

A bench is ended by its process group's id if it outlives its timeout (SIGINT first: a bench
stops the nodes it started; SIGKILL if it hangs).

The benches run in the project's built environment (``scripts/in-env python bench/...``, their
docstrings): without it (no rclpy: the Ubuntu 24.04 library check, scripts/noble-test, which
tests the packages on noble's libraries) this module skips, rather than spend its ~45 s again
on the tail of `make test`'s second lane.
"""

from __future__ import annotations

import importlib.util
import json
import os
from pathlib import Path
import signal
import subprocess
import sys

from ladrc_bringup.bringup import interrupt_process
import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / 'bench'
pytestmark = pytest.mark.skipif(importlib.util.find_spec('rclpy') is None,
                                reason='the benches run in the built environment (make test)')

# kinds of JSON values (a bool is not a number here)
NUM = (int, float)
INT = int
BOOL = bool
STR = str
DICT = dict
LIST = list
NULL = type(None)
OPT_NUM = (int, float, type(None))
OPT_DICT = (dict, type(None))


_LOG = {'stderr': ''}  # the tail of the last bench's stderr, for the messages of check()


def run_bench(name: str, *args: str, timeout_s: float, env: dict | None = None) -> dict:
    """Run ``bench/NAME.py ARGS``; return its last stdout line, a JSON object."""
    cmd = [sys.executable, str(BENCH / f'{name}.py'), *args]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=dict(os.environ) if env is None else env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        interrupt_process(proc, 30.0)  # its group: SIGINT, SIGKILL if it hangs
        out, err = proc.communicate()
        pytest.fail(f'{name} hung for {timeout_s} s: {" ".join(args)}\n{out[-2000:]}\n'
                    f'{err[-3000:]}')
    finally:
        if proc.poll() is None:  # interrupted (Ctrl-C): the whole group goes
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 0, f'{name} exit {proc.returncode}\n{out[-2000:]}\n{err[-3000:]}'
    lines = out.strip().splitlines()
    assert lines, f'{name} printed nothing on stdout\n{err[-3000:]}'
    try:
        result = json.loads(lines[-1])
    except json.JSONDecodeError as exc:
        raise AssertionError(f'{name}: last line is not JSON ({exc}): {lines[-1][:500]}') from None
    assert isinstance(result, dict), f'{name}: last line is not a JSON object: {lines[-1][:500]}'
    _LOG['stderr'] = f'--- {name} stderr (tail):\n{err[-3000:]}'
    return result


def _is(value, kind) -> bool:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if isinstance(value, bool):
        return bool in kinds
    return isinstance(value, kinds)


def check(result: dict, spec: dict, where: str = '') -> None:
    """Every key of ``spec`` in ``result``, its value of the kind ``spec`` gives."""
    log = _LOG['stderr']
    missing = [k for k in spec if k not in result]
    assert not missing, f'{where}missing keys {missing}; the JSON has {sorted(result)}\n{log}'
    wrong = {k: result[k] for k, kind in spec.items() if not _is(result[k], kind)}
    assert not wrong, f'{where}values of the wrong kind: {wrong}\n{log}'


@pytest.fixture(scope='module')
def ros_env() -> dict[str, str]:
    """Return the environment of the ROS tests (own ROS_DOMAIN_ID, localhost discovery)."""
    spec = importlib.util.spec_from_file_location(
        'ros_conftest_for_benches', ROOT / 'tests' / 'ros' / 'conftest.py')
    ros = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ros)  # sets ROS_DOMAIN_ID / localhost discovery (or skips)
    return dict(os.environ)


# ------------------------------------------------------------------------- non-ROS benches

def test_bag_read() -> None:
    r = run_bench('bag_read', '--seconds', '2', timeout_s=300)
    check(r, {'messages': INT, 'indexed': BOOL, 'indexed_s': NUM, 'unindexed_s': NUM,
              'per_message_s': NUM, 'indexed_msgs_per_s': NUM, 'per_message_msgs_per_s': NUM,
              'speedup': NUM, 'same_columns': BOOL, 'command_with_string_s': NUM,
              'command_fixed_s': NUM, 'command_messages': INT})


BAG_SCALE_TOP = ('segment_close_ratio', 'messages_lost', 'recorder_peak_rss_mib',
                 'bytes_per_hour', 'replay_realtime_x', 'report_realtime_x',
                 'tools_peak_rss_mib')


def test_bag_scale_writer() -> None:
    r = run_bench('bag_scale', '--part', 'writer', '--hours', '0.001', timeout_s=300)
    check(r, {k: OPT_NUM for k in BAG_SCALE_TOP} | {'writer': DICT})
    check(r, {'segment_close_ratio': NUM, 'messages_lost': INT, 'recorder_peak_rss_mib': NUM,
              'bytes_per_hour': NUM, 'replay_realtime_x': NULL, 'tools_peak_rss_mib': NULL})
    check(r['writer'], {'hours_simulated': NUM, 'messages_fed': INT, 'messages_written': INT,
                        'messages_lost': INT, 'wall_s': NUM, 'realtime_x': NUM,
                        'periodic_ms_start': NUM, 'periodic_ms_end': NUM,
                        'periodic_end_over_start': NUM, 'periodic_ms_max': NUM, 'bytes': INT,
                        'bytes_per_hour': NUM, 'peak_rss_mib': NUM}, 'writer: ')


def test_bag_scale_tools() -> None:
    r = run_bench('bag_scale', '--part', 'tools', '--tool-hours', '0.005', timeout_s=600)
    check(r, {k: OPT_NUM for k in BAG_SCALE_TOP} | {'tools': DICT})
    check(r, {'replay_realtime_x': NUM, 'report_realtime_x': NUM, 'tools_peak_rss_mib': NUM,
              'segment_close_ratio': NULL})
    tools = r['tools']
    check(tools, {'hours': NUM, 'bag_bytes': INT, 'replay': DICT, 'report': DICT,
                  'export': DICT, 'whatif': DICT}, 'tools: ')
    for name in ('replay', 'report', 'export', 'whatif'):
        check(tools[name], {'wall_s': NUM, 'rc': INT, 'peak_rss_mib': NUM,
                            'realtime_x': OPT_NUM}, f'tools/{name}: ')
        # the CLI tool itself ran (the bench reports a failed child, it does not fail)
        assert tools[name]['rc'] == 0, (name, tools[name])
    check(tools['replay'], {'mismatches': INT}, 'tools/replay: ')
    check(tools['export'], {'csv_bytes': INT}, 'tools/export: ')


def test_cia402_units() -> None:
    r = run_bench('cia402_units', '--scenarios', 'step', timeout_s=300)
    check(r, {'scenarios': DICT, 'max_relative_all': NUM})
    for variant in ('baseline', 'gap_counts', 'position_increments', 'velocity_units',
                    'power_up', 'all'):
        check(r['scenarios']['step'][variant], {'error_rms_mm': NUM, 'relative': NUM},
              f'step/{variant}: ')


def test_figures(tmp_path: Path) -> None:
    """One quick figure into a scratch folder (the docs and the README stay as they are)."""
    r = run_bench('figures', '--only', 'paper-eso-frequency', '--out', str(tmp_path),
                  timeout_s=300)
    check(r, {'figures': LIST, 'failed': LIST, 'wall_s': NUM, 'written': LIST})
    assert r['figures'] == ['paper-eso-frequency'] and not r['failed']
    table = (tmp_path / 'figures.md').read_text()
    assert '<a id="paper-eso-frequency"></a>' in table and 'not measured yet' in table


def test_core_step() -> None:
    r = run_bench('core_step', '--quick', timeout_s=300)
    check(r, {'scalar_step_us': NUM, 'batch_realtime_x': DICT, 'load_1min': NUM})
    check(r['batch_realtime_x'], {'1': NUM, '100': NUM, '1000': NUM}, 'batch_realtime_x: ')


def test_edge_fit_timing() -> None:
    r = run_bench('edge_fit_timing', '--fits', '5', timeout_s=300)
    check(r, {'fits': INT, 'median_ms': NUM, 'p99_ms': NUM, 'max_ms': NUM, 'warm_up_ms': NUM,
              'settings': LIST, 'target_max_ms': NUM})
    assert r['fits'] == 5


def test_fault_matrix_cnc_fuzz() -> None:
    """The cheapest part of the matrix: the CNC interface fuzz (headless)."""
    r = run_bench('fault_matrix', '--only', 'cnc-fuzz', timeout_s=300)
    check(r, {'contacts': INT, 'node_crashes': INT, 'probe_crashes': (INT, NULL),
              'nonfinite_commands': INT, 'invalid_params_accepted': INT,
              'invalid_params_tried': INT, 'spurious_faults_under_load': (INT, NULL),
              'kill_stop_ms': OPT_NUM, 'recorder_kill_loss_s': OPT_NUM,
              'param_clients': OPT_DICT, 'live_error': STR, 'rows': LIST})
    assert [row['row'] for row in r['rows']] == ['CNC interface fuzz (headless)'], r['rows']


def test_fleet_scaling() -> None:
    r = run_bench('fleet_scaling', '--machines', '3', '--days', '1', '--bags-per-day', '1',
                  '--bag-s', '4', '--report-bags', '1', timeout_s=600)
    check(r, {'bags': INT, 'wall_s_1_worker': NUM, 'wall_s_2_workers': NUM, 'speedup': NUM,
              'per_bag_s': NUM, 'report_per_bag_s': NUM, 'worker_peak_rss_mb': NUM,
              'degraded_flagged': DICT, 'healthy_flagged': DICT, 'all_degraded_flagged': BOOL})


def test_headless_speed() -> None:
    r = run_bench('headless_speed', '--scenario', 'sine_5hz', '--repeat', '1', timeout_s=300)
    check(r, {'realtime_x': NUM, 'realtime_x_median': NUM, 'controller': STR, 'scenario': STR,
              'sim_s': NUM, 'us_per_tick': NUM, 'sim_only_realtime_x': NUM,
              'sim_only_us_per_tick': NUM, 'target_realtime_x': NUM, 'collisions': INT,
              'error_rms_mm': NUM})


def test_html_report() -> None:
    """The zoomable report of a 2 s bag; the browser figures are null without Chromium."""
    r = run_bench('html_report', '--seconds', '2', timeout_s=600)
    check(r, {'seconds': NUM, 'ticks': INT, 'bag_bytes': INT, 'html_bytes': INT, 'write_s': NUM,
              'write_cpu_s': NUM, 'write_peak_rss_mib': OPT_NUM, 'report_no_html_s': NUM,
              'report_no_html_cpu_s': NUM, 'report_no_html_peak_rss_mib': OPT_NUM,
              'rounds': LIST, 'html_parts': DICT,
              'chromium_render_s': OPT_NUM, 'chromium_wall_s': OPT_NUM,
              'page_timing': OPT_DICT, 'console_errors': (LIST, NULL),
              'full_view_level': (INT, NULL), 'level_50ms': (INT, NULL),
              'points_in_50ms_window': (INT, NULL), 'samples_in_window': (INT, NULL),
              'command_points_in_50ms_window': (INT, NULL), 'zoom_s': OPT_NUM})
    if r['chromium_render_s'] is not None:  # the 50 ms window: every sample drawn
        assert r['points_in_50ms_window'] == r['samples_in_window'] > 0, r
        assert r['console_errors'] == [], r['console_errors']


def test_identified_plant() -> None:
    r = run_bench('identified_plant', '--quick', timeout_s=300)
    check(r, {'ladrc_pm_deg_gain_b0_1': NUM, 'ladrc_pm_deg_gain_1': NUM,
              'ladrc_dm_ms_gain_1': NUM, 'ladrc_fc_hz_gain_1': NUM,
              'ladrc_fc_hz_gain_0_01': NUM, 'slow_pole_rad_s': NUM, 'plant_zero_rad_s': NUM,
              'plant_rms_mm_ladrc': NUM, 'plant_rms_mm_pid': NUM,
              'plant_rms_mm_ladrc_gain_1': NUM, 'pid_gain_1_collisions': INT,
              'pid_gain_1_fault': STR, 'ladrc_gain_1_dead_2_fault': STR,
              'identified_plant_ladrc_rms_range_mm': LIST,
              'identified_plant_pid_rms_range_mm': LIST,
              'identified_step_ladrc_rms_range_mm': LIST,
              'identified_step_pid_rms_range_mm': LIST, 'runtime_s': NUM})


def test_job_speed() -> None:
    r = run_bench('job_speed', '--jobs', 'tipping_pair', '--repeat', '1', timeout_s=300)
    check(r, {'jobs': DICT, 'realtime_x_min': NUM, 'target_x': NUM, 'met': BOOL})
    check(r['jobs'], {'tipping_pair': DICT}, 'jobs: ')
    check(r['jobs']['tipping_pair'], {'job_time_s': NUM, 'wall_s': NUM, 'realtime_x': NUM,
                                      'controller_share': NUM}, 'jobs/tipping_pair: ')


def test_loop_vs_sim() -> None:
    r = run_bench('loop_vs_sim', '--quick', timeout_s=300)
    loops = ('LADRC shipped (order 1, Euler)', 'LADRC order 2, ZOH, Kalman', 'PID shipped')
    check(r, {'frequencies_hz': LIST} | {name: DICT for name in loops})
    for name in loops:
        check(r[name], {'max_db': NUM, 'max_deg': NUM}, f'{name}: ')


def test_paper_eso_compensator() -> None:
    # the step case's window starts at 5 s: the shortest run past it, at a 1 ms step
    r = run_bench('paper_eso_compensator', '--h', '1e-3', '--t-end', '5.5', timeout_s=300)
    errors = ('leso_x2_err', 'leso_d_x2_err', 'neso_x2_err', 'neso_d_x2_err')
    spec = {k: NUM for k in errors}
    spec |= {f'{k}_{case}': NUM for k in errors for case in ('away', 'step', 'noise')}
    spec |= {f'{o}_ratio_{case}': NUM for o in ('leso', 'neso')
             for case in ('zero', 'step', 'noise', 'away')}
    spec |= {f'paper_{k}': NUM for k in errors}
    spec |= {'h_s': NUM, 't_end_s': NUM, 'runtime_s': NUM}
    check(r, spec)


def test_paper_eso_frequency() -> None:
    r = run_bench('paper_eso_frequency', '--plot', '', timeout_s=300)  # '': no PNG in docs/
    check(r, {k: NUM for k in (
        'omega_lost_paper', 'omega_0p1db_i2', 'omega_0p1db_i3', 'omega_0p1db_i4',
        'phi_lost_paper_deg', 'phi_at_13_3_i3_deg', 'phi_at_13_3_i4_deg', 'omega_weak_paper',
        'omega_weak_phase_i4', 'omega_weak_is_10_pow_0_71', 'phi_weak_paper_deg',
        'phi_at_5_1286_i4_deg', 'a_weak_paper', 'a_db_spread_at_5_1286', 'max_rel_deviation',
        'true_peak_db_i3', 'true_peak_omega_i3', 'true_peak_db_i4', 'true_peak_omega_i4',
        'ss_minus_eq32_max', 'ss_minus_true_max', 'leso_measured_minus_true_max',
        'runtime_s')} | {'a_weak_reproduced': BOOL, 'a_db_at_5_1286': LIST})


def test_seed_experiments() -> None:
    r = run_bench('seed_experiments', '--quick', '--jobs', '1', timeout_s=300)
    check(r, {k: NUM for k in (
        'sine5_td_ratio', 'sine5_gap_ratio_9_8hz', 'sine5_gap_ratio_14_6hz',
        'edge_step_chatter_9_8hz', 'edge_step_chatter_14_6hz', 'thin_sheet_ladrc_range_mm',
        'thin_sheet_pid_range_mm', 'wall_s')} | {'runs': INT, 'rows': LIST})
    assert r['runs'] == len(r['rows']) > 0


def test_sweep_engine() -> None:
    r = run_bench('sweep_engine', '--sets', '1', '--scenarios', 'sine_5hz', '--workers', '1',
                  timeout_s=600)
    check(r, {'points': INT, 'one_core_s': NUM, 'engine_s': NUM, 'identical': BOOL,
              'front': INT, 'driver_peak_rss_mb': NUM, 'worker_peak_rss_mb': NUM})


def test_sweep_speed() -> None:
    r = run_bench('sweep_speed', '--quick', '--sets', '2', timeout_s=300)
    check(r, {'n_sets': INT, 'scenarios': LIST, 'wall_s': NUM, 'aggregate_realtime_x': NUM,
              'single_scenario': DICT, 'worst_error_rms_mm': DICT})
    check(r['single_scenario'], {'sine_5hz': DICT}, 'single_scenario: ')


# ----------------------------------------------------------------- benches with ROS nodes

@pytest.mark.ros
def test_stalls(ros_env: dict[str, str]) -> None:
    """One condition (the normal scheduler, no busy loops), half a second."""
    r = run_bench('stalls', '--seconds', '0.5', '--conditions', 'normal_idle', timeout_s=300,
                  env=ros_env)
    check(r, {'date': STR, 'cpus': INT, 'seconds': NUM, 'stall_max_fifo_ms': NULL,
              'stall_max_normal_ms': NUM, 'STALL_MAX_S': NULL, 'STALL_MAX_NORMAL_S': NUM,
              'conditions': DICT})
    check(r['conditions'], {'normal_idle': DICT}, 'conditions: ')
    check(r['conditions']['normal_idle'], {
        'ticks': INT, 'rate_hz': NUM, 'late_p50_ms': NUM, 'late_p99_ms': NUM,
        'late_max_ms': NUM, 'over_2ms': INT, 'period_max_ms': NUM, 'stalls': LIST,
        'loop_thread_policy': STR, 'applied': LIST, 'warnings': LIST}, 'normal_idle: ')


@pytest.mark.ros
def test_loop_timing(ros_env: dict[str, str]) -> None:
    """One loop mode with the full recorder, half a second measured; no lock-step runs."""
    r = run_bench('loop_timing', '--floor', '0.5', '--duration', '0.5', '--loops', 'deadline',
                  '--recorder', 'with', '--lockstep', '0',
                  '--domain-id', ros_env['ROS_DOMAIN_ID'], timeout_s=600, env=ros_env)
    figures = {'rate_hz': NUM, 'ticks': INT, 'period_p99_us': NUM, 'latency_p99_ms': NUM,
               'fault_ticks': INT, 'fault_causes': DICT, 'watchdog_trips': INT}
    check(r, figures | {'duration_s': NUM, 'bare_timer_rate_hz': NUM,
                        'bare_timer_period_p99_us': NUM, 'lockstep_realtime_x': NULL,
                        'lockstep_alone_realtime_x': NULL, 'runs': DICT, 'lockstep': NULL,
                        'lockstep_alone': NULL})
    check(r['runs'], {'deadline/with_recorder': DICT}, 'runs: ')
    check(r['runs']['deadline/with_recorder'], figures, 'runs/deadline/with_recorder: ')


@pytest.mark.ros
def test_showcase_live(ros_env: dict[str, str]) -> None:
    """One free-running run of a 4 s scenario (its outcome is the machine's; the keys are not)."""
    r = run_bench('showcase_live', '--runs', '1', '--scenario', 'step',
                  '--domain-id', ros_env['ROS_DOMAIN_ID'], timeout_s=300, env=ros_env)
    check(r, {'scenario': STR, 'runs': INT, 'clean_runs': INT, 'stopped_by_timing_guard': INT,
              'other_faults': INT, 'faults_by_code': DICT, 'first_faults': LIST,
              'failed': INT})
    assert r['runs'] == 1 and r['failed'] == 0, r
    assert r['clean_runs'] + r['stopped_by_timing_guard'] + r['other_faults'] == 1, r


@pytest.mark.ros
def test_live_jobs(ros_env: dict[str, str]) -> None:
    """The shortest shipped job in lock step (deterministic: the same on a loaded machine)."""
    r = run_bench('live_jobs', '--jobs', 'tipping_pair', '--lockstep',
                  '--domain-id', ros_env['ROS_DOMAIN_ID'], timeout_s=900, env=ros_env)
    check(r, {'lockstep': BOOL, 'separate_cnc': BOOL, 'jobs': DICT, 'all_ok': BOOL})
    check(r['jobs'], {'tipping_pair': DICT}, 'jobs: ')
    job = r['jobs']['tipping_pair']
    check(job, {'live': DICT, 'headless': DICT, 'declared_tipping': BOOL, 'verdict': STR},
          'jobs/tipping_pair: ')
    figures = {'finished': BOOL, 'job_time_s': NUM, 'contacts': INT, 'faults': INT}
    check(job['headless'], figures, 'headless: ')
    # the live figures are bringup's last line: none if bringup failed (the bench goes on)
    check(job['live'], figures | {'realtime_x': NUM}, 'live: ')


@pytest.mark.ros
def test_linuxcnc_jobs(ros_env: dict[str, str]) -> None:
    """The shortest shipped job, one LinuxCNC run with the allowance; no live sim, no extras."""
    from system import require

    require('linuxcnc')
    r = run_bench('linuxcnc_jobs', '--jobs', 'tipping_pair', '--runs', '1', '--allowances',
                  'allowance', '--blend-job', 'none', '--gcode-job', 'none', '--no-sim-live',
                  '--domain-id', ros_env['ROS_DOMAIN_ID'], timeout_s=900, env=ros_env)
    check(r, {'jobs': DICT, 'runs': INT, 'allowances': LIST, 'blend': NULL, 'foreign': NULL,
              'all_ok': BOOL, 'wall_s': NUM})
    job = r['jobs']['tipping_pair']
    check(job, {'headless': DICT, 'sim_live': NULL, 'linuxcnc': DICT, 'ran_to_end': DICT,
                'verdict': STR}, 'jobs/tipping_pair: ')
    figures = {'job_time_s': NUM, 'holds': DICT, 'corner_max_down_mm': NUM, 'contacts': INT,
               'faults': INT, 'pierces': INT}
    check(job['headless'], figures, 'headless: ')
    runs = job['linuxcnc']['allowance']
    assert len(runs) == 1 and job['ran_to_end']['allowance'][1] == 1
    # a LinuxCNC run's figures are bringup's last line (the bench goes on if it failed)
    check(runs[0], figures | {'bridge_moved_before_ready': INT, 'm62_holds': INT},
          'linuxcnc/allowance[0]: ')


@pytest.mark.ros
def test_view_load(ros_env: dict[str, str]) -> None:
    """One round (without, with the live view) on a 1 s scenario after the approach."""
    import socket

    with socket.socket() as s:  # a free port on 127.0.0.1 for the view
        s.bind(('127.0.0.1', 0))
        port = s.getsockname()[1]
    r = run_bench('view_load', '--rounds', '1', '--seconds', '1', '--port', str(port),
                  '--domain-id', ros_env['ROS_DOMAIN_ID'], timeout_s=600, env=ros_env)
    check(r, {'rounds': INT, 'scenario': STR, 'runs': LIST, 'without_view': DICT,
              'with_view': DICT, 'rate_hz_without': NUM, 'rate_hz_with': NUM,
              'period_p99_us_without': NUM, 'period_p99_us_with': NUM, 'status_rate_hz': NUM,
              'view_cpu_pct': NUM, 'all_fault_reasons_received': BOOL})
    loop = {'view': BOOL, 'load_1min': NUM, 'rate_hz': NUM, 'period_p99_us': NUM,
            'period_max_us': NUM, 'ticks': INT, 'fault_ticks': INT, 'watchdog_trips': INT}
    without, with_view = r['runs']
    check(without, loop, 'runs[0]: ')
    check(with_view, loop | {'view_cpu_pct': NUM, 'status_received': INT, 'status_ticks': INT,
                             'status_rate_hz': NUM, 'fault_reasons': LIST,
                             'fault_reasons_received': LIST, 'events': INT,
                             'events_received': INT}, 'runs[1]: ')


@pytest.mark.ros
def test_cia402_timing(ros_env: dict[str, str]) -> None:
    """The CiA 402 path free-running at 1 ms for 1 s after the approach."""
    r = run_bench('cia402_timing', '--duration', '1', '--periods-ms', '1',
                  '--domain-id', ros_env['ROS_DOMAIN_ID'], timeout_s=600, env=ros_env)
    run = {'period_ms': NUM, 'held': NUM, 'sync_jitter_p99_us': OPT_NUM,
           'latency_p99_ms': OPT_NUM, 'latency_received_p99_ms': OPT_NUM, 'frames_per_s': INT,
           'bus_load_1mbit': NUM, 'contacts': INT, 'faults': INT, 'ran_to_end': BOOL}
    check(r, run | {'duration_s': NUM, 'runs': LIST})
    check(r['runs'][0], run, 'runs[0]: ')


def test_every_bench_has_its_smoke_test() -> None:
    """A bench without a test here could break silently: each bench/NAME.py has test_NAME*."""
    names = {p.stem for p in BENCH.glob('*.py')}
    tests = {n for n in globals() if n.startswith('test_')}
    missing = sorted(n for n in names if not any(t == f'test_{n}' or t.startswith(f'test_{n}_')
                                                  for t in tests))
    assert not missing, f'benches without a smoke test in tests/test_benches.py: {missing}'
