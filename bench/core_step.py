"""Per-tick cost of the full LADRC step (TD + ESO + Kalman + law + limits).

Scalar path: µs per ``LADRC.step`` (median of timeit repeats) with the shipped defaults
and the Kalman filter switched on. Batch path: one ``step`` of N parameter sets on numpy
arrays; throughput as multiples of real time at h = 0.5 ms, counting all N controllers
(N·h / wall time per batch step). Last line: one JSON object, ``scalar_step_us``,
``batch_realtime_x`` (per N: ``"1"``, ``"100"``, ``"1000"``) and ``load_1min``.

The tick is the plain composition of the step functions (``LADRC.step_order1`` /
``step_order2``); the 1-minute load average is printed with the figures (the development VM is
shared).

Run: ``scripts/in-env python bench/core_step.py [--quick]`` (or any Python with numpy + scipy +
yaml). ``--quick``: one repeat of a hundredth of the steps per timing, a smoke test of the
bench (its figures are noisy).
"""

import argparse
from dataclasses import replace
import json
import os
from pathlib import Path
import statistics
import sys
import timeit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'ros2_ws' / 'src' / 'ladrc_follow'))

from ladrc_follow.control.ladrc import LADRC  # noqa: E402
from ladrc_follow.control.params import ControllerParams, KalmanParams  # noqa: E402
import numpy as np  # noqa: E402


def params() -> ControllerParams:
    return replace(ControllerParams(), kalman=KalmanParams(enabled=True))


def scalar_step_us(repeats: int = 7, number: int = 50000) -> float:
    c = LADRC(params())
    c.reset(1.0, 0.0, 1.0, encoder_mm=0.0)
    gap, enc, target = 1.001, 0.0002, 1.0
    step = c.step
    times = timeit.repeat(lambda: step(gap, enc, target), number=number, repeat=repeats)
    return statistics.median(times) / number * 1e6


def batch_realtime_x(n: int, repeats: int = 7, scale: float = 1.0) -> tuple[float, float]:
    base = params()
    rng = np.random.default_rng(0)
    plist = [replace(base, law=replace(base.law, kp=float(k)))
             for k in rng.uniform(5.0, 20.0, size=n)]
    c = LADRC.batch(plist)
    c.reset(np.ones(n), np.zeros(n), np.ones(n), encoder_mm=np.zeros(n))
    gap = 1.0 + 0.001 * rng.standard_normal(n)
    enc = np.zeros(n)
    number = max(1, int(max(200, 20000 // max(1, n // 50)) * scale))
    times = timeit.repeat(lambda: c.step(gap, enc, 1.0), number=number, repeat=repeats)
    t_step = statistics.median(times) / number
    h = base.h_s
    return n * h / t_step, t_step * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--quick', action='store_true',
                    help='one repeat of a hundredth of the steps per timing (a smoke test)')
    a = ap.parse_args()
    repeats, scale = (1, 0.01) if a.quick else (7, 1.0)
    load = os.getloadavg()[0]
    us = scalar_step_us(repeats, max(1, int(50000 * scale)))
    print(f'scalar LADRC step (TD+ESO+Kalman+law+limits): {us:.2f} µs '
          f'({0.0005e6 / us:.0f}× real time)')
    batch = {}
    for n in (1, 100, 1000):
        x, t_us = batch_realtime_x(n, repeats, scale)
        batch[str(n)] = round(x, 1)
        print(f'batch N = {n:4d}: {t_us:8.1f} µs per step, {x:10.1f}× real time')
    load = max(load, os.getloadavg()[0])
    print(f'1-minute load average: {load:.2f} on {os.cpu_count()} CPUs')
    print(json.dumps({'scalar_step_us': round(us, 3), 'batch_realtime_x': batch,
                      'load_1min': round(load, 2)}))


if __name__ == '__main__':
    main()
