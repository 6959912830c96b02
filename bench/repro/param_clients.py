"""Fault-matrix row: 20 parameter clients (20 processes) appear and vanish while the axis follows.

    scripts/in-env python bench/repro/param_clients.py [--checkout /work/main] [--clients 20]
                         [--rounds 3] [--duration 30] [--loop sync] [--set law.kp] [--out DIR]

With the checkout's code (default: the current one, /work/main), the bring-up
(``scripts/in-env bringup --scenario FLAT --bag B --logs L --domain-id D --loop LOOP``: sim,
follow node, recorder; the product's defaults: 10 ms stale limit, 5 ms drive watchdog,
SCHED_FIFO where granted) follows a flat sheet at 1 mm (approach from 3 mm, ``start_follow``
at 0.5 s). Once the sim plays (3 s after), rounds of ``--clients`` separate processes start
at once, each an rclpy node with a client of ``/ladrc_follow/get_parameters`` that waits for
the service, calls GetParameters once (``law.kp``), and exits (its node, and its DDS
participant, vanish); the next round starts 1 s after the last one ended, while the
scenario has more than 4 s to run. ``--set NAME``: after the rounds, one more process calls
SetParameters once (NAME x 1.0, a valid set: the stability gate runs on the loop thread).
``--env KEY=VALUE``: set in the nodes' and clients' environment (a candidate fix).

Reported, from the bag's ``follow/status`` over the sim's run (the end, when the sim exits and
the controller sees stale input, left out): any FAULT and its reason, the tick period max
(``period_us``) during and outside the rounds; the sim's drive watchdog trips (``watchdog:``
lines of its log); from the in-process trace (bench/repro/_trace.py): the follow node's late
ticks and the sim's command gaps with their time relative to the rounds, collections, what
SCHED_FIFO was granted; the clients' own timings (start, service ready, answered).

Last stdout line: JSON with the figures.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
import random
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _trace as tr  # noqa: E402

FLAT = """name: param_clients_flat
description: bench/repro/param_clients.py - approach from 3 mm, follow at 1 mm, flat sheet.
duration_s: {duration}
seed: 3
initial_gap_mm: 3.0
sensor: {{noise_std_mm: 0.003, quant_mm: 0.001}}
timeline:
  - {{t_s: 0.5, do: start_follow, target_gap_mm: 1.0}}
"""

CLIENT = r"""
import json, sys, time
t0 = time.monotonic()
import rclpy
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
mode, name = sys.argv[1], sys.argv[2]
rclpy.init()
node = rclpy.create_node('param_client_%d' % __import__('os').getpid())
t_node = time.monotonic()
out = {'t_start': t0, 't_node': t_node}
if mode == 'get':
    cli = node.create_client(GetParameters, '/ladrc_follow/get_parameters')
    req = GetParameters.Request(names=[name])
else:
    cli = node.create_client(GetParameters, '/ladrc_follow/get_parameters')
    cli.wait_for_service(timeout_sec=10.0)
    f = cli.call_async(GetParameters.Request(names=[name]))
    rclpy.spin_until_future_complete(node, f, timeout_sec=10.0)
    value = f.result().values[0].double_value
    cli = node.create_client(SetParameters, '/ladrc_follow/set_parameters')
    req = SetParameters.Request(parameters=[Parameter(name=name, value=ParameterValue(
        type=ParameterType.PARAMETER_DOUBLE, double_value=value * 1.0))])
ok = cli.wait_for_service(timeout_sec=10.0)
out['t_ready'] = time.monotonic()
if ok:
    f = cli.call_async(req)
    rclpy.spin_until_future_complete(node, f, timeout_sec=10.0)
    out['answered'] = f.done() and f.result() is not None
    if out['answered'] and mode == 'get':
        out['value'] = f.result().values[0].double_value
    elif out['answered']:
        out['successful'] = f.result().results[0].successful
else:
    out['answered'] = False
