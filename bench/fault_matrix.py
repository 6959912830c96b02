"""The fault-injection matrix of the safety issue: each row injects one fault, prints its figure.

    scripts/in-env python bench/fault_matrix.py [--load-s 30] [--clients-s 18] [--skip-live]
        [--only headless|param-fuzz|cnc-fuzz|live|canopen]

Headless rows run the FollowController against the simulator models (the runner the sim node
drives), deterministic per seed: a frozen sensor with fresh stamps, sensor stops of 5/50/500 ms,
a nozzle sliding off an edge (coverage 1 → 0.5, 0.06, 0 over 1 s and over 50 ms), the notes'
half-off edge scenarios (each edge row also with the edge verification off), the
verification's known limit (a slide at the crest of a wavy sheet), corrupted inputs
(NaN / ±inf / out-of-range gap marked valid, NaN / inf encoder), and a parameter fuzz over
every declared parameter (invalid values must be rejected, valid ones must never crash, also
through ``set_params`` of a running controller).

Live rows start real processes (sim node, follow node, recorder) on an isolated DDS domain: the
controller SIGKILLed while following (time until the simulated axis is at rest), the driver
killed and restarted (the controller holds and resumes only on command), the recorder SIGKILLed
(how much of the bag is lost), a second publisher injecting NaN readings marked valid, a live
parameter fuzz over SetParameters, ``--load-s`` seconds of following with two busy loops at
normal priority on both cores (spurious faults), and rounds of 20 nodes with
parameter clients, each in a process of its own, appearing and vanishing for ``--clients-s``
seconds while the axis follows (faults, tick period max and p99, drive watchdog trips). The
topics are watched, and services called, through the test probe process
(tests/support/rosnodes.py ``Probe``, tests/support/probe_node.py): this process runs no rclpy,
and a crash of the probe is counted as ``probe_crashes``, apart from the nodes' crashes. A row
that SIGKILLs a node closes its probe 3 s after the kill at the earliest (Fast DDS 2.14's
shared-memory port replacement, probe_node.py "Why a process").

A contact is a true gap <= 0 (sim truth). Last line: one JSON object with at least
``contacts``, ``node_crashes``, ``probe_crashes``, ``nonfinite_commands``,
``invalid_params_accepted``, ``invalid_params_tried``, ``spurious_faults_under_load``,
``kill_stop_ms``, ``recorder_kill_loss_s``, ``param_clients``, and every row.

CiA 402 rows (``canopen``) run the same follow on the CANopen path (the CiA 402
driver node, the emulated drive, the test bus; free-running at 1 ms, the period the test bus
holds on 2 cores): the driver SIGKILLed (the shipped drive's RPDO event timer; and a drive
without one, ``examples/servo_a_heartbeat.yaml``, whose heartbeat consumer stops it), the
emulated drive SIGKILLed, the bus server killed, an EMCY following error, a second master's
RPDOs at -50 mm/s, random frames on the bus; last-line keys ``canopen_kill_stop_ms``,
``canopen_heartbeat_kill_stop_ms`` and ``canopen_node_crashes``.

LinuxCNC rows (``linuxcnc``; ``bringup --cnc linuxcnc --fault``, a three-contour
job): LinuxCNC SIGKILLed while cutting (the controller lifts the head and stops), the bridge
SIGKILLed (LinuxCNC holds its feed and pauses, the controller holds on the stale CNC), LinuxCNC's
estop while cutting; each with the contact, the nozzle's fall after the fault, its lift, the
controller's final state (``linuxcnc_rows``); last-line key ``linuxcnc_rows_not_run``.

``--only PART`` runs one part of the matrix: ``headless`` (the headless rows), ``param-fuzz``,
``cnc-fuzz`` (the CNC interface fuzz, the cheapest: tests/test_benches.py runs it), ``live``,
``canopen`` or ``linuxcnc``; the summary's figures of the parts not run are 0 or null.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import typing

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'tests' / 'support'))
os.environ['ROS_DOMAIN_ID'] = str(random.randint(1, 101))
os.environ.pop('FASTRTPS_DEFAULT_PROFILES_FILE', None)  # the shipped loopback profile

from ladrc_bringup.bringup import loopback_settings  # noqa: E402

os.environ.update(loopback_settings(os.environ))

from ladrc_contract.schema import entries  # noqa: E402
from ladrc_contract.tick import CncInput  # noqa: E402
from ladrc_follow.control.follow import FollowController  # noqa: E402
from ladrc_follow.control.params import (  # noqa: E402
    ControllerParams,
    ParameterError,
    params_from_dict,
)
from ladrc_sim.headless import runner  # noqa: E402
from ladrc_sim.headless.scenario import load_scenario, scenario_from_dict  # noqa: E402
from ladrc_tools.offline.suite import LAW_ONLY  # noqa: E402

FAULT = 5
PID, LADRC = 3, 4
EDGE_HOLDS = ('edge', 'out of panel edge')  # the edge guard's hold reasons (edge.py)
SCENARIOS = ROOT / 'tests' / 'ros' / 'scenarios'
ROWS: list[dict] = []
OFF_LABEL = ' (edge verification off)'
KNOWN_LIMIT = ' (known limit)'


def row(name: str, **figures) -> dict:
    """Record and print one row of the matrix."""
    r = {'row': name, **figures}
    ROWS.append(r)
    text = ', '.join(f'{k} {v:.4g}' if isinstance(v, float) else f'{k} {v}'
                     for k, v in figures.items())
    print(f'{name:44s} {text}', flush=True)
    return r


# ---------------------------------------------------------------------------- headless rows
class Corrupt:
    """Wrap a FollowController; ``corrupt(t, tick) -> tick`` rewrites its inputs."""

    def __init__(self, ctrl: FollowController, corrupt) -> None:
        self.c, self.corrupt = ctrl, corrupt

    def step(self, tick) -> float:
        """Step the controller on the corrupted inputs."""
        return self.c.step(self.corrupt(tick.t_s, tick))

    def command(self, name, **kwargs):
        """Pass a follow command on."""
        return self.c.command(name, **kwargs)

    def internals(self):
        """Return the controller's internals."""
        return self.c.internals()


def headless(name: str, timeline=(), sheet=None, duration_s=3.5, corrupt=None,
             scenario=None, params: ControllerParams | None = None, edge: bool = False) -> dict:
    """Run one headless case; return its row (contact, min gap, fault, downward after fault).

    ``edge`` rows also report ``gap_over_target``: the smallest true gap / target gap while
    following (the safety issue's bar for edges: >= 0.7).
    """
    if scenario is None:
        d = dict(name=name, duration_s=duration_s, seed=3, initial_gap_mm=3.0,
                 sensor={'noise_std_mm': 0.005, 'quant_mm': 0.001},
                 timeline=[{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0},
                           *timeline])
        if sheet:
            d['sheet'] = sheet
        sc = scenario_from_dict(d)
    else:
        sc = load_scenario(scenario)
    c = FollowController(params or ControllerParams())
    ctrl = c if corrupt is None else Corrupt(c, corrupt)
    res = runner.run(sc, ctrl, record_internals=True)
    gap = np.asarray(res.true_gap_mm)
    u = np.asarray(res.command_mm_s)
    state = np.asarray(res.internals['state'])
    faulted = bool(np.any(state == FAULT))
    k = int(np.argmax(state == FAULT)) if faulted else len(u)
    extra = {}
    if edge:
        extra['gap_over_target'] = round(gap_over_target(
            gap, np.asarray(res.internals['target_gap_mm'], dtype=float)), 3)
        # an edge is held, not latched (edge.py): the first edge hold, nothing toward the sheet
        # while held, and whether the run ends following again
        reasons = res.internals['hold_reason']
        at_edge = np.array([r.startswith(EDGE_HOLDS) for r in reasons], dtype=bool)
        extra['edge_hold'] = (reasons[int(np.argmax(at_edge))][:50] if at_edge.any()
                              else '-')
        extra['downward_while_edge_held'] = bool(np.any(u[at_edge] < 0.0))
        extra['following_at_end'] = bool(state[-1] in (PID, LADRC) and not at_edge[-1])
    return row(name, contact=bool(gap.min() <= 0.0), min_true_gap_mm=float(gap.min()),
               fault=c.fault_reason[:70] if faulted else '-',
               downward_after_fault=bool(np.any(u[k:] < 0.0)),
               nonfinite_commands=int(np.sum(~np.isfinite(u))), **extra)


