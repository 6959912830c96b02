"""Headless closed-loop speed: simulated seconds per wall-clock second (realtime_x).

Runs one scenario (default ``showcase``, 25 s) through ``ladrc_sim.headless.runner.run`` at
2 kHz with the most complete controller ``ladrc_follow.control`` offers:

1. ``ladrc_follow.control.follow.FollowController`` (the state machine), if present;
2. else ``ladrc_follow.control.ladrc.LADRC`` behind a small adapter (start_follow resets it
   bumplessly at the current reading; zero command while not following or invalid);
3. else a simple PD on the gap.

Also times the simulator alone (a controller that returns 0) so the sim's share is visible.
The loop is timed by the runner itself (set-up excluded); best of ``--repeat`` runs.
Target: ``realtime_x >= 50`` with the full controller.

Run: python bench/headless_speed.py [--scenario showcase] [--repeat 3]
The last line of output is one JSON object: ``realtime_x`` (best), ``realtime_x_median``,
``controller``, ``scenario``, ``sim_s``, ``us_per_tick``, ``sim_only_realtime_x``,
``sim_only_us_per_tick``, ``target_realtime_x``, ``collisions`` and ``error_rms_mm``.
"""

import argparse
import json
from pathlib import Path
import statistics
import sys

ROOT = Path(__file__).resolve().parents[1]
for pkg in ('ladrc_follow', 'ladrc_sim'):
    src = str(ROOT / 'ros2_ws' / 'src' / pkg)
    if src not in sys.path:
        sys.path.insert(0, src)

from ladrc_sim.headless.runner import run  # noqa: E402
from ladrc_sim.headless.scenario import load_scenario  # noqa: E402


class PD:
    """Fallback: proportional gap control, velocity-limited."""

    name = 'PD (fallback)'

    def __init__(self, kp=60.0, v_max=200.0):
        self.kp, self.v_max, self.target = kp, v_max, None

    def command(self, name, **kwargs):
        """Take the target of the follow commands."""
        if name in ('start_follow', 'set_target', 'gradient_follow'):
            self.target = kwargs['target_gap_mm']
        elif name == 'stop_follow':
            self.target = None

    def step(self, tick):
        """Return kp (target - gap), clipped."""
        if self.target is None or not tick.gap_valid:
            return 0.0
        u = self.kp * (self.target - tick.gap_mm)
        return self.v_max if u > self.v_max else (-self.v_max if u < -self.v_max else u)


class Null:
    """Always 0 mm/s: times the simulator alone."""

    name = 'null'

    def command(self, name, **kwargs):
        """Ignore commands."""

    def step(self, tick):
        """Return 0 mm/s."""
        return 0.0


class LadrcAdapter:
    """The composite LADRC (no state machine yet) behind the runner's controller protocol."""

    name = 'ladrc.LADRC (adapter)'

    def __init__(self, ladrc_cls, params_cls):
        self.c = ladrc_cls(params_cls())
        self.target = None
        self.reset_pending = False

    def command(self, name, **kwargs):
        """Track the target; a start from idle resets the LADRC at the next tick."""
        if name in ('start_follow', 'set_target', 'gradient_follow'):
            if self.target is None:
                self.reset_pending = True
            self.target = kwargs['target_gap_mm']
        elif name == 'stop_follow':
            self.target = None

    def step(self, tick):
        """Return the LADRC command, 0 while idle or on invalid input."""
        if self.target is None or not tick.gap_valid or tick.drive_fault:
            self.reset_pending = self.target is not None
            return 0.0
        if self.reset_pending:
            self.c.reset(tick.gap_mm, 0.0, self.target, tick.encoder_mm)
            self.reset_pending = False
        return float(self.c.step(tick.gap_mm, tick.encoder_mm, self.target))


def full_controller():
    """Return the most complete controller available and its description."""
    try:
        from ladrc_follow.control.follow import FollowController
        ctrl = FollowController()
        ctrl.name = 'follow.FollowController'
        return ctrl
    except Exception:  # noqa: BLE001 - not there yet, or not constructible with defaults
        pass
    try:
        from ladrc_follow.control.ladrc import LADRC
        from ladrc_follow.control.params import ControllerParams
        return LadrcAdapter(LADRC, ControllerParams)
    except Exception:  # noqa: BLE001
        return PD()


def time_runs(sc, make, repeat):
    return [run(sc, make()) for _ in range(repeat)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--scenario', default='showcase', help='file or shipped name')
    ap.add_argument('--repeat', type=int, default=3)
    args = ap.parse_args()
    sc = load_scenario(args.scenario)
    probe = full_controller()
    name = probe.name
    make = (lambda: full_controller()) if name != PD.name else PD
    full = time_runs(sc, make, args.repeat)
    null = time_runs(sc, Null, args.repeat)
    rx = [r.realtime_x for r in full]
    rx0 = [r.realtime_x for r in null]
    n = full[0].t_s.size
    best = max(full, key=lambda r: r.realtime_x)
    m = best.metrics
    print(f'scenario {sc.name}: {sc.duration_s} s simulated, {n} ticks, controller {name}')
    print(f'full loop:  realtime x{max(rx):.1f} (median x{statistics.median(rx):.1f}), '
          f'{best.wall_s / n * 1e6:.2f} us/tick')
    print(f'sim alone:  realtime x{max(rx0):.1f} '
          f'({min(r.wall_s for r in null) / n * 1e6:.2f} us/tick)')
    print(f'metrics: followed at {m.followed_at_s:.3f} s, error rms {m.error_rms_mm:.4f} mm, '
          f'max {m.error_max_mm:.3f} mm, collisions {m.collisions}')
    print(json.dumps({
        'realtime_x': round(max(rx), 2),
        'realtime_x_median': round(statistics.median(rx), 2),
        'controller': name,
        'scenario': sc.name,
        'sim_s': sc.duration_s,
        'us_per_tick': round(best.wall_s / n * 1e6, 3),
        'sim_only_realtime_x': round(max(rx0), 2),
        'sim_only_us_per_tick': round(min(r.wall_s for r in null) / n * 1e6, 3),
        'target_realtime_x': 50,
        'collisions': m.collisions,
        'error_rms_mm': m.error_rms_mm,
    }))


if __name__ == '__main__':
    main()
