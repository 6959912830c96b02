"""Shift-long recording: the recorder's writer path fed a whole shift, and the tools on it.

    scripts/in-env python bench/bag_scale.py [--hours 4] [--out DIR]           # part (a)
    scripts/in-env python bench/bag_scale.py --tools [--tool-hours 1] [--bag DIR]  # part (b)

Part (a) of the recording issue: the contract's 2 kHz topics (capacitive height, feedback,
velocity command, follow status, sim truth: 10 000 messages per second of simulated time,
pre-serialized) go through :class:`ladrc_tools.bags.bag.BagWriter` exactly as the recorder's
writer thread calls it, on a simulated clock (so the 0.25 s flushes and the 5 s
``metadata.yaml`` rewrites happen per simulated second, as live). Reported: the cost of the
periodic work (flush + metadata) over the first and the last simulated minutes and their ratio
(target <= 1.5), messages written vs fed (target: all), peak RSS, bytes per hour, and the
bag read back (message count).

Part (b) (``--tools``): a headless run of ``--tool-hours`` (a 0.3 mm 0.5 Hz sine sheet, the
shipped controller) written as a bag (or ``--bag``), then ``ladrc replay`` and
``ladrc report`` on it, each in its own process: wall time, times real time (targets: replay
>= 20x, report >= 100x) and peak RSS (target <= 1 GiB). Last line: JSON.
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

from ladrc_tools.bags import bag as bagmod  # noqa: E402
from ladrc_tools.bags.bag import BagWriter, RowPacker, open_bag  # noqa: E402

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


def tools(hours: float, bag: str | None) -> None:
    """Part (b): replay and report of a long headless bag."""
    from ladrc_follow.control.follow import FollowController
    from ladrc_follow.control.params import ControllerParams, dump_params
    from ladrc_sim.headless.runner import run
    from ladrc_sim.headless.scenario import scenario_from_dict
    from ladrc_tools.bags.bag import write_run_bag

    tmp = Path(tempfile.mkdtemp(prefix='bag-scale-tools-'))
    seconds = hours * 3600
    if bag is None:
        sc = scenario_from_dict({
            'name': 'shift', 'duration_s': seconds, 'seed': 3, 'initial_gap_mm': 3.0,
            'sensor': {'noise_std_mm': 0.005, 'quant_mm': 0.001},
            'sheet': {'profiles': [{'kind': 'sine', 'amp_mm': 0.3, 'freq_hz': 0.5}]},
            'timeline': [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}]})
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
    size = sum(f.stat().st_size for f in Path(bag).iterdir())
    replay = _tool(['replay', bag])
    report = _tool(['report', bag, '-o', str(tmp / 'report'), '-q'])
    out = {'hours': hours, 'bag_bytes': size,
           'replay': {**{k: v for k, v in replay.items() if k != 'last_line'},
                      'realtime_x': round(seconds / replay['wall_s'], 1),
                      'mismatches': (replay['last_line'] or {}).get('mismatches')},
           'report': {**{k: v for k, v in report.items() if k != 'last_line'},
                      'realtime_x': round(seconds / report['wall_s'], 1)}}
    shutil.rmtree(tmp, ignore_errors=True)
    print(json.dumps(out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--hours', type=float, default=4.0, help='simulated recording length')
    ap.add_argument('--out', default=None, help='bag folder (default: a temporary one)')
    ap.add_argument('--tools', action='store_true', help='part (b): replay and report')
    ap.add_argument('--tool-hours', type=float, default=1.0, help='part (b) bag length')
    ap.add_argument('--bag', default=None, help='part (b): use this bag instead')
    a = ap.parse_args()
    if a.tools:
        tools(a.tool_hours, a.bag)
        return
    tmp = None if a.out else Path(tempfile.mkdtemp(prefix='bag-scale-'))
    path = Path(a.out) if a.out else tmp / 'shift'
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
    seconds = int(round(a.hours * 3600))
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
        'hours_simulated': a.hours, 'messages_fed': fed, 'messages_written': read_back,
        'messages_lost': fed - read_back, 'wall_s': round(wall, 1),
        'realtime_x': round(seconds / wall, 1) if wall else None,
        'periodic_ms_start': round(start_ms, 3), 'periodic_ms_end': round(end_ms, 3),
        'periodic_end_over_start': round(end_ms / start_ms, 3) if start_ms else None,
        'periodic_ms_max': round(float(per[:, 1].max() * 1e3), 3) if per.size else None,
        'bytes': size, 'bytes_per_hour': round(size / a.hours) if a.hours else None,
        'peak_rss_mib': round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }
    if tmp is not None:
        shutil.rmtree(tmp, ignore_errors=True)
    print(json.dumps(out))


if __name__ == '__main__':
    main()