def gap_over_target(gap: np.ndarray, target: np.ndarray) -> float:
    """Smallest true gap / target of the follow in progress (held through a fault).

    After a target change the smaller of the new and the previous target counts (a step up
    starts below the new target by design).
    """
    ok = np.isfinite(target) & (target > 0.0)
    if not ok.any():
        return math.nan
    first = int(np.argmax(ok))
    held = np.maximum.accumulate(np.where(ok, np.arange(len(target)), first))
    t = target[held]
    ref = t.copy()
    prev = t[first]
    for i in range(first + 1, len(t)):
        if t[i] != t[i - 1]:
            prev = t[i - 1]
        ref[i] = min(t[i], prev)
    return float(np.min(gap[first:] / ref[first:]))


def headless_rows() -> None:
    print('-- headless: sensor, edges, corrupted inputs')
    sine = {'profiles': [{'kind': 'sine', 'amp_mm': 0.3, 'freq_hz': 1.0}]}
    headless('frozen reading, fresh stamps, moving sheet',
             [{'t_s': 1.5, 'do': 'sensor_freeze', 'duration_s': 1.0}], sheet=sine)
    for ms in (5, 50, 500):
        headless(f'sensor stream stops {ms} ms',
                 [{'t_s': 1.5, 'do': 'sensor_dropout', 'duration_s': ms * 1e-3}], sheet=sine)
    # shipped, and without the edge verification (what it buys)
    off = params_from_dict({'edge': dict(LAW_ONLY)})
    for label, params in (('', None), (OFF_LABEL, off)):
        for cov in (0.5, 0.06, 0.0):
            for ramp in (1.0, 0.05):
                headless(f'edge: coverage 1 -> {cov:g} over {ramp * 1e3:g} ms{label}',
                         [{'t_s': 1.5, 'do': 'coverage', 'value': cov, 'ramp_s': ramp}],
                         params=params, edge=True)
        for sc in ('edge_step_2_5', 'edge_step_3_1', 'edge_open_10_1'):
            headless(f'seed edge scenario {sc}{label}', scenario=sc, params=params, edge=True)
    # off the sheet and back: the hold must end by itself (no latched FAULT)
    for cov in (0.7, 0.5, 0.3):
        headless(f'edge: {1 - cov:.0%} off the sheet for 1.5 s, then back',
                 [{'t_s': 1.5, 'do': 'coverage', 'value': cov, 'ramp_s': 0.2},
                  {'t_s': 3.0, 'do': 'coverage', 'value': 1.0, 'ramp_s': 0.2}],
                 duration_s=5.0, edge=True)
    # the verification's known limit (docs/safety.md): a slide at the crest of a wavy sheet
    # sinks only as far as the trough already verified before anything is verified
    for amp in (0.3, 0.5):
        headless(f'edge at a crest of a 0.5 Hz, {amp:g} mm sine sheet{KNOWN_LIMIT}',
                 [{'t_s': 2.85, 'do': 'coverage', 'value': 0.06, 'ramp_s': 0.3}],
                 sheet={'profiles': [{'kind': 'sine', 'amp_mm': amp, 'freq_hz': 0.5,
                                      't_start_s': 0.5}]}, duration_s=4.5, edge=True)

    def window(fn):
        return lambda t, tick: fn(tick) if 1.5 <= t < 1.52 else tick

    for label, fn in (
            ('gap NaN marked valid', lambda k: k._replace(gap_mm=math.nan)),
            ('gap +inf marked valid', lambda k: k._replace(gap_mm=math.inf)),
            ('gap -inf marked valid', lambda k: k._replace(gap_mm=-math.inf)),
            ('gap 1e6 mm marked valid', lambda k: k._replace(gap_mm=1e6)),
            ('gap -1 mm marked valid', lambda k: k._replace(gap_mm=-1.0)),
            ('encoder NaN', lambda k: k._replace(encoder_mm=math.nan)),
            ('encoder +inf', lambda k: k._replace(encoder_mm=math.inf)),
            ('stamp 2 s in the future', lambda k: k._replace(gap_stamp_s=k.t_s + 2.0))):
        headless(f'input: {label} (20 ms)', sheet=sine, corrupt=window(fn))


def parameter_fuzz(rng: random.Random) -> tuple[int, int, int]:
    """Invalid values must be rejected (as a reason), valid ones must never crash."""
    print('-- headless: parameter fuzz')
    tried = accepted = crashes = 0
    running = FollowController(ControllerParams())
    for e in entries(ControllerParams()):
        spec = e.spec
        if spec.choices:
            bad = ['nonsense', -7, 3.5]
        elif e.type is bool:
            bad = ['yes', 2, None]
        elif e.type is str:  # sensor.table_file: a path
            bad = [3, 1.5, None, True]
        else:
            lo, hi = spec.lower, spec.le
            bad = [math.inf, -math.inf, math.nan, 1e300, -1e300, 10 ** 400, hi * 2 + 1,
                   lo - 1, 'fast', None]
            if spec.gt is not None:
                bad.append(lo)
        for value in bad:
            if typing.get_origin(e.type) is tuple and not isinstance(value, (str, type(None))):
                value = [value] * len(e.value)
            tried += 1
            try:
                p = params_from_dict({e.name: value})
                accepted += 1
                print(f'   ACCEPTED invalid {e.name} = {value!r}')
                running.set_params(p)
            except (ParameterError, ValueError):
                pass
            except Exception as exc:  # noqa: BLE001 - that is what the row counts
                crashes += 1
                print(f'   CRASH {e.name} = {value!r}: {type(exc).__name__}: {exc}')
    # valid random values: accepted or refused by a cross check, never a crash
    numeric = [e for e in entries(ControllerParams()) if e.type in (int, float)
               and not e.spec.choices]
    for _ in range(300):
        e = rng.choice(numeric)
        lo, hi = e.spec.lower, e.spec.le
        value = rng.uniform(lo, hi) if e.type is float else rng.randint(int(lo), int(hi))
        try:
            running.set_params(params_from_dict({e.name: value}))
        except (ParameterError, ValueError):
            pass
        except Exception as exc:  # noqa: BLE001
            crashes += 1
            print(f'   CRASH valid {e.name} = {value!r}: {type(exc).__name__}: {exc}')
    row('parameter fuzz (headless)', invalid_tried=tried, invalid_accepted=accepted,
        valid_tried=300, crashes=crashes)
    return tried, accepted, crashes


