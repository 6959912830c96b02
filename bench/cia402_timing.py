"""The CiA 402 path's timing on the test bus: cycles held, SYNC jitter, latency, frames/s.

    scripts/in-env python bench/cia402_timing.py [--duration 30] [--periods-ms 1,0.5]
                                                 [--domain-id N]

Per SYNC period: ``bringup --drive cia402`` free-running (python-can-remote on 127.0.0.1, the
emulated CiA 402 drive in the sim node, the CiA 402 driver node, the follow node with ``h_s`` =
the period, the recorder), the controller following at 1 mm over a 0.3 mm 1 Hz sine sheet for
``--duration`` seconds after a 3 s approach. From the bag:

* ``held``: the share of SYNC periods of the run that brought a sample pair to the controller
  (feedback samples / (run time / period)); ``late_tpdo_cycles`` and ``missed_tpdo_cycles``:
  the driver's own counts (TPDOs after its wait but before the next SYNC; never);
* ``sync_jitter_p99_us``: p99 of |SYNC interval - period| (the samples' stamps are the SYNC
  times);
* ``latency_p99_ms``: sensor -> command, the sample's SYNC time to the first command answering
  it (its stamp, when the controller computed it; a tick without a new sample answers the old
  one again, which is not that sample's latency); ``latency_received_p99_ms``: to the
  recorder's reception of that command (what the driver also waits for);
* ``frames_per_s``: RPDO + SYNC + two TPDOs per cycle (heartbeats and EMCYs aside), and the
  bus load of those frames at 1 Mbit/s (``bus_load_1mbit``: bits with worst-case stuffing);
* ``contacts``, ``faults`` (FAULT entries of the controller) and ``ran_to_end``.

Last line: one JSON object, the first period's figures at top level (``period_ms``,
``held``, ``sync_jitter_p99_us``, ``latency_p99_ms``, ``frames_per_s``, ``contacts``), every
period under ``runs``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import random
import subprocess
import sys
import tempfile

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BIN = ROOT / 'ros2_ws' / 'install' / 'ladrc_bringup' / 'lib' / 'ladrc_bringup'

SCENARIO = """name: cia402_timing
description: bench/cia402_timing.py - approach from 3 mm, follow at 1 mm over a 0.3 mm 1 Hz sine.
duration_s: {duration}
seed: 3
initial_gap_mm: 3.0
sensor: {{noise_std_mm: 0.003, quant_mm: 0.001}}
sheet:
  profiles:
    - {{kind: sine, amp_mm: 0.3, freq_hz: 1.0, t_start_s: 2.0}}
timeline:
  - {{t_s: 0.0, do: start_follow, target_gap_mm: 1.0}}
