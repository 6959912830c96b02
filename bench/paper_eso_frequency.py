"""Reproduce paper §4 (§3.2 of the text): the LESO's error transfer functions with and without D.

Gao & Dong 2019, eqs. 28-32 and Fig. 2: G_Di(Ω) = E'_i/E_i, the compensated over the
uncompensated observation error of state i, for the 4-state observer (n = 3, bandwidth gains,
Ω = ω/ω0), and the paper's two statements: at Ω = 5.1286, A = 1.43 and φ = 43.5929°
(compensation weak, curves nearly merged); above Ω = 13.3, |A| < 0.1 and φ < 17.52°
(compensation lost). The transfer functions come from the project's observer matrices
(``eso.continuous_matrices``) through scipy.signal, are checked against eq. 32 and against the
sampled ``LinearESO(compensate=True)``, and are plotted as Fig. 2 (docs/estimators.md, "Paper §4").

Prints a table beside the paper's figures; the last line is one JSON object: the paper's
figures (``omega_lost_paper``, ``phi_lost_paper_deg``, ``omega_weak_paper``,
``phi_weak_paper_deg``, ``a_weak_paper``) beside this reproduction's (``omega_0p1db_i2`` ..
``_i4``, ``phi_at_13_3_i3_deg``, ``phi_at_13_3_i4_deg``, ``omega_weak_phase_i4``,
``omega_weak_is_10_pow_0_71``, ``phi_at_5_1286_i4_deg``, ``a_weak_reproduced``,
``a_db_at_5_1286``, ``a_db_spread_at_5_1286``, ``max_rel_deviation``), the true form's peaks
(``true_peak_db_i3``, ``true_peak_omega_i3``, ``true_peak_db_i4``, ``true_peak_omega_i4``), the
checks (``ss_minus_eq32_max``, ``ss_minus_true_max``, ``leso_measured_minus_true_max``: NaN
with ``--no-measure``) and ``runtime_s``.
Run: python bench/paper_eso_frequency.py [--plot docs/img/paper_eso_frequency.png] [--no-measure]
(``--plot ''``: no plot)
"""

import argparse
import json
from pathlib import Path
import sys
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for _pkg in ('ladrc_follow', 'ladrc_tools', 'ladrc_bags'):
    sys.path.insert(0, str(ROOT / 'ros2_ws/src' / _pkg))
from ladrc_tools.offline.eso_frequency import (  # noqa: E402
    N_FIG2,
    PAPER,
    error_per_disturbance,
    error_tfs,
    figures,
    gd_closed_form,
    gd_corrected,
    gd_phase_deg,
    gd_response,
    measure_gd,
)

MEASURE_OMEGAS = (0.3, 1.0, 1.4142, 3.248, 5.1286, 13.3)


def rel(ours: float, paper: float) -> float:
    """Return the relative deviation of ours from the paper's figure."""
    return ours / paper - 1.0