class CncFuzz(Corrupt):
    """A CNC gone wrong: garbage motion samples every tick, random (often invalid) commands."""

    def __init__(self, ctrl: FollowController, rng: random.Random) -> None:
        super().__init__(ctrl, None)
        self.rng = rng
        self.seq = 0
        self.tried = self.accepted = 0
        self.exceptions = 0

    def _value(self) -> float:
        r = self.rng
        return r.choice([math.nan, math.inf, -math.inf, -5.0, 0.0, 1e300, r.uniform(0, 200)])

    def step(self, tick) -> float:
        """Step on a fuzzed CNC sample; issue a random CNC command now and then."""
        r, t = self.rng, tick.t_s
        self.seq += 1
        if r.random() < 0.9:  # mostly a plausible CNC, cutting with corners and edges ahead
            f = r.uniform(0.0, 200.0)
            return self._step(tick, CncInput(self.seq, t, r.choice([1, 2, 2, 2, 3]),
                                             r.random() < 0.9, 1, f, f * r.uniform(0.3, 1.0),
                                             r.uniform(0, 50), r.choice([math.inf, 3.0, 30.0])))
        cnc = CncInput(r.choice([self.seq, 0, 2 ** 63]),
                       r.choice([t, t, t - 1.0, t + 1.0, math.nan, -math.inf]),
                       r.randint(0, 5), r.random() < 0.5, r.randint(0, 3), self._value(),
                       self._value(), self._value(), self._value())
        return self._step(tick, cnc)

    def _step(self, tick, cnc: CncInput) -> float:
        r = self.rng
        if r.random() < 0.0005:  # the follow resumes (a lift or a leapfrog holds until then)
            self.c.command('set_target', target_gap_mm=1.0)
        if r.random() < 0.002:
            self.tried += 1
            name = r.choice(['pierce', 'lift', 'hold', 'leapfrog'])
            args = {'pierce': dict(heights_mm=[self._value() for _ in range(r.randint(0, 3))],
                                   dwell_s=[r.uniform(-1, 2) for _ in range(r.randint(0, 3))],
                                   cut_gap_mm=self._value() % 3, thc_delay_s=r.uniform(-1, 1)),
                    'lift': dict(mode=r.randint(-1, 2), value_mm=self._value(),
                                 velocity_mm_s=self._value()),
                    'hold': dict(hold=r.choice([True, False, 'x']),
                                 at_next_segment=r.choice([True, False]),
                                 reason=r.choice(['', 'fuzz'])),
                    'leapfrog': dict(lift_mm=self._value(), rapid_length_mm=self._value(),
                                     rapid_feed_mm_s=self._value(),
                                     arrive_height_mm=self._value() % 10)}[name]
            self.accepted += self.c.command(name, **args)[0]
        u = self.c.step(tick, cnc)
        if 'exception' in self.c.fault_reason:
            self.exceptions += 1
        return u


EMCY_T_S = 15.0
"""The CiA 402 EMCY row: the emulated drive raises it at this time of the run (after the follow
is established, which takes more than 5 s; the row fails where it was not yet)."""

LINUXCNC_FAULTS = (('kill-linuxcnc', 'LinuxCNC SIGKILLed while cutting'),
                   ('kill-bridge', 'LinuxCNC bridge SIGKILLed while cutting'),
                   ('estop', 'LinuxCNC estop while cutting'))
"""The LinuxCNC rows: ``bringup --cnc linuxcnc --fault KIND@SECONDS``."""


def linuxcnc_rows(at_s: float = 2.5) -> int:
    """Run the LinuxCNC rows: a 15-contour job under LinuxCNC, a fault ``at_s`` after start.

    From the run's bag (the sim's truth, the controller's status, by the fault's wall time) and
    its figures: ``contact``, ``min_true_gap_after_mm``, ``down_after_mm`` (the nozzle's fall
    below its height at the fault: nothing toward the sheet), ``lift_mm`` (its rise after it),
    ``final_state`` (the controller's, IDLE: stopped), ``stale_hold`` (held on a stale CNC),
    and LinuxCNC's side (``paused``, ``feed_hold``: from its HAL pins or the bridge's log).
    Returns the rows that could not run (LinuxCNC missing: 0 rows, a line).
    """
    from ladrc_bags import BagError, open_bag
    from ladrc_linuxcnc.machine import missing
    from linuxcnc_runs import bringup_linuxcnc, small_job

    why = missing()
    if why:
        print(f'LinuxCNC rows not run: {why}')
        return len(LINUXCNC_FAULTS)
    failed = 0
    for kind, name in LINUXCNC_FAULTS:
        tmp = Path(tempfile.mkdtemp(prefix='fault-linuxcnc-'))
        try:
            job = small_job(tmp / 'job', small_holes=12)  # (lasts past a late fault)
            rc, f, err = bringup_linuxcnc(job, tmp / 'logs', '--fault', f'{kind}@{at_s:g}',
                                          '--bag', str(tmp / 'bag'), '--domain-id',
                                          str(random.randint(120, 200)), timeout_s=300.0)
            fault = f.get('linuxcnc', {}).get('fault')
            if not fault:
                print(f'   {name}: no fault injected: {f.get("aborted")} {err[-500:]}')
                failed += 1
                continue
            t_fault = float(fault['t_wall_s'])
            try:
                b = open_bag(tmp / 'bag')
                truth = b.columns('sim/truth', ['true_gap_mm', 'nozzle_mm'])
                status = b.columns('follow/status', ['state', 'substate', 'hold_reason'])
            except (BagError, ValueError, KeyError) as exc:
                print(f'   {name}: bag unreadable: {exc}')
                failed += 1
                continue
            tt = truth['timestamp_ns'] * 1e-9
            after = tt >= t_fault
            nozzle_at = float(truth['nozzle_mm'][np.argmax(after)]) if after.any() else math.nan
            st = status['timestamp_ns'] * 1e-9 >= t_fault
            reasons = [str(r) for r, s in zip(status['hold_reason'][st],
                                              status['substate'][st], strict=True) if s == 7]
            bridge = f['linuxcnc'].get('bridge', {})
            hal = fault.get('linuxcnc_after', {})
            row(name, contact=bool(np.nanmin(truth['true_gap_mm']) <= 0.0),
                min_true_gap_after_mm=round(float(np.nanmin(truth['true_gap_mm'][after])), 4)
                if after.any() else None,
                down_after_mm=round(nozzle_at - float(np.nanmin(truth['nozzle_mm'][after])), 4)
                if after.any() else None,
                lift_mm=round(float(np.nanmax(truth['nozzle_mm'][after])) - nozzle_at, 4)
                if after.any() else None,
                final_state=int(status['state'][-1]) if len(status['state']) else None,
                stale_hold=any(r.startswith('CNC motion stale') for r in reasons),
                bridge_aborted=bridge.get('aborted'), bridge_lifts=bridge.get('lifts'),
                paused=bool(hal.get('is-paused', f['linuxcnc'].get('paused'))),
                feed_hold=hal.get('feed-hold-in'), link_ok=hal.get('link-ok'),
                estop=f['linuxcnc'].get('estop'),
                at_s=fault.get('at_s'), job_aborted=f.get('aborted'))
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return failed


def cnc_fuzz(rng: random.Random) -> None:
    """Run the row of the CNC interface fed garbage while following a sine sheet."""
    d = dict(name='cnc_fuzz', duration_s=8.0, seed=3, initial_gap_mm=3.0,
             sensor={'noise_std_mm': 0.005, 'quant_mm': 0.001},
             sheet={'profiles': [{'kind': 'sine', 'amp_mm': 0.3, 'freq_hz': 1.0}]},
             timeline=[{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}])
    c = FollowController(ControllerParams())
    fz = CncFuzz(c, rng)
    res = runner.run(scenario_from_dict(d), fz, record_internals=True)
    gap = np.asarray(res.true_gap_mm)
    u = np.asarray(res.command_mm_s)
    row('CNC interface fuzz (headless)', contact=bool(gap.min() <= 0.0),
        min_true_gap_mm=float(gap.min()), commands_tried=fz.tried,
        commands_accepted=fz.accepted, exception_ticks=fz.exceptions,
        ladrc_ticks=int(np.sum(np.asarray(res.internals['state']) == 4)),
        nonfinite_commands=int(np.sum(~np.isfinite(u))))


