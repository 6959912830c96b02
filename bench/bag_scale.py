"""Shift-long recording: the recorder's writer path fed a whole shift, the tools on an hour.

    scripts/in-env python bench/bag_scale.py                      # all three parts (~35 min)
    scripts/in-env python bench/bag_scale.py --part writer [--hours 4]
    scripts/in-env python bench/bag_scale.py --part tools [--tool-hours 1] [--bag DIR]
    scripts/in-env python bench/bag_scale.py --part live [--live-s 600]

Part ``writer`` (the recording issue's (a)): the contract's 2 kHz topics (capacitive height,
feedback, velocity command, follow status, sim truth: 10 000 messages per second of simulated
time, pre-serialized) go through :class:`ladrc_bags.BagWriter` exactly as the
recorder's writer thread calls it, on a simulated clock (so the 0.25 s flushes and the 5 s
``metadata.yaml`` rewrites happen per simulated second, as live). Reported: the cost of the
periodic work (flush + metadata) over the first and the last simulated minutes and their ratio
(target <= 1.5), messages written vs fed (target: all), peak RSS, bytes per hour.

Part ``tools`` ((b)): a headless run of ``--tool-hours`` (a 0.3 mm 0.5 Hz sine sheet, the
shipped controller) written as a bag (or ``--bag``), then ``ladrc replay``, ``ladrc report``,
``ladrc export`` and a what-if replay on it, each in its own process: wall time, times real
time (targets: replay >= 20x, report >= 100x) and the child's peak RSS (target <= 1 GiB).

Part ``live``: the full node set (sim, follow node, recorder; the bring-up) for ``--live-s``
seconds of a sine-sheet follow: the recorder's summary (messages written, lost by seq gap,
dropped by its queue), the 1-minute load average sampled every 10 s (what else the machine
did shows there), the bag's bytes per hour.

Last line: JSON with ``segment_close_ratio``, ``messages_lost``, ``recorder_peak_rss_mib``,
``bytes_per_hour``, ``replay_realtime_x``, ``report_realtime_x``, ``tools_peak_rss_mib`` (null
for a part not run) and each part's figures.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import resource
import shutil
import sys
import tempfile
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'ros2_ws' / 'src' / 'ladrc_tools'))
sys.path.insert(0, str(ROOT / 'ros2_ws' / 'src' / 'ladrc_bags'))
sys.path.insert(0, str(ROOT / 'ros2_ws' / 'src' / 'ladrc_bringup'))

from ladrc_bags import BagWriter, RowPacker, open_bag  # noqa: E402
from ladrc_bags import writer as bagmod  # noqa: E402 (its clock: time.monotonic)

TOPICS = {'axis/capacitive_height': 'ladrc_msgs/msg/CapacitiveHeight',
          'axis/feedback': 'ladrc_msgs/msg/AxisFeedback',
          'axis/velocity_command': 'ladrc_msgs/msg/VelocityCommand',
          'follow/status': 'ladrc_msgs/msg/FollowStatus',
          'sim/truth': 'ladrc_msgs/msg/SimTruth'}
RATE_HZ = 2000


class SimClock:
    """time.monotonic for the writer: simulated seconds."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        """Return the simulated time (s)."""
        return self.t


# The child's own peak RSS: VmHWM of its address space. (ru_maxrss is no good here: Linux
# carries the parent's peak over fork into the child's figure, and the parent held the run.)
_CHILD = ('import json, sys\n'
          'from ladrc_tools.cli import main\n'
          'rc = main(sys.argv[1:])\n'
          'hwm = [int(ln.split()[1]) for ln in open("/proc/self/status")'
          ' if ln.startswith("VmHWM:")]\n'
          'print(json.dumps({"rc": rc, "rss_kib": hwm[0] if hwm else None}), file=sys.stderr)\n')


def shift_scenario(seconds: float, start_s: float = 0.0) -> dict:
    """Return the benches' shift: follow at 1 mm over a 0.3 mm, 0.5 Hz sine sheet."""
    return {'name': 'shift', 'duration_s': seconds, 'seed': 3, 'initial_gap_mm': 3.0,
            'sensor': {'noise_std_mm': 0.005, 'quant_mm': 0.001},
            'sheet': {'profiles': [{'kind': 'sine', 'amp_mm': 0.3, 'freq_hz': 0.5}]},
            'timeline': [{'t_s': start_s, 'do': 'start_follow', 'target_gap_mm': 1.0}]}


