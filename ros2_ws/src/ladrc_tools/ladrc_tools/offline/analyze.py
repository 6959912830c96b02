"""``ladrc analyze``: the linear follow loop of a parameter set, in the frequency domain.

The loop is :mod:`ladrc_follow.analysis.loop`'s: the controller's own tick, linearized, around
the axis model ``b0/(s(T1 s + 1))`` with dead time and sensor lag, at the controller's period.
Writes ``bode.png`` (loop gain L, S and T, sheet-to-gap, target-to-gap through the TD, and
the LADRC's observer: disturbance estimate / disturbance), ``analysis.md`` and
``analysis.json`` into the output folder (built under a temporary name, renamed when
complete).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from ladrc_follow import (
    AxisModel,
    ControllerParams,
    LoopAnalysis,
    ObserverAnalysis,
    analyse_observer,
    analyse_params,
)
import numpy as np

from .outdir import building
from .report import strict_json


def figures(an: LoopAnalysis, obs: ObserverAnalysis | None = None) -> dict[str, Any]:
    """Return the loop's (and the observer's) figures, rounded for reading (JSON)."""
    def r(v: Any) -> Any:
        if isinstance(v, list):
            return [r(x) for x in v]
        return round(v, 4) if isinstance(v, float) and math.isfinite(v) else v

    items = {**an.figures(), **(obs.figures() if obs is not None else {})}
    return {k: r(v) for k, v in items.items()}


def _db(x: np.ndarray) -> np.ndarray:
    with np.errstate(divide='ignore'):
        return 20 * np.log10(np.abs(x))


def plot(an: LoopAnalysis, path: Path, title: str, obs: ObserverAnalysis | None = None
         ) -> None:
    """Bode plots of L, S, T, sheet and target to gap, the observer, into ``path`` (PNG)."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    f = an.f_hz
    fig, ax = plt.subplots(3, 1, figsize=(10, 10), sharex=True)
    ax[0].semilogx(f, _db(an.loop), label='|L| (loop gain at the axis input)')
    ax[0].axhline(0, color='k', lw=0.6)
    if math.isfinite(an.crossover_hz):
        ax[0].axvline(an.crossover_hz, color='C0', ls=':', lw=0.8)
    ax[0].set_ylabel('dB')
    ax[0].set_ylim(max(-80, float(np.nanmin(_db(an.loop)))), 80)
    ax[0].legend(loc='upper right', fontsize=8)
    ax[0].set_title(title)
    ph = np.degrees(np.unwrap(np.angle(an.loop)))
    ax[1].semilogx(f, ph, color='C1', label='∠L')
    for k in range(-4, 2):
        ax[1].axhline(-180 + 360 * k, color='k', lw=0.5, ls='--')
    ax[1].set_ylabel('phase [deg]')
    ax[1].set_ylim(max(-720, float(np.nanmin(ph)) - 20), min(360, float(np.nanmax(ph)) + 20))
    ax[1].legend(loc='upper right', fontsize=8)
    ax[2].semilogx(f, _db(an.sensitivity), label='|S| = |1/(1+L)|')
    ax[2].semilogx(f, _db(an.complementary), label='|T| = |L/(1+L)|')
    ax[2].semilogx(f, _db(an.sheet_to_gap), ls='--', label='|sheet → gap|')
    ax[2].semilogx(f, _db(an.reference_to_gap), ls='-.', label='|target → gap| (through the TD)')
    if obs is not None:
        ax[2].semilogx(obs.f_hz, _db(obs.disturbance_estimate), ls=':',
                       label='|ESO: disturbance estimate / disturbance|')
    ax[2].axhline(-3, color='k', lw=0.5, ls=':')
    ax[2].set_ylim(-60, 15)
    ax[2].set_ylabel('dB')
    ax[2].set_xlabel('f [Hz]')
    ax[2].legend(loc='lower right', fontsize=8)
    for a in ax:
        a.grid(True, which='both', alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown(fig: dict[str, Any], params_source: str, mode: str, axis: AxisModel) -> str:
    """Return the summary page (Markdown)."""
    def f(v: Any) -> str:
        return 'n/a' if v is None or (isinstance(v, float) and not math.isfinite(v)) else str(v)

    rows = [('closed loop stable', fig['stable']),
            ('spectral radius of the closed loop', fig['spectral_radius']),
            ('phase margin [deg]', fig['phase_margin_deg']),
            ('gain crossover [Hz]', fig['crossover_hz']),
            ('delay margin [ms]', fig['delay_margin_ms']),
            ('gain margin [dB]', fig['gain_margin_db']),
            ('phase crossover [Hz]', fig['gain_margin_hz']),
            ('lower gain margin [dB]', fig['lower_gain_margin_db']),
            ('Ms = max |S|', fig['ms_peak']),
            ('at [Hz]', fig['ms_hz']),
            ('bandwidth, |T| = −3 dB [Hz]', fig['bandwidth_hz']),
            ('reference bandwidth, target → gap −3 dB [Hz]', fig['reference_bandwidth_hz'])]
    if 'eso_bandwidth_hz' in fig:
        rows += [('ESO disturbance-estimation bandwidth, −3 dB [Hz]', fig['eso_bandwidth_hz']),
                 ('ESO error-dynamics poles [Hz]', ', '.join(
                     f'{v:g}' for v in fig['eso_error_poles_hz'])),
                 ('ESO error-dynamics spectral radius', fig['eso_error_spectral_radius'])]
    lines = ['# Loop analysis', '',
             f'Controller: {mode} ({params_source}); axis b0 = {axis.b0:g}, T1 = '
             f'{axis.t1_s * 1e3:g} ms, dead time {axis.dead_ticks} tick(s), sensor lag '
             f'{axis.lag_s * 1e3:g} ms. The loop is linear: the limits inactive (small '
             'signals), the Kalman filter at its steady-state gain; the TD (linear) shapes '
             'the target outside the feedback loop.', '',
             '| figure | value |', '| --- | --- |']
    lines += [f'| {k} | {f(v)} |' for k, v in rows]
    gate = ('passes' if fig['gate_passed'] else 'fails:\n\n' + '\n'.join(
        f'- {r}' for r in fig['gate_reasons']))
    lines += ['', f'Stability gate (the set’s `stability.*` minima and axis model): {gate}',
              '', '![bode](bode.png)', '']
    return '\n'.join(lines)


def write_analysis(params: ControllerParams, params_source: str, mode: str | None,
                   axis: AxisModel, out_dir: Path) -> tuple[Path, dict[str, Any]]:
    """Analyse and write ``out_dir``; return it and the figures."""
    from ladrc_follow import stability_reasons

    mode = mode or params.follow.controller
    an = analyse_params(params, axis, mode)
    obs = analyse_observer(params) if mode == 'ladrc' else None
    fig = figures(an, obs)
    # the gate's verdict on the set as it would go live (its own axis model: stability.*)
    reasons = stability_reasons(params)
    fig['gate_passed'] = not reasons
    fig['gate_reasons'] = reasons
    if out_dir.exists():
        raise FileExistsError(f'{out_dir} exists already: outputs are never overwritten')
    with building(out_dir) as tmp:
        plot(an, tmp / 'bode.png', f'{mode}: PM {fig["phase_margin_deg"]}°, '
             f'GM {fig["gain_margin_db"]} dB, Ms {fig["ms_peak"]}', obs)
        (tmp / 'analysis.md').write_text(markdown(fig, params_source, mode, axis),
                                         encoding='utf-8')
        (tmp / 'analysis.json').write_text(json.dumps(strict_json(
            {'controller': mode, 'params': params_source, 'axis': vars(axis), **fig}),
            indent=1) + '\n', encoding='utf-8')
    return out_dir, fig