# ---------------------------------------------------------------------------- live rows
# One parameter client of the param_clients row: a process of its own (rclpy.init, a node, one
# GetParameters call, destroy, exit), as a tool such as `ros2 param get` is. Last stdout line:
# JSON (answered, the value, its seconds from start to service ready and to the answer).
PARAM_CLIENT = r"""
import json, os, sys, time
t0 = time.monotonic()
import rclpy
from rcl_interfaces.srv import GetParameters
out = {'answered': False}
rclpy.init()
try:
    node = rclpy.create_node(f'fault_matrix_param_client_{os.getpid()}')
    cli = node.create_client(GetParameters, '/ladrc_follow/get_parameters')
    ready = cli.wait_for_service(timeout_sec=10.0)
    out['ready_s'] = time.monotonic() - t0
    if ready:
        future = cli.call_async(GetParameters.Request(names=['law.kp']))
        rclpy.spin_until_future_complete(node, future, timeout_sec=10.0)
        res = future.result() if future.done() else None
        if res is not None and len(res.values) == 1:
            out.update(answered=True, value=res.values[0].double_value,
                       answer_s=time.monotonic() - t0)
    node.destroy_node()
finally:
    rclpy.try_shutdown()
print(json.dumps(out))
"""
SIGKILL_SETTLE_S = 3.0  # Fast DDS 2.14: no probe teardown within ~1 s of a publisher's SIGKILL