def _tool(args: list[str]) -> dict:
    """Run ``ladrc ARGS`` in its own process; wall time and its peak RSS."""
    import subprocess

    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, '-c', _CHILD, *args], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    last = [ln for ln in p.stderr.splitlines() if ln.startswith('{"rc"')]
    info = json.loads(last[-1]) if last else {'rc': p.returncode, 'rss_kib': None}
    if not last:
        print(p.stderr[-2000:], file=sys.stderr)
    tail = [ln for ln in p.stdout.splitlines() if ln.startswith('{')]
    return {'wall_s': round(wall, 1), 'rc': info['rc'],
            'peak_rss_mib': round(info['rss_kib'] / 1024, 1) if info['rss_kib'] else None,
            'last_line': json.loads(tail[-1]) if tail else None}


def tools(hours: float, bag: str | None) -> dict:
    """Part (b): replay, report, export and what-if of a long headless bag."""
    from ladrc_bags import write_run_bag
    from ladrc_follow.control.follow import FollowController
    from ladrc_follow.control.params import ControllerParams, dump_params
    from ladrc_sim.headless.runner import run
    from ladrc_sim.headless.scenario import scenario_from_dict

    tmp = Path(tempfile.mkdtemp(prefix='bag-scale-tools-'))
    seconds = hours * 3600
    if bag is None:
        sc = scenario_from_dict(shift_scenario(seconds))
        params = ControllerParams()
        t0 = time.perf_counter()
        result = run(sc, FollowController(params), record_internals=True)
        t1 = time.perf_counter()
        bag = str(tmp / 'shift')
        write_run_bag(result, bag, dump_params(params), 'name: shift\n')
        t2 = time.perf_counter()
        del result
        print(f'bag: {seconds:.0f} s simulated in {t1 - t0:.0f} s, written in {t2 - t1:.0f} s',
              file=sys.stderr, flush=True)
    else:
        with open_bag(bag) as b:
            st = b.columns('follow/status', ['stamp_s'])['stamp_s']
        seconds = float(st[-1] - st[0]) if st.size > 1 else 0.0
    size = sum(f.stat().st_size for f in Path(bag).iterdir())
    out: dict = {'hours': round(seconds / 3600, 3), 'bag_bytes': size}
    for name, args in (('replay', ['replay', bag]),
                       ('report', ['report', bag, '-o', str(tmp / 'report'), '-q']),
                       ('export', ['export', bag, '-o', str(tmp / 'csv'), '-q']),
                       ('whatif', ['replay', bag, '--set', 'law.kp=20',
                                   '-o', str(tmp / 'whatif')])):
        r = _tool(args)
        print(f'{name}: {r["wall_s"]} s, {r["peak_rss_mib"]} MiB', file=sys.stderr, flush=True)
        row = {k: v for k, v in r.items() if k != 'last_line'}
        row['realtime_x'] = round(seconds / r['wall_s'], 1) if r['wall_s'] else None
        if name == 'replay':
            row['mismatches'] = (r['last_line'] or {}).get('mismatches')
        out[name] = row
        if name == 'export':
            out['export']['csv_bytes'] = sum(f.stat().st_size for f in (tmp / 'csv').iterdir())
            shutil.rmtree(tmp / 'csv', ignore_errors=True)
    shutil.rmtree(tmp, ignore_errors=True)
    return out


