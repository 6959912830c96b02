"""The loop analysis against the simulator: sheet sines in the headless closed loop.

    scripts/in-env python bench/loop_vs_sim.py [--plot docs/img/loop_vs_sim.png] [--quick]

For the shipped LADRC (order 1, Euler), an order-2 ZOH observer with the Kalman fusion and
the PID: a 5 um sheet sine at 12 frequencies from 0.5 to 60 Hz in the headless runner (the
full FollowController in its LADRC or PID state; no noise, no quantization), projected over the
last whole periods, against the analysed sheet-to-nozzle response
(``ladrc_follow.analysis.loop``). Plots both (magnitude and phase) and prints the largest
deviations; last line JSON: ``frequencies_hz`` and, per loop (its name as the key), ``max_db``
and ``max_deg``. ``--quick``: the two highest frequencies only (the shortest runs), a smoke
test of the bench.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import json
from pathlib import Path
import sys

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for pkg in ('ladrc_follow', 'ladrc_sim'):
    sys.path.insert(0, str(ROOT / 'ros2_ws' / 'src' / pkg))

from ladrc_follow.analysis.loop import AxisModel, analyse_params, frequency_grid  # noqa: E402
from ladrc_follow.control.follow import FollowController  # noqa: E402
from ladrc_follow.control.params import (  # noqa: E402
    ControllerParams,
    ESOParams,
    KalmanParams,
    LawParams,
)
from ladrc_sim.headless.runner import run  # noqa: E402
from ladrc_sim.headless.scenario import scenario_from_dict  # noqa: E402

H = 0.0005
FREQS = [0.5, 1.0, 2.0, 3.0, 5.0, 8.0, 12.0, 16.0, 20.0, 30.0, 45.0, 60.0]
QUICK_FREQS = FREQS[-2:]
LOOPS = {
    'LADRC shipped (order 1, Euler)': ('ladrc', ControllerParams()),
    'LADRC order 2, ZOH, Kalman': ('ladrc', replace(
        ControllerParams(), eso=ESOParams(order=2, discretization='zoh', gains='bandwidth',
                                          w0_rad_s=300.0, b0=1.0 / 0.008),
        law=LawParams(form=3, gains='bandwidth', wc_rad_s=40.0),
        kalman=KalmanParams(enabled=True))),
    'PID shipped': ('pid', ControllerParams()),
}


def simulated(params: ControllerParams, mode: str, f: float) -> complex:
    """Nozzle / sheet at ``f`` from a headless run (the last whole periods)."""
    t_on = 1.0
    periods = max(4, int(round(0.6 * f)))
    sc = scenario_from_dict({
        'name': 'sweep', 'duration_s': t_on + 1.5 + periods / f, 'seed': 1,
        'initial_gap_mm': 1.0, 'encoder': {'resolution_mm': 0.0},
        'sheet': {'profiles': [{'kind': 'sine', 'amp_mm': 0.005, 'freq_hz': f,
                                't_start_s': t_on}]},
        'timeline': [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}]})
    res = run(sc, FollowController(params, mode=mode))
    n = int(round(periods / f / H))
    sl = slice(res.t_s.size - n, res.t_s.size)
    basis = np.exp(-2j * np.pi * f * (res.t_s[sl] - t_on))
    noz = res.nozzle_mm[sl] - res.nozzle_mm[sl].mean()
    return complex(np.sum(noz * basis) / np.sum(res.sheet_mm[sl] * basis))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--plot', default=None, help='write the comparison plot (PNG) here')
    ap.add_argument('--quick', action='store_true',
                    help='the two highest frequencies only (a smoke test)')
    a = ap.parse_args()
    freqs = QUICK_FREQS if a.quick else FREQS
    grid = frequency_grid(H, 2000, 0.3)
    out = {}
    curves = {}
    for name, (mode, p) in LOOPS.items():
        an = analyse_params(p, AxisModel(), mode, freqs)
        sim = np.array([simulated(p, mode, f) for f in freqs])
        db = 20 * np.log10(np.abs(sim) / np.abs(an.sheet_to_nozzle))
        deg = np.degrees(np.angle(sim / an.sheet_to_nozzle))
        out[name] = {'max_db': round(float(np.max(np.abs(db))), 4),
                     'max_deg': round(float(np.max(np.abs(deg))), 4)}
        curves[name] = (analyse_params(p, AxisModel(), mode, grid).sheet_to_nozzle, sim)
        print(f'{name}: max {out[name]["max_db"]} dB, {out[name]["max_deg"]} deg',
              file=sys.stderr, flush=True)
    if a.plot:
        import matplotlib

        matplotlib.use('Agg')
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(2, 1, figsize=(10, 8), sharex=True)
        for k, (name, (curve, sim)) in enumerate(curves.items()):
            c = f'C{k}'
            ax[0].semilogx(grid, 20 * np.log10(np.abs(curve)), color=c, label=f'{name}: analysis')
            ax[0].semilogx(freqs, 20 * np.log10(np.abs(sim)), 'o', color=c, mfc='none',
                           label=f'{name}: simulated sine')
            ax[1].semilogx(grid, np.degrees(np.unwrap(np.angle(curve))), color=c)
            ax[1].semilogx(freqs, np.degrees(np.unwrap(np.angle(sim))), 'o', color=c,
                           mfc='none')
        ax[0].set_ylabel('|nozzle / sheet| [dB]')
        ax[0].set_ylim(-45, 8)
        ax[0].legend(fontsize=7, loc='lower left')
        ax[0].set_title('sheet -> nozzle: loop analysis (lines) vs headless closed loop (circles)')
        ax[1].set_ylabel('phase [deg]')
        ax[1].set_xlabel('f [Hz]')
        for x in ax:
            x.grid(True, which='both', alpha=0.3)
        fig.tight_layout()
        fig.savefig(a.plot, dpi=110)
        plt.close(fig)
    print(json.dumps({'frequencies_hz': freqs, **out}))


if __name__ == '__main__':
    main()
