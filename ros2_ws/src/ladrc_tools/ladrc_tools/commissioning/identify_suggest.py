"""Controller parameters suggested for an identified axis, checked by the stability gate."""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any

from .identify import AxisFit, IdentifyError

OBSERVER_LAG_PRODUCT = 0.5
"""ω0 · T_Σ: the observer's bandwidth against the lag it does not model (module suggest)."""
OBSERVER_OVER_CONTROLLER = 4.0
"""ω0 / ωc."""
TARGET_PHASE_MARGIN_DEG = 40.0
TARGET_MS = 2.0


@dataclass
class Suggestion:
    """Suggested controller parameters (a gated ControllerParams), figures and reasoning."""

    params: Any
    eso_b0: float
    w0_rad_s: float
    wc_rad_s: float
    dead_time_ticks: int
    lag_sum_s: float
    figures: dict[str, dict[str, float]]
    reasoning: list[str]


def gate_dead_ticks(tau_s: float, h_s: float) -> int:
    """Whole ticks for the gate's axis model: τ/h rounded up, a quarter tick of tolerance."""
    return max(0, int(math.ceil(tau_s / h_s - 0.25)))


def suggest(axis: AxisFit, sensor_lag_s: float = 0.0) -> Suggestion:
    """Suggest b0, ESO and controller bandwidths for the identified axis; gate-checked.

    Raises :class:`IdentifyError` when no set on the search passes the stability gate.
    """
    from ladrc_follow import (
        AxisModel,
        ControllerParams,
        ParameterError,
        analyse_params,
        check_gate,
        frequency_grid,
        params_from_dict,
    )

    # the controller's tick, not the bag's sample period: the gate counts dead time in it
    h = ControllerParams().h_s
    b0 = axis.b0.value
    t1 = axis.t1_s.value
    unresolved = t1 < h  # a lag below a tick is not resolved: plan with one tick
    dead = gate_dead_ticks(axis.dead_time_s.value, h)
    lag = max(0.0, sensor_lag_s if math.isfinite(sensor_lag_s) else 0.0)
    t_sum = max(t1, h) + dead * h + lag + h
    w0 = OBSERVER_LAG_PRODUCT / t_sum
    stab = {'axis_b0': float(f'{b0:.6g}'), 'axis_t1_ms': float(f'{t1 * 1e3:.6g}'),
            'axis_dead_time_ticks': dead, 'axis_lag_ms': float(f'{lag * 1e3:.6g}')}
    model = AxisModel(stab['axis_b0'], stab['axis_t1_ms'] * 1e-3, dead,
                      stab['axis_lag_ms'] * 1e-3)
    reasoning = [
        f'The order-1 LADRC models the axis as the integrator b0/s with b0 = {b0:.4g} '
        '(eso.b0, the identified gain). What it does not model acts as a lag T_Σ = T1 + dead '
        f'time + sensor lag + one tick of hold = {max(t1, h) * 1e3:.3g} + '
        f'{dead * h * 1e3:.3g} + '
        f'{lag * 1e3:.3g} + {h * 1e3:.3g} = {t_sum * 1e3:.3g} ms, which costs about '
        'ω·T_Σ rad of phase at ω.',
        f'Observer: ω0·T_Σ = {OBSERVER_LAG_PRODUCT:g} '
        f'(≈ {math.degrees(OBSERVER_LAG_PRODUCT):.0f}° of unmodelled lag at ω0), so '
        f'ω0 = {w0:.1f} rad/s; a faster observer estimates the '
        'lag as disturbance and rings, a slower one rejects less.',
        f'Controller: ωc = ω0/{OBSERVER_OVER_CONTROLLER:g} = '
        f'{w0 / OBSERVER_OVER_CONTROLLER:.1f} rad/s (the observer settles before the law acts '
        'on its estimate; 3–10 is the usual ratio), far below 1/T_Σ = '
        f'{1.0 / t_sum:.0f} rad/s.',
    ]
    if unresolved:
        reasoning.insert(1, f'T1 = {t1 * 1e3:.3g} ms is below one tick: not resolved by the '
                            f'data, so T_Σ counts one tick ({h * 1e3:g} ms) for it.')
    grid = frequency_grid(h, 1000)
    last: list[str] = []
    for attempt in range(24):
        wc = w0 / OBSERVER_OVER_CONTROLLER
        d = {'eso': {'gains': 'bandwidth', 'w0_rad_s': round(w0, 2),
                     'b0': float(f'{b0:.6g}')},
             'law': {'gains': 'bandwidth', 'wc_rad_s': round(wc, 3)},
             'stability': stab}
        try:
            p = check_gate(params_from_dict(d))
        except ParameterError as exc:
            last = exc.reasons
            p = None
        if p is not None:
            figs = {}
            for mode in ('ladrc', 'pid'):
                an = analyse_params(p, model, mode, grid)
                figs[mode] = {k: float(v) for k, v in an.figures().items()}
            lad = figs['ladrc']
            if (lad['phase_margin_deg'] >= TARGET_PHASE_MARGIN_DEG
                    and lad['ms_peak'] <= TARGET_MS):
                if attempt:
                    reasoning.append(f'Lowered both by 0.85 per step ({attempt} steps) until '
                                     f'the phase margin reached {TARGET_PHASE_MARGIN_DEG:g}° '
                                     f'and Ms {TARGET_MS:g} at most.')
                reasoning.append(
                    f"Checked with the stability gate against the identified axis: LADRC "
                    f"phase margin {lad['phase_margin_deg']:.1f}°, gain margin "
                    f"{lad['gain_margin_db']:.1f} dB, delay margin "
                    f"{lad['delay_margin_ms']:.1f} ms, Ms {lad['ms_peak']:.2f}, bandwidth "
                    f"{lad['bandwidth_hz']:.1f} Hz; PID phase margin "
                    f"{figs['pid']['phase_margin_deg']:.1f}°, Ms "
                    f"{figs['pid']['ms_peak']:.2f} (gate minima: stability.*).")
                return Suggestion(params=p, eso_b0=float(f'{b0:.6g}'), w0_rad_s=round(w0, 2),
                                  wc_rad_s=round(wc, 3), dead_time_ticks=dead,
                                  lag_sum_s=t_sum, figures=figs, reasoning=reasoning)
        w0 *= 0.85
    raise IdentifyError('no suggested parameter set passes the stability gate for the '
                        f'identified axis: {" | ".join(last) or "margins below target"}')