def live(seconds: float) -> dict:
    """Part live: the bring-up's node set for ``seconds`` recording a bag; its summary."""
    import os

    from ladrc_bringup.bringup import Bringup, isolated_env, node_specs
    import yaml

    tmp = Path(tempfile.mkdtemp(prefix='bag-scale-live-'))
    scenario = tmp / 'shift_live.yaml'
    scenario.write_text(yaml.safe_dump(shift_scenario(seconds, start_s=0.5)))
    bag = tmp / 'bag'
    up = Bringup(node_specs(str(scenario), None, str(bag)), isolated_env(), log_dir=tmp / 'logs')
    load = []
    t0 = time.monotonic()
    try:
        up.start()
        while up.wait('ladrc_sim', 10.0) is None:
            load.append(os.getloadavg()[0])
            if any(p.poll() is not None for n, p in up.procs.items() if n != 'ladrc_sim'):
                break
            if time.monotonic() - t0 > seconds + 120:
                break
    finally:
        codes = up.stop()
    wall = time.monotonic() - t0
    rec = json.loads((bag / 'recording.json').read_text()) if (bag / 'recording.json'
                                                               ).is_file() else {}
    size = sum(f.stat().st_size for f in bag.iterdir() if f.is_file())
    with open_bag(bag) as b:
        st = b.columns('follow/status', ['stamp_s'])['stamp_s']
    recorded_s = float(st[-1] - st[0]) if st.size > 1 else 0.0
    out = {'seconds': seconds, 'wall_s': round(wall, 1), 'exit_codes': codes,
           'messages_total': rec.get('messages_total'),
           'messages_lost': rec.get('messages_lost'),
           'messages_dropped': rec.get('messages_dropped'),
           'recorded_s': round(recorded_s, 1), 'bag_bytes': size,
           'bytes_per_hour': round(size * 3600 / recorded_s) if recorded_s else None,
           'load_avg_1min_mean': round(sum(load) / len(load), 2) if load else None,
           'load_avg_1min_max': round(max(load), 2) if load else None,
           'cpus': os.cpu_count()}
    shutil.rmtree(tmp, ignore_errors=True)
    return out