def live_rows(load_s: float, clients_s: float) -> dict:
    from diagnostic_msgs.msg import DiagnosticArray
    from ladrc_bags import BagError, open_bag
    from ladrc_bringup.bringup import node_specs, ros_arguments
    from ladrc_msgs.msg import CapacitiveHeight, FollowStatus, SimTruth, VelocityCommand
    from ladrc_msgs.srv import StartFollow
    from rcl_interfaces.msg import ParameterType
    from rcl_interfaces.srv import SetParameters
    from rosnodes import NodeProcesses, Probe, ProbeError

    out: dict = {'node_crashes': 0, 'probe_crashes': 0}
    domains = iter(random.sample(range(1, 102), 20))  # one per live setup (recorder: 3)

    class Live:
        """The processes and probe (a process of its own) of one row, on its own DDS domain.

        A SIGKILLed node of the previous row leaves middleware state behind that must not
        meet the next row's nodes. ``kill`` notes the time: the probe's teardown waits
        SIGKILL_SETTLE_S after it (tests/support/probe_node.py, "Why a process").
        """

        def __init__(self, name: str) -> None:
            os.environ['ROS_DOMAIN_ID'] = str(next(domains))
            self.nodes = NodeProcesses()
            self.probe = Probe(name)
            self.t_sigkill: float | None = None

        def kill(self, name: str) -> None:
            self.nodes.kill(name)
            self.t_sigkill = time.monotonic()

        def close(self) -> None:
            try:
                if self.t_sigkill is not None:
                    wait = self.t_sigkill + SIGKILL_SETTLE_S - time.monotonic()
                    if wait > 0:
                        time.sleep(wait)  # the probe process serves its readers meanwhile
                try:
                    self.probe.close()
                except ProbeError as exc:  # the probe's crash, not a node's
                    out['probe_crashes'] += 1
                    print(f'   PROBE CRASH {self.probe.name}: {str(exc)[:1500]}')
            finally:
                self.nodes.close()

    scenario = str(SCENARIOS / 'follow_sine.yaml')

    def stamp_s(row) -> tuple:
        """(header.stamp.sec, header.stamp.nanosec, *rest) -> (stamp [s], *rest)."""
        return (row[0] + row[1] * 1e-9, *row[2:])

    def start_axis(live: Live, with_recorder: Path | None = None):
        nodes, probe = live.nodes, live.probe
        if with_recorder is not None:
            nodes.start('recorder', 'ladrc_bags', 'recorder', '-p', f'output:={with_recorder}')
        # the configuration of bring-up (product timeouts, real-time settings, CPU pinning)
        for spec in node_specs(scenario):
            if spec.executable in ('follow_node', 'sim_node'):
                extra = ['-p', 'wait_for_controller_s:=0.0'] if spec.executable == 'sim_node' \
                    else []
                nodes.start(spec.executable.split('_')[0], spec.package, spec.executable,
                            *ros_arguments(spec)[1:], *extra)
        # rows: (t_s, state, fault_reason, velocity_mm_s, gap_seq, period_us)
        status = probe.record(FollowStatus, 'follow/status', fields=[
            't_s', 'state', 'fault_reason', 'velocity_mm_s', 'gap_seq', 'period_us'])
        # rows: (stamp [s], true_gap_mm, nozzle_mm)
        truth = probe.record(SimTruth, 'sim/truth', fields=[
            'header.stamp.sec', 'header.stamp.nanosec', 'true_gap_mm', 'nozzle_mm'],
            keep=stamp_s)
        # rows: (stamp [s], velocity_mm_s, enable)
        cmds = probe.record(VelocityCommand, 'axis/velocity_command', fields=[
            'header.stamp.sec', 'header.stamp.nanosec', 'velocity_mm_s', 'enable'],
            keep=stamp_s)
        if not probe.spin_until(lambda: len(status) > 200 and status[-1][4] > 0, 30.0):
            raise RuntimeError('no follow/status: ' + nodes.log('follow')[-1500:])
        res = probe.call(StartFollow, 'follow/start', StartFollow.Request(target_gap_mm=1.0))
        assert res.accepted, res.message
        if not probe.spin_until(lambda: status[-1][1] == 4, 20.0):
            raise RuntimeError(f'not following: {status[-1]}')
        return status, truth, cmds

    def crashed(nodes: NodeProcesses, *names: str) -> int:
        n = 0
        for name in names:
            rc = nodes.procs[name].poll()
            if rc is not None and rc != 0:
                n += 1
                print(f'   {name} exited with {rc}: {nodes.log(name)[-600:]}')
        return n

    def contacts_of(truth) -> int:
        return int(any(g <= 0.0 for _, g, _ in truth))

    def watchdog_lines(nodes: NodeProcesses) -> int:
        """Count the drive watchdog's trips so far: 'watchdog:' lines of the sim's log."""
        return sum(1 for ln in nodes.log('sim').splitlines() if 'watchdog:' in ln)

    def fault_entries(status, n0: int) -> list:
        """Return the status rows from ``n0`` on at which the state became FAULT."""
        prev = status[n0 - 1][1] if n0 > 0 else None
        entries_ = []
        for s in status[n0:]:
            if s[1] == FAULT and prev != FAULT:
                entries_.append(s)
            prev = s[1]
        return entries_

    # L1: controller SIGKILL while following: the drive's watchdog stops the axis
    live = Live('fault_probe_1')
    try:
        nodes, probe = live.nodes, live.probe
        status, truth, cmds = start_axis(live)
        # kill while the axis moves: the sheet's 1 Hz sine runs from 4 s of the scenario
        moving_cmd = probe.spin_until(
            lambda: abs(cmds[-1][1]) > 1.5 and status[-1][0] > 5.0, 20.0)
        state_at_kill = f'{status[-1][1]} {status[-1][2]}'.strip()
        t_kill = time.time()
        live.kill('follow')
        probe.spin_for(1.0)
        tr = np.asarray(truth[:], dtype=float)
        dt = np.maximum(np.diff(tr[:, 0]), 1e-6)
        v = np.abs(np.diff(tr[:, 2])) / dt     # nozzle speed from the sim's truth
        after = tr[1:, 0] > t_kill
        v_kill = float(v[np.argmax(after)])
        moving = np.flatnonzero(after & (v > 0.1))
        rest_t = tr[moving[-1] + 2, 0] if moving.size else t_kill
        out['kill_stop_ms'] = float((rest_t - t_kill) * 1e3)
        row('controller SIGKILL while following', kill_stop_ms=out['kill_stop_ms'],
            speed_at_kill_mm_s=v_kill, moving_command_seen=moving_cmd,
            state_at_kill=state_at_kill, contact=bool(contacts_of(truth)))
        out['node_crashes'] += crashed(nodes, 'sim')
    finally:
        live.close()

    # L2: driver killed and restarted: the controller holds, resumes only on command
    live = Live('fault_probe_2')
    try:
        nodes, probe = live.nodes, live.probe
        status, truth, cmds = start_axis(live)
        probe.spin_for(0.5)
        live.kill('sim')
        probe.spin_for(0.5)
        state_after_kill = status[-1][1]
        n_cmd = len(cmds)
        sim_spec = next(s for s in node_specs(scenario) if s.executable == 'sim_node')
        nodes.start('sim2', 'ladrc_sim', 'sim_node', *ros_arguments(sim_spec)[1:],
                    '-p', 'wait_for_controller_s:=0.0')
        probe.spin_for(3.0)
        later = cmds[n_cmd:]
        held = state_after_kill == FAULT and status[-1][1] == FAULT and all(
            v == 0.0 for _, v, _ in later)
        row('driver killed and restarted', state_after=int(status[-1][1]),
            commands_after_restart=len(later), held_until_commanded=held)
        out['driver_restart_held'] = held
        out['node_crashes'] += crashed(nodes, 'follow', 'sim2')
    finally:
        live.close()

    # L3: recorder SIGKILL: how much of the bag is lost (three kills, the worst counts)
    losses = []
    for trial in range(3):
        tmp = Path(tempfile.mkdtemp(prefix='fault-matrix-'))
        live = Live(f'fault_probe_3_{trial}')
        try:
            nodes, probe = live.nodes, live.probe
            bag = tmp / 'bag'
            status, truth, cmds = start_axis(live, with_recorder=bag)
            probe.spin_for(3.0 + 0.37 * trial)  # kills at different phases of the flush
            t_kill = time.time()
            live.kill('recorder')
            probe.spin_for(0.5)
            try:
                b = open_bag(bag)
                last = max(ts for ts, _ in b.raw('follow/status')) * 1e-9
                loss = t_kill - last
            except (BagError, ValueError) as exc:
                print(f'   bag unreadable after the kill: {exc}')
                loss = math.inf
            losses.append(float(loss))
            out['node_crashes'] += crashed(nodes, 'follow', 'sim')
        finally:
            live.close()
            shutil.rmtree(tmp, ignore_errors=True)
    out['recorder_kill_loss_s'] = max(losses)
    row('recorder SIGKILL (3 kills)', loss_s=max(losses),
        losses_s=' '.join(f'{x:.2f}' for x in losses))

    # L4: a second publisher injects NaN readings marked valid
    live = Live('fault_probe_4')
    try:
        nodes, probe = live.nodes, live.probe
        status, truth, cmds = start_axis(live)
        nan_gap = {'gap_mm': math.nan, 'valid': True, 'status': 0, 'seq': 10 ** 9}
        # the probe's publisher first (count 0), matched before the 50 ms of injection
        probe.publish(CapacitiveHeight, 'axis/capacitive_height', nan_gap, qos=10, count=0)
        probe.spin_for(1.0)
        n_cmd = len(cmds)
        injected = 0
        end = time.monotonic() + 0.05
        while time.monotonic() < end:
            # bursts of 10 at 2 kHz, each burst stamped now: every stamp within the node's
            # 10 ms stamp tolerance (a stale stamp would be a different fault)
            ns = time.time_ns()
            msg = {**nan_gap, 'header': {'stamp': {'sec': ns // 10 ** 9,
                                                   'nanosec': ns % 10 ** 9}}}
            injected += probe.publish(CapacitiveHeight, 'axis/capacitive_height', msg, qos=10,
                                      count=10, period_s=0.0005)
        probe.spin_for(0.5)
        after = cmds[n_cmd:]
        nonfinite = sum(1 for _, v, _ in after if not math.isfinite(v))
        faulted = any(s[1] == FAULT for s in status[-2000:])
        row('second publisher: NaN marked valid (50 ms)', fault=faulted,
            nonfinite_commands=nonfinite, contact=bool(contacts_of(truth)), injected=injected)
        out['nonfinite_live'] = nonfinite
        out['node_crashes'] += crashed(nodes, 'follow', 'sim')
    finally:
        live.close()

    # L4b: a second commander on axis/velocity_command, -50 mm/s with enable for 1 s while the
    # axis follows, at 1 Hz, 100 Hz and 2 kHz (one commander: ladrc_sim/node/commander_lock.py)
    from ladrc_msgs.msg import AxisFeedback

    out['second_commander'] = {}
    for rate_hz in (1, 100, 2000):
        live = Live(f'fault_probe_4b_{rate_hz}')
        try:
            nodes, probe = live.nodes, live.probe
            status, truth, cmds = start_axis(live)
            fbs = probe.record(AxisFeedback, 'axis/feedback',
                               fields=['seq', 'drive_fault', 'fault_reason'])
            n_truth = len(truth)
            intruder = {'velocity_mm_s': -50.0, 'enable': True, 'commander': '/intruder',
                        'session': 99}
            # its publisher first, matched before the commands (a best-effort message to an
            # unmatched reader is lost); the controller may see it in the graph meanwhile
            probe.publish(VelocityCommand, 'axis/velocity_command', intruder, qos=10, count=0)
            probe.spin_for(1.0)
            # 1 s at the rate, at least 3 messages (a single best-effort one may be lost)
            probe.publish(VelocityCommand, 'axis/velocity_command', intruder, qos=10,
                          count=max(3, rate_hz), period_s=1.0 / rate_hz, increment=['seq'])
            probe.spin_for(0.5)
            min_gap = min(g for _, g, _ in truth[n_truth:])
            nodes.interrupt('sim')
            log = nodes.log('sim')
            # the cycle as the feedback's seq counts it (the drive's cycle counter also counts
            # the cycles caught up silently after a stall of the simulator)
            first = re.search(r'drive fault at cycle \d+ \(next feedback seq (\d+)\): '
                              r'(second commander[^\n]*)', log)
            fault_seq = next((f[0] for f in fbs if 'second commander' in f[2]), None)
            summary = json.loads(log.split('commands by source: ')[1].splitlines()[0].strip())
            foreign_executed = sum(v for k, v in summary['cycles_executed'].items()
                                   if 'intruder' in k)
            names_both = bool(first) and '/intruder' in first.group(2) and \
                '/ladrc_follow' in first.group(2)
            cycles = (fault_seq - int(first.group(1))) if first and fault_seq is not None \
                else None
            follow_reason = next((s[2] for s in status if s[1] == FAULT), '')
            seconds = max(3, rate_hz) / rate_hz
            row(f'second commander at {rate_hz} Hz (-50 mm/s, {seconds:g} s)',
                contact=min_gap <= 0.0,
                min_true_gap_mm=round(min_gap, 3), foreign_cycles_executed=foreign_executed,
                fault_names_both=names_both, fault_after_cycles=cycles,
                follow_fault=follow_reason[:90])
            out['second_commander'][rate_hz] = {
                'contact': min_gap <= 0.0, 'min_true_gap_mm': min_gap,
                'foreign_cycles_executed': foreign_executed, 'fault_names_both': names_both,
                'fault_after_cycles': cycles, 'follow_fault': follow_reason}
            out['node_crashes'] += crashed(nodes, 'follow')
        finally:
            live.close()

    # L4c: a second publisher on each sensor topic: the controller's topology check
    from ladrc_msgs.msg import CapacitiveHeight as _Gap

    out['second_sensor'] = {}
    for topic, msg_type in (('axis/capacitive_height', _Gap), ('axis/feedback', AxisFeedback)):
        live = Live(f'fault_probe_4c_{topic.split("/")[1]}')
        try:
            nodes, probe = live.nodes, live.probe
            status, truth, cmds = start_axis(live)
            n_truth = len(truth)
            # a publisher that has sent nothing: only the topology check can see it
            probe.publish(msg_type, topic, {'seq': 10 ** 9}, qos=10, count=0)
            probe.spin_until(lambda st=status: st[-1][1] == FAULT, 10.0)
            reason = next((s[2] for s in status if s[1] == FAULT), '')
            row(f'second publisher on {topic}', fault=bool(reason),
                topology_reason='topology:' in reason, reason=reason[:100],
                contact=bool(contacts_of(truth[n_truth:])))
            out['second_sensor'][topic] = reason
            out['node_crashes'] += crashed(nodes, 'follow', 'sim')
        finally:
            live.close()

    # L5: live parameter fuzz over SetParameters
    live = Live('fault_probe_5')
    try:
        nodes, probe = live.nodes, live.probe
        status, truth, cmds = start_axis(live)
        tried = accepted = 0
        for e in entries(ControllerParams()):
            if e.type is not float:
                continue
            for value in (math.inf, math.nan, 1e300, -1e300, e.spec.le * 2 + 1):
                p = {'name': e.name, 'value': {'type': ParameterType.PARAMETER_DOUBLE,
                                               'double_value': value}}
                res = probe.call(SetParameters, '/ladrc_follow/set_parameters',
                                 {'parameters': [p]}).results[0]
                tried += 1
                accepted += int(res.successful)
        alive = nodes.procs['follow'].poll() is None
        row('parameter fuzz (live SetParameters)', invalid_tried=tried,
            invalid_accepted=accepted, node_alive=alive,
            state=int(status[-1][1]))
        out['live_params'] = (tried, accepted)
        out['node_crashes'] += crashed(nodes, 'follow', 'sim') + (0 if alive else 1)
    finally:
        live.close()

    # L6: following under load: two busy loops at normal priority on both cores
    live = Live('fault_probe_6')
    busy = []
    try:
        nodes, probe = live.nodes, live.probe
        status, truth, cmds = start_axis(live)
        n0 = len(status)
        busy = [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
                for _ in range(2)]
        probe.spin_for(load_s)
        seen = status[n0:]
        faults = sum(1 for i in range(1, len(seen))
                     if seen[i][1] == FAULT and seen[i - 1][1] != FAULT)
        reasons = sorted({s[2][:60] for s in seen if s[1] == FAULT})
        diag = {}

        def on_diag(msg):
            for st in msg.status:
                if st.name.startswith('ladrc_follow'):
                    diag.update({kv.key: kv.value for kv in st.values})

        probe.subscribe(DiagnosticArray, '/diagnostics', on_diag)
        probe.spin_for(1.2)
        row(f'following under load ({load_s:g} s, 2 busy loops)', spurious_faults=faults,
            reasons='; '.join(reasons) or '-', contact=bool(contacts_of(truth)),
            realtime=diag.get('realtime', '?'))
        out['spurious_faults_under_load'] = faults
        out['node_crashes'] += crashed(nodes, 'follow', 'sim')
    finally:
        for b in busy:
            b.send_signal(signal.SIGKILL)
            b.wait()
        live.close()

    # L7: 20 nodes with parameter clients, 20 processes, appear and vanish while the
    # axis follows; rounds of 20 at once (the next once all of a round ended), at least two,
    # for clients_s
    live = Live('fault_probe_7')
    clients: list[subprocess.Popen] = []
    try:
        nodes, probe = live.nodes, live.probe
        status, truth, cmds = start_axis(live)
        # the node's own tick statistics (every tick, also those the best-effort probe missed)
        diag = probe.record(DiagnosticArray, '/diagnostics', fields='status', qos=10)
        probe.poll()
        n0, d0 = len(status), len(diag)
        watchdog0 = watchdog_lines(nodes)
        results: list[dict] = []
        rounds = []
        t_start = time.monotonic()
        while len(rounds) < 2 or time.monotonic() - t_start < clients_s:
            t_round = time.monotonic()
            clients = [subprocess.Popen([sys.executable, '-c', PARAM_CLIENT],
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True, env=dict(os.environ),
                                        start_new_session=True) for _ in range(20)]
            probe.spin_until(lambda procs=clients: all(c.poll() is not None for c in procs),
                             60.0)
            for c in clients:
                if c.poll() is None:  # hung past 60 s: not a success
                    os.killpg(c.pid, signal.SIGKILL)
                stdout, stderr = c.communicate()
                try:
                    res = json.loads(stdout.strip().splitlines()[-1])
                except (IndexError, json.JSONDecodeError):
                    res = {'answered': False, 'error': (stderr or '').strip()[-300:]}
                res['rc'] = c.returncode
                results.append(res)
            clients = []
            rounds.append(time.monotonic() - t_round)
            probe.spin_for(0.5)
        probe.spin_for(1.0)
        seen = status[n0:]
        period_ms = np.asarray([s[5] for s in seen], dtype=float) * 1e-3
        entered = fault_entries(status, n0)
        reasons = [s[2][:80] for s in entered]
        diag_max_us = [float(kv.value) for statuses in diag[d0:] for st in statuses
                       if st.name.startswith('ladrc_follow') for kv in st.values
                       if kv.key == 'period_max_us']
        span_s = seen[-1][0] - seen[0][0] if len(seen) > 1 else math.nan
        watchdog = watchdog_lines(nodes) - watchdog0
        ok = sum(1 for r in results if r.get('answered') and r['rc'] == 0)
        fig = {
            'faults': len(entered), 'fault_reasons': reasons,
            'tick_period_max_ms': float(period_ms.max()) if period_ms.size else math.nan,
            'tick_period_p99_ms': float(np.percentile(period_ms, 99)) if period_ms.size
            else math.nan,
            'watchdog_trips': watchdog, 'clients_ok': ok, 'clients': len(results),
            'rounds': len(rounds), 'round_s': [round(x, 2) for x in rounds],
            'client_answer_s_max': round(max((r['answer_s'] for r in results
                                              if 'answer_s' in r), default=math.nan), 2),
            # controller time of each fault from the row's start [s]
            'fault_at_s': [round(s[0] - seen[0][0], 3) for s in entered],
            # the best-effort probe's share of the row's ticks (2 kHz): what the figures saw
            'status_seen_fraction': round(len(seen) / (span_s * 2000.0 + 1.0), 3),
            'tick_period_max_ms_diagnostics': max(diag_max_us, default=math.nan) * 1e-3,
            'contact': bool(contacts_of(truth)),
        }
        for r in results:
            if not (r.get('answered') and r['rc'] == 0):
                print(f'   client failed: {r}')
        row('parameter clients: 20 nodes in 20 processes', faults=fig['faults'],
            reasons='; '.join(reasons) or '-', tick_period_max_ms=fig['tick_period_max_ms'],
            tick_period_p99_ms=fig['tick_period_p99_ms'], watchdog_trips=watchdog,
            clients_ok=f'{ok}/{len(results)}', rounds=len(rounds),
            contact=fig['contact'])
        out['param_clients'] = fig
        out['node_crashes'] += crashed(nodes, 'follow', 'sim')
    finally:
        for c in clients:
            if c.poll() is None:
                os.killpg(c.pid, signal.SIGKILL)
                c.wait()
        live.close()
    return out


