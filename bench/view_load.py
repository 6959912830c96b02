"""The live view's cost to the loop: the showcase live with and without ``--view``, alternating.

    scripts/in-env python bench/view_load.py [--rounds 2] [--seconds S] [--port 8765]
                                             [--domain-id N]

Per round, two runs of the bring-up's node set (sim node, follow node, recorder; free-running,
the default ``deadline`` loop, the product's defaults), one without the view and one with it
(``view_node`` as bring-up's ``--view`` starts it, and a WebSocket client speaking the Foxglove
protocol subscribed to every channel, as the Foxglove app would): ``showcase`` (about 30 s), or
with ``--seconds S`` bench/loop_timing.py's scenario of S seconds after its approach (the tiny
size of tests/test_benches.py). Order: without, with, without, with, ... so that a drift of the
machine hits both alike.

Loop figures per run from its bag, as bench/loop_timing.py computes them (``figures``: from the
end of the approach to the sim's last sample): ``rate_hz`` (ticks per second of the
controller's clock), ``period_p99_us``, ``period_max_us``, ``fault_ticks``,
``watchdog_trips``; and ``load_1min`` (the machine's 1-minute load average at the run's end,
the node set's own threads included: other work on the machine shows there). View figures
(runs with the view): ``status_received`` (status messages the client received),
``status_rate_hz`` (received per second of the run), ``status_ticks`` (status messages in the
bag), ``view_cpu_pct`` (the view process' CPU time over the run's wall time, in % of one core),
``fault_reasons`` (distinct non-empty reasons in the bag), ``fault_reasons_received`` (of
those, received on ``/follow/status``), ``events_received`` / ``events`` (the bag's).

Last line: one JSON object with ``rounds``, ``scenario``, ``runs`` (every run's figures, in
order), ``without_view`` and ``with_view`` (per figure: the runs' values), and the summary
``rate_hz_without`` / ``rate_hz_with`` and ``period_p99_us_without`` / ``period_p99_us_with``
(means over the runs), ``status_rate_hz`` and ``view_cpu_pct`` (means),
``all_fault_reasons_received`` (bool, every run with the view).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import random
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'bench'))
sys.path.insert(0, str(ROOT / 'tests' / 'support'))

LOOP_FIGURES = ('rate_hz', 'period_p99_us', 'period_max_us', 'ticks', 'fault_ticks',
                'watchdog_trips')


def run(folder: Path, scenario: str, view_port: int | None, domain_id: int) -> dict:
    """One run of the node set (+ the view and a client when ``view_port``); its figures."""
    from foxglove_client import FoxgloveClient
    from ladrc_bags import open_bag
    from ladrc_bringup.bringup import Bringup, isolated_env, node_specs, view_spec
    from loop_timing import figures

    folder.mkdir(parents=True, exist_ok=True)
    bag = folder / 'bag'
    specs = node_specs(scenario, bag=str(bag))
    if view_port is not None:
        specs.insert(0, view_spec(view_port))
    logs = folder / 'logs'
    up = Bringup(specs, isolated_env(domain_id), logs)
    client = None
    try:
        up.start()
        if view_port is not None:
            client = FoxgloveClient(f'ws://127.0.0.1:{view_port}', connect_timeout_s=60.0)
        t0 = time.monotonic()
        if up.wait('ladrc_sim', 600.0) is None:
            raise RuntimeError('the sim node did not finish')
        time.sleep(0.5)  # the view's last intervals
        cpu_s = _cpu_s(up.procs['ladrc_view'].pid) if view_port is not None else None
        wall_s = time.monotonic() - t0
    finally:
        up.stop()
        if client is not None:
            client.close()
    out = {'view': view_port is not None, 'load_1min': os.getloadavg()[0],
           **{k: v for k, v in figures(bag, {p.stem: p.read_text(errors='replace')
                                             for p in logs.glob('*.log')}).items()
              if k in LOOP_FIGURES}}
    if client is None:
        return out
    with open_bag(bag) as b:
        st = b.columns('follow/status', ['fault_reason', 't_s'])
        n_events = b.columns('follow/events', ['tick'])['tick'].size
    status = client.messages.get('/follow/status', [])
    reasons = sorted({r for r in st['fault_reason'].tolist() if r})
    got = {m.data['fault_reason'] for m in status}
    span_s = float(st['t_s'][-1] - st['t_s'][0]) if st['t_s'].size > 1 else float('nan')
    out.update({
        'view_cpu_pct': 100.0 * cpu_s / wall_s,
        'status_received': len(status), 'status_ticks': int(st['t_s'].size),
        'status_rate_hz': len(status) / span_s if span_s > 0 else 0.0,
        'fault_reasons': reasons,
        'fault_reasons_received': [r for r in reasons if r in got],
        'events': int(n_events),
        'events_received': len(client.messages.get('/follow/events', [])),
    })
    return out


def _cpu_s(pid: int) -> float:
    """CPU time (user + system) of a process so far [s], from /proc."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _mean(values: list) -> float | None:
    vals = [float(v) for v in values if v is not None]
    return sum(vals) / len(vals) if vals else None