out['t_done'] = time.monotonic()
node.destroy_node()
rclpy.try_shutdown()
out['t_exit'] = time.monotonic()
print(json.dumps(out))
"""


LAUNCH = """
import os, sys
from pathlib import Path
from ladrc_tools.bringup.bringup import Bringup, isolated_env, node_specs
scenario, bag, logs, domain, loop = sys.argv[1:6]
env = isolated_env(int(domain))
env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = os.environ['REPRO_DISCOVERY_RANGE']
up = Bringup(node_specs(scenario, bag=bag, loop=loop), env, Path(logs))
try:
    up.start()
    up.wait('ladrc_sim', 600)
finally:
    print(up.stop())
"""


def checkout_env(checkout: Path) -> dict[str, str]:
    """Return the environment of ``checkout``'s ``scripts/in-env`` (one call)."""
    out = subprocess.run(tr.in_env(checkout, 'python', '-c',
                                   'import json, os; print(json.dumps(dict(os.environ)))'),
                         cwd=checkout, env=tr.clean_env(), capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def run_round(python: str, script: Path, env: dict[str, str], n: int, mode: str,
              name: str) -> list[dict]:
    """Start ``n`` client processes at once; wait for all; return their timings."""
    procs = [subprocess.Popen([python, str(script), mode, name], env=env, cwd=script.parent,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              start_new_session=True) for _ in range(n)]
    results = []
    for p in procs:
        try:
            out, err = p.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, 9)
            out, err = p.communicate()
        try:
            results.append(json.loads(out.strip().splitlines()[-1]))
        except (IndexError, json.JSONDecodeError):
            results.append({'error': (err or '').strip().splitlines()[-1:]})
    return results