# ---- the CiA 402 path on the test bus: the driver node, the emulated drive ------------------
CANOPEN_PERIOD_S = 0.001  # the test bus does not hold 0.5 ms free-running on 2 cores
ROGUE = r"""
import random, sys, time
import can
bus = can.Bus(channel=sys.argv[1], interface='remote')
kind, seconds, period = sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
rng = random.Random(11)
end = time.monotonic() + seconds
n = 0
while time.monotonic() < end:
    if kind == 'master':   # RPDO1 of node 5: controlword enable operation, -50 mm/s
        msg = can.Message(arbitration_id=0x205, is_extended_id=False,
                          data=(0x0F).to_bytes(2, 'little') + (-50000).to_bytes(4, 'little',
                                                                                signed=True))
    else:                  # any frame: random id (11 bit), random length and bytes
        k = rng.randint(0, 8)
        msg = can.Message(arbitration_id=rng.randint(0, 0x7FF), is_extended_id=False,
                          data=bytes(rng.randint(0, 255) for _ in range(k)))
    bus.send(msg)
    n += 1
    time.sleep(period)
print(n, flush=True)
bus.shutdown()
"""


HEARTBEAT_DEVICE = (ROOT / 'ros2_ws' / 'src' / 'ladrc_cia402' / 'examples'
                    / 'servo_a_heartbeat.yaml')


