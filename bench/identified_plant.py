"""The follow controller on the identified plant of notes §1.2: gain, units and intervals.

Three parts (docs/identification.md):

1. The linear loop (``loop.analyse``, the machinery of ``ladrc analyze``) of the shipped LADRC
   and PID on the §1.2 plant for ``identified_gain`` = 1/16.75 (b0 = 1, the sim's default),
   0.01 (the project's UnitP/UnitV mapping) and 1 (16.75 taken as mm/s per mm/s), beside the
   sim's first-order axis; and with the ESO's b0 set to what each gain implies.
2. The library scenarios ``identified_plant`` and ``identified_step`` run headless (the same
   runner and metrics as ``ladrc simulate NAME``) with those gains, and with gain 1 plus a
   dead time of 1 and 2 ticks.
3. The same two scenarios with each coefficient at each end of the notes' ±1σ interval and at
   the two corners (all −, all +), LADRC and PID, with the loop's figures at each end.

Prints tables; the last line is one JSON object: the loop's figures (``ladrc_pm_deg_gain_b0_1``,
``ladrc_pm_deg_gain_1``, ``ladrc_dm_ms_gain_1``, ``ladrc_fc_hz_gain_1``,
``ladrc_fc_hz_gain_0_01``, ``slow_pole_rad_s``, ``plant_zero_rad_s``), the headless runs'
(``plant_rms_mm_ladrc``, ``plant_rms_mm_pid``, ``plant_rms_mm_ladrc_gain_1``,
``pid_gain_1_collisions``, ``pid_gain_1_fault``, ``ladrc_gain_1_dead_2_fault``), the interval's
error RMS range per scenario and mode (``identified_plant_ladrc_rms_range_mm``, ...), with
``--long-s`` the long run's (``long_s``, ``long_error_rms_mm``,
``long_last10s_mean_command_mm_s``), and ``runtime_s``.
Run: python bench/identified_plant.py [--long-s 300] [--quick]
``--quick``: every headless run cut to its first 0.5 s and part 3 on the nominal plant only, a
smoke test of the bench (its figures are not the scenarios').
"""

import argparse
import dataclasses
import json
import math
from pathlib import Path
import sys
import time

ROOT = Path(__file__).resolve().parents[1]
for _pkg in ('ladrc_follow', 'ladrc_sim', 'ladrc_tools', 'ladrc_bags'):
    sys.path.insert(0, str(ROOT / 'ros2_ws/src' / _pkg))
from ladrc_follow.analysis.loop import AxisModel, analyse_params  # noqa: E402
from ladrc_follow.control.follow import FollowController  # noqa: E402
from ladrc_follow.control.params import ControllerParams, params_from_dict  # noqa: E402
from ladrc_sim.headless.runner import run, summary  # noqa: E402
from ladrc_sim.headless.scenario import load_scenario  # noqa: E402
from ladrc_tools.offline.identified_plant import (  # noqa: E402
    GAIN_B0_1,
    GAIN_PROJECT_UNITS,
    Coeffs,
    interval_cases,
    loop_figures,
)
from ladrc_tools.offline.suite import law_only  # noqa: E402

SCENARIOS = ('identified_plant', 'identified_step')
RUN_S: float | None = None  # --quick: every headless run cut to this length [s]
KEYS = ('error_rms_mm', 'error_p2p_mm', 'settling_time_s', 'overshoot_pct', 'collisions')


def with_b0(params: ControllerParams, b0: float) -> ControllerParams:
    """Return ``params`` with ``eso.b0`` replaced (through the validated dict route)."""
    d = dataclasses.asdict(params)
    d['eso']['b0'] = b0
    return params_from_dict(d)


def sim(name: str, mode: str, params: ControllerParams, **axis) -> dict:
    sc = load_scenario(name)
    sc = dataclasses.replace(sc, axis=dataclasses.replace(sc.axis, **axis))
    if RUN_S is not None:
        sc = dataclasses.replace(sc, duration_s=min(sc.duration_s, RUN_S))
    ctrl = FollowController(params, mode=mode)
    res = dict(summary(run(sc, ctrl, record_internals=True)))
    res['fault'] = ctrl.fault_reason or ''
    return res