def writer(hours: float, out_dir: str | None) -> dict:
    """Part (a): the recorder's writer path fed ``hours`` of the contract at full rate."""
    tmp = None if out_dir else Path(tempfile.mkdtemp(prefix='bag-scale-'))
    path = Path(out_dir) if out_dir else tmp / 'shift'
    # one second of each topic, pre-serialized (a varying seq would not change the cost)
    rows = {}
    for t, m in TOPICS.items():
        packer = RowPacker(m)
        counter = 'tick' if 'tick' in packer.fields else 'seq'
        rows[t] = packer.pack(RATE_HZ, {counter: np.arange(RATE_HZ)})
    clock = SimClock()
    real_monotonic = bagmod.time.monotonic
    bagmod.time.monotonic = clock  # the writer's flush and metadata schedule: simulated time
    periodic: list[tuple[float, float]] = []  # (simulated s, wall s of the periodic work)
    w = BagWriter(path)
    orig_poll = w.poll

    def timed_poll() -> None:
        t0 = time.perf_counter()
        orig_poll()
        dt = time.perf_counter() - t0
        if dt > 2e-5:  # a flush or a metadata rewrite happened
            periodic.append((clock.t, dt))

    w.poll = timed_poll
    seconds = int(round(hours * 3600))
    fed = 0
    wall0 = time.perf_counter()
    write = w.write_raw
    names = list(TOPICS)
    for s in range(seconds):
        base_ns = s * 1_000_000_000
        for i in range(RATE_HZ):
            clock.t = s + i / RATE_HZ
            ts = base_ns + i * 500_000
            for t in names:
                write(t, ts, rows[t][i])
        fed += RATE_HZ * len(names)
        if s % 600 == 599:
            print(f'{(s + 1) / 3600:.2f} h simulated, {time.perf_counter() - wall0:.0f} s wall',
                  file=sys.stderr, flush=True)
    w.close()
    wall = time.perf_counter() - wall0
    bagmod.time.monotonic = real_monotonic
    size = sum(f.stat().st_size for f in path.iterdir())
    with open_bag(path) as b:
        read_back = sum(b.message_counts.values())
    per = np.array(periodic) if periodic else np.zeros((0, 2))
    first = per[per[:, 0] < 60.0, 1] if per.size else np.zeros(0)
    last = per[per[:, 0] >= seconds - 60.0, 1] if per.size else np.zeros(0)
    start_ms = float(first.mean() * 1e3) if first.size else float('nan')
    end_ms = float(last.mean() * 1e3) if last.size else float('nan')
    out = {
        'hours_simulated': hours, 'messages_fed': fed, 'messages_written': read_back,
        'messages_lost': fed - read_back, 'wall_s': round(wall, 1),
        'realtime_x': round(seconds / wall, 1) if wall else None,
        'periodic_ms_start': round(start_ms, 3), 'periodic_ms_end': round(end_ms, 3),
        'periodic_end_over_start': round(end_ms / start_ms, 3) if start_ms else None,
        'periodic_ms_max': round(float(per[:, 1].max() * 1e3), 3) if per.size else None,
        'bytes': size, 'bytes_per_hour': round(size / hours) if hours else None,
        'peak_rss_mib': round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }
    if tmp is not None:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--part', choices=('all', 'writer', 'tools', 'live'), default='all')
    ap.add_argument('--hours', type=float, default=4.0, help='writer: simulated length')
    ap.add_argument('--out', default=None, help='writer: bag folder (default: temporary)')
    ap.add_argument('--tool-hours', type=float, default=1.0, help='tools: bag length')
    ap.add_argument('--bag', default=None, help='tools: use this bag instead')
    ap.add_argument('--live-s', type=float, default=600.0, help='live: run length [s]')
    a = ap.parse_args()
    parts = ('writer', 'tools', 'live') if a.part == 'all' else (a.part,)
    res: dict = {}
    # the writer part first: its peak RSS (ru_maxrss of this process) is its own
    if 'writer' in parts:
        res['writer'] = writer(a.hours, a.out)
        print(json.dumps({'writer': res['writer']}), flush=True)
    if 'tools' in parts:
        res['tools'] = tools(a.tool_hours, a.bag)
        print(json.dumps({'tools': res['tools']}), flush=True)
    if 'live' in parts:
        res['live'] = live(a.live_s)
        print(json.dumps({'live': res['live']}), flush=True)
    w, t, lv = res.get('writer'), res.get('tools'), res.get('live')
    lost = [x for x in ((w or {}).get('messages_lost'), (lv or {}).get('messages_lost'),
                        (lv or {}).get('messages_dropped')) if x is not None]
    rss = [t[k]['peak_rss_mib'] for k in ('replay', 'report', 'export', 'whatif')
           if t and t[k]['peak_rss_mib'] is not None]
    print(json.dumps({
        'segment_close_ratio': w['periodic_end_over_start'] if w else None,
        'messages_lost': sum(lost) if lost else None,
        'recorder_peak_rss_mib': w['peak_rss_mib'] if w else None,
        'bytes_per_hour': w['bytes_per_hour'] if w else None,
        'live_bytes_per_hour': lv['bytes_per_hour'] if lv else None,
        'replay_realtime_x': t['replay']['realtime_x'] if t else None,
        'report_realtime_x': t['report']['realtime_x'] if t else None,
        'export_realtime_x': t['export']['realtime_x'] if t else None,
        'whatif_realtime_x': t['whatif']['realtime_x'] if t else None,
        'tools_peak_rss_mib': max(rss) if rss else None,
        **res}))


if __name__ == '__main__':
    main()