"""

# CAN 2.0A frame bits: SOF 1 + id 11 + RTR 1 + IDE 1 + r0 1 + DLC 4 + data + CRC 15 + CRC del 1
# + ACK 2 + EOF 7 + IFS 3 = 47 + 8n; bit stuffing adds at most (34 + 8n - 1) / 4 bits
FRAME_BYTES = (0, 6, 6, 6)  # SYNC, RPDO1 (controlword + target), TPDO1, TPDO2


def frame_bits(n: int) -> float:
    """Bits of a standard frame with ``n`` data bytes, worst-case stuffing."""
    return 47 + 8 * n + (34 + 8 * n - 1) // 4


def stamps_s(cols: dict) -> np.ndarray:
    return cols['header.stamp.sec'].astype(float) + cols['header.stamp.nanosec'] * 1e-9


def one(period_ms: float, duration: float, folder: Path, domain: int) -> dict:
    from ladrc_bags import open_bag

    scenario = folder / f'timing_{period_ms:g}.yaml'
    scenario.write_text(SCENARIO.format(duration=duration + 3.0), encoding='utf-8')
    bag = folder / f'bag_{period_ms:g}'
    res = subprocess.run([str(BIN / 'bringup'), '--drive', 'cia402', '--scenario', str(scenario),
                          '--period-ms', f'{period_ms:g}', '--bag', str(bag),
                          '--logs', str(folder / f'logs_{period_ms:g}'),
                          '--domain-id', str(domain), '--timeout', str(duration + 120)],
                         capture_output=True, text=True, check=False)
    last = json.loads(res.stdout.strip().splitlines()[-1]) if res.stdout.strip() else {}
    b = open_bag(bag)
    h = period_ms * 1e-3
    fb = b.columns('axis/feedback', ['header.stamp.sec', 'header.stamp.nanosec', 'seq',
                                     'drive_fault'])
    cmd = b.columns('axis/velocity_command', ['header.stamp.sec', 'header.stamp.nanosec',
                                              'sample_seq', 'timestamp_ns'])
    st = b.columns('follow/status', ['state'])
    truth = b.columns('sim/truth', ['true_gap_mm'])
    t_fb = stamps_s(fb)
    run_s = t_fb[-1] - t_fb[0] if len(t_fb) > 1 else 0.0
    held = len(t_fb) / max(1.0, run_s / h + 1)
    jitter = np.abs(np.diff(t_fb) - h) * 1e6
    by_seq = dict(zip(fb['seq'].tolist(), t_fb.tolist(), strict=True))
    lat, lat_rx = [], []
    t_cmd = stamps_s(cmd)
    # a sample's latency is its first answer's (a tick without a new sample answers it again)
    answered: set[int] = set()
    for s, tc, rx in zip(cmd['sample_seq'].tolist(), t_cmd.tolist(),
                         (cmd['timestamp_ns'] * 1e-9).tolist(), strict=True):
        ts = by_seq.get(s)
        if ts is not None and s not in answered:
            answered.add(s)
            lat.append(tc - ts)
            lat_rx.append(rx - ts)
    counts: dict = {}
    log = folder / f'logs_{period_ms:g}' / 'ladrc_driver.log'
    for line in log.read_text(errors='replace').splitlines() if log.is_file() else []:
        if line.startswith('driver_node: {'):
            counts = json.loads(line.split(': ', 1)[1])
    states = st['state'].astype(int)
    faults = int(np.sum((states[1:] == 5) & (states[:-1] != 5)))
    bits = sum(frame_bits(n) for n in FRAME_BYTES)
    return {'period_ms': period_ms, 'samples': int(len(t_fb)), 'run_s': round(run_s, 3),
            'held': round(float(held), 4),
            'sync_jitter_p99_us': round(float(np.percentile(jitter, 99)), 1) if jitter.size
            else None,
            'sync_jitter_max_us': round(float(jitter.max()), 1) if jitter.size else None,
            'latency_p50_ms': round(float(np.percentile(lat, 50)) * 1e3, 3) if lat else None,
            'latency_p99_ms': round(float(np.percentile(lat, 99)) * 1e3, 3) if lat else None,
            'latency_received_p99_ms': round(float(np.percentile(lat_rx, 99)) * 1e3, 3)
            if lat_rx else None,
            'frames_per_s': round(len(FRAME_BYTES) / h), 'bus_load_1mbit': round(
                bits / h / 1e6, 3),
            'late_tpdo_cycles': counts.get('late_tpdo_cycles'),
            'missed_tpdo_cycles': counts.get('missed_tpdo_cycles'),
            'contacts': int(np.sum(truth['true_gap_mm'] <= 0.0)),
            'faults': faults, 'drive_fault_samples': int(np.sum(fb['drive_fault'])),
            'exit_codes': last.get('exit_codes'),
            'ran_to_end': bool(last.get('exit_codes')) and all(
                c == 0 for c in last['exit_codes'].values())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--duration', type=float, default=30.0, help='seconds of following')
    ap.add_argument('--periods-ms', default='1,0.5', help='SYNC periods to run [1,0.5]')
    ap.add_argument('--domain-id', type=int, default=None)
    a = ap.parse_args()
    runs = []
    with tempfile.TemporaryDirectory(prefix='cia402-timing-') as tmp:
        for p in (float(x) for x in a.periods_ms.split(',')):
            domain = a.domain_id if a.domain_id is not None else random.randint(1, 101)
            r = one(p, a.duration, Path(tmp), domain)
            print(json.dumps(r), file=sys.stderr, flush=True)
            runs.append(r)
    print(json.dumps({**runs[0], 'duration_s': a.duration, 'runs': runs}))


if __name__ == '__main__':
    os.environ.setdefault('PYTHONUNBUFFERED', '1')
    main()