def canopen_rows() -> dict:
    """Rows of the CiA 402 path: the driver node and the emulated drive on the test bus.

    Free-running at ``CANOPEN_PERIOD_S`` (controller, driver and drive), the axis following
    the 0.3 mm sine sheet at 1 mm: the driver SIGKILLed (the drive's RPDO deadline brakes the
    axis), the emulated drive SIGKILLed, the bus server killed, an EMCY following error raised
    by the drive, a second master's RPDOs (-50 mm/s) and random frames on the bus. Each row:
    contact (true gap <= 0), the time to rest where the axis survives, the follow node's fault
    and its reason, crashes of the nodes that should survive.
    """
    from ladrc_bringup.bringup import node_specs, ros_arguments
    from ladrc_msgs.msg import AxisFeedback, FollowStatus, SimTruth
    from ladrc_msgs.srv import ResetFault, StartFollow
    from ladrc_sim.cia402.bus import start_bus_server
    from rosnodes import NodeProcesses, Probe, ProbeError

    out: dict = {'canopen_node_crashes': 0, 'canopen_contacts': 0}
    domains = iter(random.sample(range(1, 102), 10))
    scenario = str(SCENARIOS / 'follow_sine.yaml')
    fault_scenario = Path(tempfile.mkdtemp(prefix='fault-canopen-')) / 'follow_sine_emcy.yaml'
    fault_scenario.write_text((SCENARIOS / 'follow_sine.yaml').read_text().replace(
        'name: follow_sine', 'name: follow_sine_emcy') + f'timeline:\n  - {{t_s: {EMCY_T_S}, '
        'do: drive, enabled: true, fault: true, error_code: 0x8611}\n', encoding='utf-8')

    def stamp_s(r) -> tuple:
        return (r[0] + r[1] * 1e-9, *r[2:])

    def one(name: str, inject, scenario_file: str = scenario, survivors=('follow', 'sim',
                                                                        'driver'),
            until_t_s: float | None = None, device: str = '') -> dict:
        os.environ['ROS_DOMAIN_ID'] = str(next(domains))
        nodes, probe, server = NodeProcesses(), Probe(f'fault_canopen_{len(ROWS)}'), None
        t_sigkill = None
        try:
            server = start_bus_server(nodes.logdir / 'bus.log')
            specs = {s.executable: s for s in node_specs(
                scenario_file, drive='cia402', bus=server.url, period_s=CANOPEN_PERIOD_S,
                device=device)}
            for exe, short in (('follow_node', 'follow'), ('driver_node', 'driver'),
                               ('sim_node', 'sim')):
                extra = ['-p', 'wait_for_controller_s:=0.0'] if exe == 'sim_node' else []
                nodes.start(short, specs[exe].package, exe, *ros_arguments(specs[exe])[1:],
                            *extra)
            status = probe.record(FollowStatus, 'follow/status',
                                  fields=['t_s', 'state', 'fault_reason', 'velocity_mm_s'])
            truth = probe.record(SimTruth, 'sim/truth', fields=[
                'header.stamp.sec', 'header.stamp.nanosec', 'true_gap_mm', 'nozzle_mm'],
                keep=stamp_s)
            fbs = probe.record(AxisFeedback, 'axis/feedback', fields=['drive_fault',
                                                                      'fault_reason'])
            if not probe.spin_until(lambda: len(status) > 200 and len(fbs) > 200, 60.0):
                raise RuntimeError(f'{name}: no follow/status or axis/feedback: '
                                   + nodes.log('driver')[-800:])
            spurious = []  # faults before the injection (a stall of this loaded machine)
            for _attempt in range(4):
                if status[-1][1] == FAULT:
                    spurious.append(status[-1][2])
                    probe.call(ResetFault, 'axis/reset_drive', ResetFault.Request())
                    probe.call(ResetFault, 'follow/reset_fault', ResetFault.Request())
                    probe.spin_for(0.5)
                res = probe.call(StartFollow, 'follow/start',
                                 StartFollow.Request(target_gap_mm=1.0))
                # following, on the moving sheet, the axis moving (|command| > 1 mm/s)
                if res.accepted and probe.spin_until(
                        lambda: status[-1][1] == FAULT or (
                            status[-1][1] == 4 and status[-1][0] > 5.0
                            and abs(status[-1][3]) > 1.0), 40.0) and status[-1][1] == 4:
                    break
            else:
                raise RuntimeError(f'{name}: not following: {status[-1]}; before: {spurious}')
            n_status, n_fb = len(status), len(fbs)
            t_inject = time.time()
            killed = inject(nodes, server)
            if killed:
                t_sigkill = time.monotonic()
            if until_t_s is not None:  # the scenario injects it at this time of the run
                if status[-1][0] >= until_t_s:
                    raise RuntimeError(f'{name}: following only at {status[-1][0]:.1f} s, '
                                       f'after the injection at {until_t_s:g} s')
                probe.spin_until(lambda: status[-1][0] >= until_t_s, 60.0)
                t_inject = time.time()  # (its status seen: the times below count from it)
            probe.spin_for(2.0)
            tr = np.asarray(truth[:], dtype=float)
            contact = bool(tr.size and (tr[:, 1] <= 0.0).any())
            after = tr[tr[:, 0] > t_inject] if tr.size else tr
            rest_ms = None
            if len(after) > 2:
                v = np.abs(np.diff(after[:, 2])) / np.maximum(np.diff(after[:, 0]), 1e-6)
                moving = np.flatnonzero(v > 0.1)
                rest_ms = float(((after[moving[-1] + 1, 0] if moving.size else after[0, 0])
                                 - t_inject) * 1e3)
            reasons = [s[2] for s in status[n_status:] if s[1] == FAULT and s[2]]
            drive_reasons = [f[1] for f in fbs[n_fb:] if f[0] and f[1]]
            crashes = 0
            for short in survivors:
                rc = nodes.procs[short].poll()
                if rc is not None and rc != 0:
                    crashes += 1
                    print(f'   {short} exited with {rc}: {nodes.log(short)[-600:]}')
            r = row(f'CiA 402: {name}', contact=contact, stop_ms=rest_ms,
                    follow_fault=reasons[0][:160] if reasons else '',
                    drive_fault=drive_reasons[0][:160] if drive_reasons else '',
                    min_true_gap_mm=float(tr[:, 1].min()) if tr.size else None,
                    crashes=crashes, spurious_faults_before=len(spurious))
            out['canopen_node_crashes'] += crashes
            out['canopen_contacts'] += int(contact)
            return r
        finally:
            try:
                if t_sigkill is not None:
                    wait = t_sigkill + SIGKILL_SETTLE_S - time.monotonic()
                    if wait > 0:
                        time.sleep(wait)
                try:
                    probe.close()
                except ProbeError as exc:
                    out['probe_crashes'] = out.get('probe_crashes', 0) + 1
                    print(f'   PROBE CRASH: {str(exc)[:800]}')
            finally:
                nodes.close()
                if server is not None:
                    server.stop()

    def rogue(server, kind: str, seconds: float, period_s: float) -> None:
        subprocess.run([sys.executable, '-c', ROGUE, server.url, kind, str(seconds),
                        str(period_s)], check=False, timeout=60, capture_output=True)

    r = one('driver SIGKILL while following',
            lambda nodes, server: nodes.kill('driver') or True, survivors=('follow', 'sim'))
    out['canopen_driver_kill_stop_ms'] = r['stop_ms']
    # a drive without an RPDO event timer: its heartbeat consumer (100 ms) stops it
    r = one('driver SIGKILL, heartbeat watchdog (examples/servo_a_heartbeat.yaml)',
            lambda nodes, server: nodes.kill('driver') or True, survivors=('follow', 'sim'),
            device=str(HEARTBEAT_DEVICE))
    out['canopen_heartbeat_kill_stop_ms'] = r['stop_ms']
    one('emulated drive SIGKILL', lambda nodes, server: nodes.kill('sim') or True,
        survivors=('follow', 'driver'))
    one('bus server SIGKILL', lambda nodes, server: os.kill(server.pid, signal.SIGKILL) or True)
    one('EMCY 0x8611 following error raised by the drive', lambda nodes, server: None,
        scenario_file=str(fault_scenario), until_t_s=EMCY_T_S)
    one('a second master: RPDO1 at -50 mm/s, 1 kHz for 1 s',
        lambda nodes, server: rogue(server, 'master', 1.0, 0.001))
    one('random frames on the bus, 2 kHz for 2 s',
        lambda nodes, server: rogue(server, 'random', 2.0, 0.0005))
    shutil.rmtree(fault_scenario.parent, ignore_errors=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--load-s', type=float, default=30.0, help='seconds of the load row')
    ap.add_argument('--clients-s', type=float, default=18.0,
                    help='seconds of the parameter clients row (rounds of 20 processes)')
    ap.add_argument('--skip-live', action='store_true', help='headless rows only')
    ap.add_argument('--only', choices=('headless', 'param-fuzz', 'cnc-fuzz', 'live', 'canopen',
                                       'linuxcnc'),
                    help='run only this part of the matrix [all]')
    a = ap.parse_args()
    rng = random.Random(7)
    t0 = time.monotonic()
    if a.only in (None, 'headless'):
        headless_rows()
    tried = accepted = crashes = 0
    if a.only in (None, 'param-fuzz'):
        tried, accepted, crashes = parameter_fuzz(rng)
    if a.only in (None, 'cnc-fuzz'):
        cnc_fuzz(rng)
    live: dict = {}
    live_error = ''
    if a.only in (None, 'live') and not a.skip_live:
        try:
            live = live_rows(a.load_s, a.clients_s)
        except (RuntimeError, AssertionError) as exc:  # a live row could not run: say which
            live_error = ' '.join(str(exc).split())[:300] or type(exc).__name__
            print(f'live rows stopped: {live_error}')
    canopen: dict = {}
    if a.only in (None, 'canopen') and not a.skip_live:
        try:
            canopen = canopen_rows()
        except (RuntimeError, AssertionError) as exc:
            live_error = (live_error + '; ' if live_error else '') + (
                'CiA 402 rows: ' + ' '.join(str(exc).split())[:300])
            print(f'CiA 402 rows stopped: {live_error}')
    linuxcnc_not_run = None
    if a.only in (None, 'linuxcnc') and not a.skip_live:
        linuxcnc_not_run = linuxcnc_rows()
    live_tried, live_accepted = live.get('live_params', (0, 0))
    summary = {
        'contacts': sum(1 for r in ROWS if r.get('contact') is True),
        'node_crashes': int(crashes + live.get('node_crashes', 0)
                            + canopen.get('canopen_node_crashes', 0)),
        'probe_crashes': live.get('probe_crashes'),  # the probe process', not a node's
        'nonfinite_commands': int(sum(r.get('nonfinite_commands', 0) for r in ROWS)),
        'invalid_params_accepted': int(accepted + live_accepted),
        'invalid_params_tried': int(tried + live_tried),
        'spurious_faults_under_load': live.get('spurious_faults_under_load'),
        'kill_stop_ms': live.get('kill_stop_ms'),
        'recorder_kill_loss_s': live.get('recorder_kill_loss_s'),
        'param_clients': live.get('param_clients'),
        'downward_after_fault_rows': [r['row'] for r in ROWS if r.get('downward_after_fault')],
        'downward_while_edge_held_rows': [r['row'] for r in ROWS
                                          if r.get('downward_while_edge_held')],
        'edge_back_rows_not_following_at_end': [
            r['row'] for r in ROWS if r['row'].endswith('then back')
            and not r.get('following_at_end')],
        'contact_rows': [r['row'] for r in ROWS if r.get('contact') is True],
        # edges where the true gap fell below 0.7 x the target (the bar), shipped set
        'edge_rows_below_0_7': [r['row'] for r in ROWS if r.get('gap_over_target', 1.0) < 0.7
                                and not r['row'].endswith((OFF_LABEL, KNOWN_LIMIT))],
        'edge_rows_known_limit': {r['row']: r['gap_over_target'] for r in ROWS
                                  if r['row'].endswith(KNOWN_LIMIT)},
        'edge_rows_below_0_7_verification_off': [
            r['row'] for r in ROWS
            if r.get('gap_over_target', 1.0) < 0.7 and r['row'].endswith(OFF_LABEL)],
        'canopen_kill_stop_ms': canopen.get('canopen_driver_kill_stop_ms'),
        'canopen_heartbeat_kill_stop_ms': canopen.get('canopen_heartbeat_kill_stop_ms'),
        'canopen_node_crashes': canopen.get('canopen_node_crashes'),
        'live_error': live_error,  # '' when every live row ran
        # the LinuxCNC rows that could not run (LinuxCNC missing; null: not asked for)
        'linuxcnc_rows_not_run': linuxcnc_not_run,
        'wall_s': round(time.monotonic() - t0, 1),
        'rows': ROWS,
    }
    print(json.dumps(summary, default=str))
    if live_error:
        sys.exit(1)


if __name__ == '__main__':
    main()