def fmt(v) -> str:
    if isinstance(v, float):
        return 'nan' if math.isnan(v) else (f'{v:.4g}' if abs(v) < 1e4 else f'{v:.3e}')
    return str(v)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--long-s', type=float, default=0.0,
                    help='also follow a flat sheet this long on the nominal plant (slow mode)')
    ap.add_argument('--quick', action='store_true',
                    help='runs cut to 0.5 s, part 3 on the nominal plant only (a smoke test)')
    args = ap.parse_args()
    global RUN_S
    if args.quick:
        RUN_S = 0.5
    t0 = time.perf_counter()
    # the laws on the identified plant: the edge verification's moves up off (docs/safety.md
    # has what they cost on the shipped scenarios)
    base = law_only(ControllerParams())
    out: dict = {}

    # 1. linear loop
    print('1. linear loop of the shipped set (loop.analyse): PM deg, crossover Hz, delay margin'
          ' ms, Ms, slowest closed-loop pole rad/s')
    cases = [('first-order axis (sim default)', None, 1.0, 1.0),
             ('identified, gain 1/16.75 (b = 1)', Coeffs(), GAIN_B0_1, 1.0),
             ('identified, gain 0.01 (b = 0.1675)', Coeffs(), GAIN_PROJECT_UNITS, 1.0),
             ('  same, eso.b0 = 0.1675', Coeffs(), GAIN_PROJECT_UNITS, 0.1675),
             ('identified, gain 1 (b = 16.75)', Coeffs(), 1.0, 1.0),
             ('  same, eso.b0 = 16.75', Coeffs(), 1.0, 16.75)]
    loop_rows = {}
    for mode in ('ladrc', 'pid'):
        for label, coeffs, gain, b0 in cases:
            if mode == 'pid' and b0 != 1.0:
                continue                                  # the PID has no b0
            p = with_b0(base, b0)
            if coeffs is None:
                f = dict(analyse_params(p, AxisModel(), mode).figures())
                f['slow_pole_rad_s'] = float('nan')
            else:
                f = loop_figures(p, coeffs, gain, mode)
            loop_rows[(mode, label)] = f
            print(f'  {mode:5s} {label:36s} PM {f["phase_margin_deg"]:6.1f}  fc'
                  f' {f["crossover_hz"]:6.2f}  DM {f["delay_margin_ms"]:6.2f}  Ms'
                  f' {f["ms_peak"]:5.2f}  slow pole {f["slow_pole_rad_s"]:+.4f}'
                  f'  stable(|z|<1) {f["stable"]}')
    out['ladrc_pm_deg_gain_b0_1'] = round(loop_rows[('ladrc', cases[1][0])]['phase_margin_deg'], 2)
    out['ladrc_pm_deg_gain_1'] = round(loop_rows[('ladrc', cases[4][0])]['phase_margin_deg'], 2)
    out['ladrc_dm_ms_gain_1'] = round(loop_rows[('ladrc', cases[4][0])]['delay_margin_ms'], 3)
    out['ladrc_fc_hz_gain_1'] = round(loop_rows[('ladrc', cases[4][0])]['crossover_hz'], 2)
    out['ladrc_fc_hz_gain_0_01'] = round(loop_rows[('ladrc', cases[2][0])]['crossover_hz'], 3)
    out['slow_pole_rad_s'] = round(loop_rows[('ladrc', cases[1][0])]['slow_pole_rad_s'], 5)
    out['plant_zero_rad_s'] = round(Coeffs().zero_rad_s(), 5)

    # 2. gains in closed loop
    print('2. headless runs (ladrc simulate NAME metrics) at other gains')
    runs = [('gain 1/16.75', {}, 1.0), ('gain 0.01', {'identified_gain': 0.01}, 1.0),
            ('gain 0.01, eso.b0 0.1675', {'identified_gain': 0.01}, 0.1675),
            ('gain 1', {'identified_gain': 1.0}, 1.0),
            ('gain 1, eso.b0 16.75', {'identified_gain': 1.0}, 16.75),
            ('gain 1, dead 1 tick', {'identified_gain': 1.0, 'dead_time_ticks': 1}, 1.0),
            ('gain 1, dead 2 ticks', {'identified_gain': 1.0, 'dead_time_ticks': 2}, 1.0)]
    print(f'  {"scenario":17s} {"mode":5s} {"case":26s} ' + ' '.join(f'{k:>15s}' for k in KEYS)
          + '  fault')
    gains = {}
    for name in SCENARIOS:
        for mode in ('ladrc', 'pid'):
            for label, axis, b0 in runs:
                if mode == 'pid' and b0 != 1.0:
                    continue
                r = sim(name, mode, with_b0(base, b0), **axis)
                gains[(name, mode, label)] = r
                print(f'  {name:17s} {mode:5s} {label:26s} '
                      + ' '.join(f'{fmt(r[k]):>15s}' for k in KEYS) + f'  {r["fault"][:50]}')
    g = gains
    out['plant_rms_mm_ladrc'] = round(g[('identified_plant', 'ladrc', 'gain 1/16.75')]
                                      ['error_rms_mm'], 5)
    out['plant_rms_mm_pid'] = round(g[('identified_plant', 'pid', 'gain 1/16.75')]
                                    ['error_rms_mm'], 5)
    out['plant_rms_mm_ladrc_gain_1'] = round(g[('identified_plant', 'ladrc', 'gain 1')]
                                             ['error_rms_mm'], 5)
    out['pid_gain_1_collisions'] = int(g[('identified_plant', 'pid', 'gain 1')]['collisions'])
    out['pid_gain_1_fault'] = g[('identified_plant', 'pid', 'gain 1')]['fault']
    out['ladrc_gain_1_dead_2_fault'] = g[('identified_plant', 'ladrc', 'gain 1, dead 2 ticks')][
        'fault']

    # 3. interval ends
    print("3. the notes' ±1σ interval ends (gain 1/16.75), loop figures and headless runs")
    print(f'  {"case":8s} {"zero":>8s} {"poles":>22s} {"PM":>6s} {"slow":>8s} '
          + ' '.join(f'{s[:14] + " " + m:>20s}' for s in SCENARIOS for m in ('ladrc', 'pid')))
    worst = {}
    for label, coeffs in interval_cases()[:1 if args.quick else None]:
        lf = loop_figures(base, coeffs, GAIN_B0_1, 'ladrc')
        poles = coeffs.poles_rad_s()
        cells = []
        for name in SCENARIOS:
            for mode in ('ladrc', 'pid'):
                r = sim(name, mode, base, **coeffs.axis_kwargs())
                key = 'error_rms_mm'
                cells.append(f'{r[key]:.5f}' + ('!' if r['collisions'] or r['fault'] else ''))
                w = worst.setdefault((name, mode), [math.inf, -math.inf])
                w[0], w[1] = min(w[0], r[key]), max(w[1], r[key])
        ps = ', '.join(f'{p.real:+.3f}{p.imag:+.3f}j' if abs(p.imag) > 1e-12 else f'{p.real:+.3f}'
                       for p in poles)
        print(f'  {label:8s} {coeffs.zero_rad_s():+8.4f} {ps:>22s} {lf["phase_margin_deg"]:6.2f}'
              f' {lf["slow_pole_rad_s"]:+8.4f} ' + ' '.join(f'{c:>20s}' for c in cells))
    print('  (cells: error RMS, mm; "!" = collision or fault)')
    for (name, mode), (lo, hi) in worst.items():
        out[f'{name}_{mode}_rms_range_mm'] = [round(lo, 5), round(hi, 5)]

    if args.long_s > 0:
        from ladrc_sim.headless.scenario import scenario_from_dict
        sc = scenario_from_dict({
            'name': 'identified_long', 'duration_s': args.long_s, 'seed': 1,
            'initial_gap_mm': 1.0, 'axis': {'model': 'identified'},
            'sensor': {'noise_std_mm': 0.005, 'quant_mm': 0.001},
            'timeline': [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}]})
        r = run(sc, FollowController(base, mode='ladrc'), record_internals=True)
        tail = r.command_mm_s[-int(10.0 / r.h_s):]
        out['long_s'] = args.long_s
        out['long_error_rms_mm'] = round(float(r.metrics.error_rms_mm), 5)
        out['long_last10s_mean_command_mm_s'] = round(float(tail.mean()), 5)
        print(f'4. {args.long_s:g} s on a flat sheet, nominal plant: error RMS'
              f' {out["long_error_rms_mm"]} mm, mean command over the last 10 s'
              f' {out["long_last10s_mean_command_mm_s"]} mm/s')
    out['runtime_s'] = round(time.perf_counter() - t0, 1)
    print(json.dumps(out))


if __name__ == '__main__':
    main()