def main() -> int:
    """Bring up, run the rounds, read the bag; last line JSON."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--checkout', type=Path, default=Path('/work/main'))
    ap.add_argument('--clients', type=int, default=20)
    ap.add_argument('--rounds', type=int, default=3, help='at most this many rounds [3]')
    ap.add_argument('--duration', type=float, default=30.0, help='scenario seconds [30]')
    ap.add_argument('--loop', default='sync', help='follow loop: sync|deadline|timer [sync]')
    ap.add_argument('--set', default='', help='then one SetParameters of this parameter')
    ap.add_argument('--env', action='append', default=[], metavar='KEY=VALUE',
                    help='set in the environment of the nodes and the clients (a candidate '
                    'fix, e.g. FASTDDS_BUILTIN_TRANSPORTS=UDPv4); repeatable')
    ap.add_argument('--udp-only', action='store_true',
                    help='candidate fix: Fast DDS UDPv4 only, no shared memory (the nodes are '
                    'started through Bringup/node_specs with FASTDDS_BUILTIN_TRANSPORTS=UDPv4; '
                    'rmw_fastrtps ignores it under localhost discovery, so discovery is the '
                    'subnet one on a domain of 200..230)')
    ap.add_argument('--out', type=Path, default=None, help='keep the run here [temp]')
    args = ap.parse_args()
    extra = dict(kv.split('=', 1) for kv in args.env)
    if args.udp_only:
        extra.update({'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4', 'REPRO_DISCOVERY_RANGE': 'SUBNET'})
    tr.become_subreaper()
    checkout = args.checkout.resolve()
    folder = args.out or Path(tempfile.mkdtemp(prefix='repro_param_clients_'))
    folder.mkdir(parents=True, exist_ok=True)
    scenario = folder / 'flat.yaml'
    scenario.write_text(FLAT.format(duration=args.duration))
    script = folder / 'param_client.py'
    script.write_text(CLIENT)
    domain = random.randint(200, 230) if args.udp_only else random.randint(1, 101)
    cenv = checkout_env(checkout)
    cenv.update({'ROS_DOMAIN_ID': str(domain), 'PYTHONUNBUFFERED': '1',
                 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET' if args.udp_only else 'LOCALHOST'})
    cenv.pop('LADRC_TRACE_DIR', None)
    cenv.update(extra)
    python = str(checkout / '.venv' / 'bin' / 'python')
    env = tr.trace_env(folder, **extra)
    mon = tr.Monitor()
    machine = tr.machine_state()
    rounds: list[dict] = []
    mon.start()
    logs = folder / 'logs'
    log_path = folder / 'bringup.log'
    if args.udp_only:
        cmd = tr.in_env(checkout, 'python', '-c', LAUNCH, str(scenario), str(folder / 'bag'),
                        str(logs), str(domain), args.loop)
    else:
        cmd = tr.in_env(checkout, 'bringup', '--scenario', str(scenario), '--bag',
                        str(folder / 'bag'), '--logs', str(logs), '--domain-id', str(domain),
                        '--loop', args.loop, '--timeout', str(args.duration + 90))
    proc = subprocess.Popen(
        cmd,
        cwd=checkout, env=env, stdout=open(log_path, 'wb'), stderr=subprocess.STDOUT,  # noqa: SIM115
        stdin=subprocess.DEVNULL, start_new_session=True)
    try:
        # the sim plays from its 'scenario ...' log line on
        t_play = None
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            sim_log = logs / 'ladrc_sim.log'
            if sim_log.is_file() and '[ladrc_sim]: scenario' in sim_log.read_text(
                    errors='replace'):
                t_play = time.monotonic()
                break
            time.sleep(0.05)
        if t_play is None:
            raise RuntimeError(f'the sim never started playing: {log_path.read_text()[-500:]}')
        time.sleep(max(0.0, t_play + 3.0 - time.monotonic()))
        for k in range(args.rounds):
            if time.monotonic() > t_play + args.duration - 4.0:
                break
            t0 = time.monotonic()
            res = run_round(python, script, cenv, args.clients, 'get', 'law.kp')
            rounds.append({'round': k, 't_start': t0, 't_end': time.monotonic(), 'mode': 'get',
                           'clients': res})
            print(f'round {k}: {len(res)} clients in {time.monotonic() - t0:.1f} s, answered '
                  f"{sum(bool(r.get('answered')) for r in res)}", file=sys.stderr)
            time.sleep(1.0)
        if args.set and time.monotonic() < t_play + args.duration - 3.0:
            t0 = time.monotonic()
            res = run_round(python, script, cenv, 1, 'set', args.set)
            rounds.append({'round': len(rounds), 't_start': t0, 't_end': time.monotonic(),
                           'mode': f'set {args.set}', 'clients': res})
            print(f'set {args.set}: {res}', file=sys.stderr)
        proc.wait(timeout=args.duration + 150)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, 2)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, 9)
                proc.wait()
        mon.stop()
        left = tr.end_descendants()
    events = tr.read_traces(folder)
    summary = tr.summarize(events)
    follow = summary.get('follow', {})
    sim_log = (logs / 'ladrc_sim.log').read_text(errors='replace') if (
        logs / 'ladrc_sim.log').is_file() else ''
    watchdog = [ln for ln in sim_log.splitlines() if 'watchdog:' in ln]

    def in_round(t: float) -> int | None:
        for r in rounds:
            if r['t_start'] <= t <= r['t_end'] + 0.5:
                return r['round']
        return None
    late = [(round(e['t'] - rounds[0]['t_start'], 3) if rounds else e['t'], e['period_ms'],
             in_round(e['t'])) for e in events if e['kind'] == 'follow_late_tick']
    gaps = [(round(e['t'] - rounds[0]['t_start'], 3) if rounds else e['t'], e['ms'],
             in_round(e['t']), e['seq_before'], e['seq']) for e in events
            if e['kind'] == 'sim_command_gap']
    figs = bag_figures(folder / 'bag', rounds)
    client_ready = [r['t_ready'] - r['t_start'] for rd in rounds for r in rd['clients']
                    if 't_ready' in r]
    out = {
        'checkout': str(checkout), 'loop': args.loop, 'clients_per_round': args.clients,
        'env': extra, 'udp_only': args.udp_only,
        'rounds': len(rounds), 'machine': machine,
        'clients_answered': sum(bool(r.get('answered')) for rd in rounds for r in rd['clients']),
        'clients_total': sum(len(rd['clients']) for rd in rounds),
        'client_start_to_service_ready_s_max': max(client_ready, default=math.nan),
        'round_durations_s': [round(r['t_end'] - r['t_start'], 2) for r in rounds],
        'watchdog_trips': len(watchdog), 'watchdog_lines': watchdog[:5], **figs,
        'trace_fault_reasons': [s[2] for s in follow.get('follow_states', [])
                                if s[1] == 'FAULT'],
        'follow_late_ticks_t_ms_round': late[:40],
        'sim_command_gaps_t_ms_round_seqs': gaps[:40],
        'follow_long_callbacks': follow.get('follow_long_callback'),
        'follow_set_parameters_ms': follow.get('follow_set_parameters_ms'),
        'gc_long': {p: s.get('gc') for p, s in summary.items()
                    if s.get('gc') and p in ('follow', 'sim', 'recorder')},
        'realtime': {p: s.get('realtime') for p, s in summary.items() if s.get('realtime')},
        'monitor_waits_over_2ms': len(mon.windows),
        'fastdds_shm_mappings': mon.shm_mappings,
        'foreign_rt_processes_seconds': mon.foreign_rt,
        'left_over_processes': left, 'output': str(folder),
        # what the follow node's loop thread was blocked in during its long ticks
        'follow_long_ticks_blocked_in': tr.blocked_in(mon, events)[:10],
    }
    print(json.dumps(out, default=str))
    return 0


def bag_figures(bag: Path, rounds: list[dict]) -> dict:
    """FAULTs, tick period max during and outside the rounds (follow/status of the bag)."""
    from ladrc_tools.bags.bag import open_bag

    with open_bag(bag) as b:
        st = b.columns('follow/status', ['tick', 't_s', 'state', 'period_us', 'fault_reason',
                                         'header.stamp.sec', 'header.stamp.nanosec'])
        truth = b.columns('sim/truth', ['header.stamp.sec', 'header.stamp.nanosec'])
    stamp = st['header.stamp.sec'] + st['header.stamp.nanosec'] * 1e-9
    t_truth = truth['header.stamp.sec'] + truth['header.stamp.nanosec'] * 1e-9
    keep = (stamp >= t_truth[0]) & (stamp <= t_truth[-1] - 0.005)
    state = st['state'][keep].astype(int)
    reasons = [str(st['fault_reason'][keep][i]) for i in range(state.size)
               if state[i] == 5 and (i == 0 or state[i - 1] != 5)]
    period = st['period_us'][keep] * 1e-3
    # the rounds on the bag's clock: monotonic -> wall through the offset now
    off = time.time() - time.monotonic()
    during = np.zeros(period.size, bool)
    s = stamp[keep]
    for r in rounds:
        during |= (s >= r['t_start'] + off) & (s <= r['t_end'] + off + 0.5)
    ticks = st['tick'][keep].astype(np.int64)
    return {
        'fault_during_run': bool(reasons), 'fault_reasons': reasons,
        'states_seen': sorted({int(x) for x in state}),
        'tick_period_max_ms': float(period[1:].max()) if period.size > 1 else math.nan,
        'tick_period_max_during_rounds_ms': float(period[during].max()) if during.any()
        else math.nan,
        'tick_period_max_outside_rounds_ms': float(period[~during][1:].max())
        if (~during).sum() > 1 else math.nan,
        'periods_over_5ms_during_rounds': int((period[during] > 5).sum()),
        'status_in_bag': int(state.size),
        'status_lost_by_recorder': int(ticks[-1] - ticks[0] + 1 - ticks.size) if ticks.size
        else None,
    }


if __name__ == '__main__':
    sys.exit(main())