def main() -> int:
    """Alternate the runs; print the figures, last line JSON."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--rounds', type=int, default=2, help='rounds of (without, with) [2]')
    ap.add_argument('--seconds', type=float, default=None,
                    help="bench/loop_timing.py's scenario of this many seconds instead of the "
                    'showcase (the smoke test)')
    ap.add_argument('--port', type=int, default=8765, help="the view's port [8765]")
    ap.add_argument('--domain-id', type=int, default=None,
                    help='ROS_DOMAIN_ID of the node sets [random 1..101]')
    args = ap.parse_args()
    os.environ.setdefault('PYTHONUNBUFFERED', '1')
    from ladrc_bringup.bringup import port_in_use

    busy = port_in_use(args.port)
    if busy:
        print(f'view_load: --port: cannot listen on {busy}', file=sys.stderr)
        return 2
    runs: list[dict] = []
    with tempfile.TemporaryDirectory(prefix='view_load_') as tmp:
        scenario = 'showcase'
        if args.seconds is not None:
            from loop_timing import SCENARIO, WARMUP_S

            scenario = str(Path(tmp) / 'view_load.yaml')
            Path(scenario).write_text(SCENARIO.format(duration=WARMUP_S + args.seconds))
        for r in range(args.rounds):
            for with_view in (False, True):
                folder = Path(tmp) / f'{r}_{"with" if with_view else "without"}'
                folder.mkdir()
                domain = args.domain_id or random.randint(1, 101)
                for attempt in range(3):
                    try:
                        fig = run(folder / str(attempt), scenario,
                                  args.port if with_view else None, domain)
                        break
                    except FileNotFoundError as exc:  # a rebuild of the shared workspace
                        if attempt == 2:
                            raise
                        print(f'view_load: {exc}; again in 30 s', file=sys.stderr)
                        time.sleep(30.0)
                runs.append(fig)
                print(f'round {r + 1}, {"with" if with_view else "without"} the view: {fig}',
                      file=sys.stderr)
    groups = {k: [x for x in runs if x['view'] is v] for k, v in
              (('without_view', False), ('with_view', True))}
    per = {k: {f: [x.get(f) for x in g] for f in LOOP_FIGURES + (
        ('status_received', 'status_rate_hz', 'view_cpu_pct') if k == 'with_view' else ())}
        for k, g in groups.items()}
    out = {'rounds': args.rounds, 'scenario': 'showcase' if args.seconds is None
           else f'loop_timing {args.seconds:g} s', 'runs': runs, **per,
           'rate_hz_without': _mean(per['without_view']['rate_hz']),
           'rate_hz_with': _mean(per['with_view']['rate_hz']),
           'period_p99_us_without': _mean(per['without_view']['period_p99_us']),
           'period_p99_us_with': _mean(per['with_view']['period_p99_us']),
           'status_rate_hz': _mean(per['with_view']['status_rate_hz']),
           'view_cpu_pct': _mean(per['with_view']['view_cpu_pct']),
           'all_fault_reasons_received': all(
               x['fault_reasons_received'] == x['fault_reasons'] for x in groups['with_view'])}
    print(json.dumps(out))
    return 0


if __name__ == '__main__':
    sys.exit(main())