def plot(path: Path, n: int, measured: dict[float, np.ndarray]) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    w = np.geomspace(0.1, 100.0, 800)
    fig, ax = plt.subplots(2, 2, figsize=(12, 8.5))
    colors = {2: 'tab:blue', 3: 'tab:orange', 4: 'tab:green', 1: 'tab:gray'}
    for i in range(2, n + 2):
        c = colors.get(i)
        ax[0, 0].semilogx(w, 20 * np.log10(np.abs(gd_closed_form(n, i, w))), '--', color=c,
                          label=f'eq. 32, i = {i}')
        ax[0, 0].semilogx(w, 20 * np.log10(np.abs(gd_corrected(n, i, w))), color=c,
                          label=f'true (state space), i = {i}')
        ax[1, 0].semilogx(w, gd_phase_deg(n, i, w), '--', color=c)
        ax[1, 0].semilogx(w, np.degrees(np.angle(gd_corrected(n, i, w))), color=c)
        if measured:
            om = np.array(sorted(measured))
            g = np.array([measured[o][i - 2] for o in om])
            ax[0, 0].semilogx(om, 20 * np.log10(np.abs(g)), 'o', mfc='none', color=c)
            ax[1, 0].semilogx(om, np.degrees(np.angle(g)), 'o', mfc='none', color=c)
    for a in (ax[0, 0], ax[1, 0]):
        for om in (PAPER['omega_weak'], PAPER['omega_lost']):
            a.axvline(om, color='k', lw=0.6, ls=':')
        a.grid(True, which='both', alpha=0.3)
    ax[0, 0].axhline(-0.1, color='k', lw=0.6, ls=':')
    ax[0, 0].set_ylim(-25, 5)
    ax[0, 0].set_ylabel("|G_Di| = |E'_i / E_i|, dB")
    ax[0, 0].set_title(f'Fig. 2: n = {n} (4 states); dotted: Ω = 5.1286, 13.3, −0.1 dB;'
                       ' o: LinearESO')
    ax[0, 0].legend(fontsize=7, ncol=2)
    ax[1, 0].set_ylabel('phase, deg')
    ax[1, 0].set_xlabel('Ω = ω / ω0')
    # eqs. 28-30: error per unit of disturbance, before and after D
    tfs = error_tfs(n)
    e, e_c = error_per_disturbance(tfs, w)
    for i in range(1, n + 2):
        c = colors.get(i, 'tab:gray') if i > 1 else 'tab:red'
        ax[0, 1].loglog(w, e[i - 1], '--', color=c, label=f'|E_{i}/f|')
        if i > 1:
            ax[0, 1].loglog(w, e_c[i - 1], color=c, label=f"|E'_{i}/f|")
    ax[0, 1].set_ylim(1e-4, 3)
    ax[0, 1].set_title('error per unit disturbance (ω0 = 1): dashed LESO, solid LESO + D')
    ax[0, 1].legend(fontsize=7, ncol=2)
    ax[0, 1].grid(True, which='both', alpha=0.3)
    ax[0, 1].set_xlabel('Ω')
    # the project's orders: n = 1 (firmware) and n = 2
    for n_p, ls in ((1, '-'), (2, '-.')):
        for i in range(2, n_p + 2):
            ax[1, 1].semilogx(w, 20 * np.log10(np.abs(gd_corrected(n_p, i, w))), ls,
                              label=f'n = {n_p}, i = {i} (true)')
    ax[1, 1].axhline(0.0, color='k', lw=0.6)
    ax[1, 1].set_ylim(-25, 5)
    ax[1, 1].set_title("the project's observer orders (bandwidth gains): |G_Di|, dB")
    ax[1, 1].set_xlabel('Ω = ω / ω0')
    ax[1, 1].legend(fontsize=7)
    ax[1, 1].grid(True, which='both', alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--plot', default=str(ROOT / 'docs/img/paper_eso_frequency.png'),
                    help='PNG to write (Fig. 2 equivalents); "" for none')
    ap.add_argument('--no-measure', action='store_true',
                    help='skip the time-domain check on the sampled LinearESO')
    args = ap.parse_args()
    t0 = time.perf_counter()
    n = N_FIG2
    fig = figures(n)
    tfs = error_tfs(n)
    grid = np.geomspace(0.01, 1000.0, 2001)
    # state space (project matrices) vs eq. 32 and vs the corrected form, on a grid
    ss_vs_eq32 = {i: float(np.max(np.abs(gd_response(tfs, i, grid) - gd_closed_form(n, i, grid))))
                  for i in range(2, n + 2)}
    ss_vs_true = {i: float(np.max(np.abs(gd_response(tfs, i, grid) - gd_corrected(n, i, grid))))
                  for i in range(2, n + 2)}
    measured: dict[float, np.ndarray] = {}
    meas_err = float('nan')
    if not args.no_measure:
        for om in MEASURE_OMEGAS:
            measured[om] = measure_gd(om, n)
        meas_err = max(float(np.max(np.abs(
            measured[om] - np.array([gd_corrected(n, i, np.array([om]))[0]
                                     for i in range(2, n + 2)])))) for om in measured)

    top = n + 1
    dev = {
        'omega_lost_vs_i3': rel(fig['omega_0p1db_i3'], PAPER['omega_lost']),
        'omega_lost_vs_i4': rel(fig['omega_0p1db_i4'], PAPER['omega_lost']),
        'phi_at_13_3_i3': rel(fig['phi_deg_at_13_3_i3'], PAPER['phi_lost_deg']),
        'phi_at_13_3_i4': rel(fig['phi_deg_at_13_3_i4'], PAPER['phi_lost_deg']),
        'omega_weak_vs_phase_i4': rel(fig['omega_phi_43_5929_top'], PAPER['omega_weak']),
        'phi_at_5_1286_i4': rel(fig[f'phi_deg_at_5_1286_i{top}'], PAPER['phi_weak_deg']),
    }
    print(f"paper §4, Fig. 2: G_Di(Ω) = E'_i/E_i, LESO with n + 1 = {n + 1} states, bandwidth"
          ' gains, Ω = ω/ω0; "eq. 32" = the paper\'s formula, "true" = from the state space')
    print(f'{"figure":48s} {"paper":>10s}  {"here (eq. 32)":28s} {"deviation":>10s}')
    rows = [
        ('Ω where |A| = 0.1 dB (compensation lost)', '13.3',
         f'{fig["omega_0p1db_i3"]:.3f} (i=3), {fig["omega_0p1db_i4"]:.3f} (i=4)',
         f'{dev["omega_lost_vs_i3"]:+.1%}, {dev["omega_lost_vs_i4"]:+.1%}'),
        ('  same for i = 2 (first order, s/(s+4))', '-', f'{fig["omega_0p1db_i2"]:.3f}',
         'paper silent'),
        ('|A| at Ω = 13.3, dB', '< 0.1',
         f'{-fig["a_db_at_13_3_i3"]:.4f} (i=3), {-fig["a_db_at_13_3_i4"]:.4f} (i=4)', ''),
        ('φ at Ω = 13.3, deg', '< 17.52',
         f'{fig["phi_deg_at_13_3_i3"]:.2f} (i=3), {fig["phi_deg_at_13_3_i4"]:.2f} (i=4)',
         f'{dev["phi_at_13_3_i3"]:+.1%}, {dev["phi_at_13_3_i4"]:+.1%}'),
        ('Ω where φ = 17.52°', '13.3',
         f'{fig["omega_phi_17_52_i3"]:.3f} (i=3), {fig["omega_phi_17_52_i4"]:.3f} (i=4)', ''),
        ('Ω = 5.1286 is 10^0.71 (a 0.01-decade grid point)', '5.1286',
         f'{fig["omega_grid_point"]:.5f}', ''),
        ('φ at Ω = 5.1286, deg', '43.5929',
         f'{fig["phi_deg_at_5_1286_i4"]:.4f} (i=4), {fig["phi_deg_at_5_1286_i3"]:.2f} (i=3)',
         f'{dev["phi_at_5_1286_i4"]:+.1%}'),
        ('Ω where φ(i=4) = 43.5929°', '5.1286', f'{fig["omega_phi_43_5929_top"]:.4f}',
         f'{dev["omega_weak_vs_phase_i4"]:+.1%}'),
        ('A at Ω = 5.1286, dB', '1.43',
         f'{fig["a_db_at_5_1286_i2"]:.2f}, {fig["a_db_at_5_1286_i3"]:.2f}, '
         f'{fig["a_db_at_5_1286_i4"]:.2f} (i=2,3,4)', 'not found'),
        ('  spread of the three curves at 5.1286, dB', '(1.43?)',
         f'{fig["a_db_spread_at_5_1286"]:.3f}', f'{rel(fig["a_db_spread_at_5_1286"], 1.43):+.1%}'),
    ]
    for name, paper, ours, d in rows:
        print(f'{name:48s} {paper:>10s}  {ours:28s} {d:>10s}')
    print('true G_Di = s·q_{i-1}/q_i (eq. 26; eq. 30 holds for i = 2 only):')
    for i in range(2, n + 2):
        pk = fig[f'corrected_peak_db_i{i}']
        where = (f'peak {pk:+.3f} dB at Ω = {fig[f"corrected_peak_omega_i{i}"]:.4f}'
                 if pk > 0 else 'no peak above 0 dB')
        a_db = fig[f'corrected_a_db_at_5_1286_i{i}']
        print(f'  i = {i}: {where}; at Ω = 5.1286: {a_db:+.3f} dB,'
              f' {fig[f"corrected_phi_deg_at_5_1286_i{i}"]:+.2f}°')
    print('state space (continuous_matrices + ss2tf) − eq. 32, max |Δ| on Ω = 0.01…1000: '
          + ', '.join(f'i={i}: {v:.2e}' for i, v in ss_vs_eq32.items()))
    print('state space − true form, max |Δ|: '
          + ', '.join(f'i={i}: {v:.2e}' for i, v in ss_vs_true.items()))
    if measured:
        print(f'sampled LinearESO (ZOH, ω0·h = 1e-3) − true form, max |Δ| at Ω = '
              f'{", ".join(f"{o:g}" for o in MEASURE_OMEGAS)}: {meas_err:.2e}')
    if args.plot:
        plot(Path(args.plot), n, measured)
        print(f'plot: {args.plot}')
    reproduced = [v for k, v in dev.items()]
    summary = {
        'omega_lost_paper': PAPER['omega_lost'],
        'omega_0p1db_i3': round(fig['omega_0p1db_i3'], 4),
        'omega_0p1db_i4': round(fig['omega_0p1db_i4'], 4),
        'omega_0p1db_i2': round(fig['omega_0p1db_i2'], 4),
        'phi_lost_paper_deg': PAPER['phi_lost_deg'],
        'phi_at_13_3_i3_deg': round(fig['phi_deg_at_13_3_i3'], 4),
        'phi_at_13_3_i4_deg': round(fig['phi_deg_at_13_3_i4'], 4),
        'omega_weak_paper': PAPER['omega_weak'],
        'omega_weak_phase_i4': round(fig['omega_phi_43_5929_top'], 4),
        'omega_weak_is_10_pow_0_71': round(fig['omega_grid_point'], 5),
        'phi_weak_paper_deg': PAPER['phi_weak_deg'],
        'phi_at_5_1286_i4_deg': round(fig['phi_deg_at_5_1286_i4'], 4),
        'a_weak_paper': PAPER['a_weak'],
        'a_weak_reproduced': False,
        'a_db_at_5_1286': [round(fig[f'a_db_at_5_1286_i{i}'], 4) for i in range(2, n + 2)],
        'a_db_spread_at_5_1286': round(fig['a_db_spread_at_5_1286'], 4),
        'max_rel_deviation': round(max(abs(v) for v in reproduced), 4),
        'true_peak_db_i3': round(fig['corrected_peak_db_i3'], 4),
        'true_peak_omega_i3': round(fig['corrected_peak_omega_i3'], 4),
        'true_peak_db_i4': round(fig['corrected_peak_db_i4'], 4),
        'true_peak_omega_i4': round(fig['corrected_peak_omega_i4'], 4),
        'ss_minus_eq32_max': max(ss_vs_eq32.values()),
        'ss_minus_true_max': max(ss_vs_true.values()),
        'leso_measured_minus_true_max': meas_err,
        'runtime_s': round(time.perf_counter() - t0, 2),
    }
    print(json.dumps(summary))


if __name__ == '__main__':
    main()
