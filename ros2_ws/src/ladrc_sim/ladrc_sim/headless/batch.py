"""The closed loop of N controllers at once: one scenario, one axis per parameter set (numpy).

For sweeps over parameter sets: the state machine is not needed inside a sweep, so
each row starts followed (the nozzle at the gap that reads the target, the controller reset
there) and holds the scenario's first target. The world is the headless runner's
(:mod:`.runner`), drawn from the same seed in the same order, so one row sees what a scalar
run sees: the sheet's profiles, the thin-sheet plate (one plate per row: the gas push couples
it to that row's nozzle), the edge (coverage schedule, fringe model and ripple), the sensor's
gain schedule, noise, lag, quantization and range, the encoder's resolution, the first-order
axis with its limits and dead time. The axis, plate and sensor edge steps are the models' own
functions (``first_order_step``, ``plate_step``, ``gas_push_mm_s2``, ``edge_gap_mm``) run on
rows with the array backend (``ladrc_contract.ops``); the sensor's gain, lag, noise,
quantization and range and the encoder's resolution are written here on arrays, operation for
operation as ``Sensor.measure`` and ``Encoder.read``; a row equals the scalar models bit for
bit (``tests/sim/test_batch.py``).

The controller is any object with ``reset(gap_mm, u_prev_mm_s, target_mm, encoder_mm)`` and
``step(gap_mm, encoder_mm, target_mm) -> u`` on arrays of N rows (``LADRC.batch``); the
simulator does not import the controller package.

Not in a batch (:class:`BatchUnsupported` says which), because each is the follow state
machine's business, not the law's: a start away from the sheet (approach), coverage below the
sensor's ``min_coverage`` (miss-panel), dropouts, freezes, encoder glitches, drive events, the
machining flag (it hands the axis to the PID), the identified plant, and commands other than
``start_follow`` / ``set_target`` (which takes effect at its tick in every row), e.g. the
controller's ``target_wave``.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path
import time
from typing import Any

from ladrc_contract.ops import ARRAY
import numpy as np
from scipy.optimize import brentq

from ..models.axis import H_S, first_order, first_order_step
from ..models.sensor import Sensor, edge_gap_mm
from ..models.sheet import _first_tick, gas_push_mm_s2, plate_step
from .runner import draw_world, schedule
from .scenario import Scenario, list_scenarios, load_scenario


class BatchUnsupported(ValueError):
    """The scenario uses something the batch loop does not model; the message says what."""


@dataclass
class BatchResult:
    """Per-row series (ticks x N) and the wall time."""

    t_s: np.ndarray
    true_gap_mm: np.ndarray      # (n, N)
    command_mm_s: np.ndarray     # (n, N)
    target_gap_mm: np.ndarray    # (n,) the target of each tick
    coverage: np.ndarray         # (n,) the edge coverage of each tick
    wall_s: float

    @property
    def realtime_x(self) -> float:
        """Simulated seconds per wall second, all rows together."""
        n_rows = self.true_gap_mm.shape[1]
        return self.t_s.size * H_S * n_rows / self.wall_s if self.wall_s > 0 else math.inf


# laid out as per-tick arrays before the loop
_WORLD_EVENTS = ('sensor_gain', 'set_target', 'coverage', 'gas', 'plate_kick')


def check_batchable(sc: Scenario) -> float:
    """Return the scenario's follow target; :class:`BatchUnsupported` if it is not batchable."""
    why = []
    if sc.axis.model != 'first_order':
        why.append(f'axis model {sc.axis.model}')
    covs = [sc.initial_coverage] + [e.args['value'] for e in sc.timeline
                                    if e.name == 'coverage']
    if min(covs) < sc.sensor.min_coverage:
        why.append(f'coverage {min(covs):g} below min_coverage {sc.sensor.min_coverage:g} '
                   '(miss-panel)')
    starts = [e for e in sc.timeline if e.name == 'start_follow']
    others = sorted({e.name for e in sc.timeline
                     if e.name not in _WORLD_EVENTS + ('start_follow',)})
    if others:
        why.append('timeline events ' + ', '.join(others))
    if len(starts) != 1:
        why.append(f'{len(starts)} start_follow events (one is needed)')
    elif starts[0].t_s > 0.0 or abs(sc.initial_gap_mm - starts[0].args['target_gap_mm']) > 1.0:
        why.append(f'an approach from {sc.initial_gap_mm:g} mm (follow starts at '
                   f'{starts[0].t_s:g} s to {starts[0].args["target_gap_mm"]:g} mm)')
    if why:
        raise BatchUnsupported(f'scenario {sc.name}: not batchable ({"; ".join(why)})')
    return float(starts[0].args['target_gap_mm'])


def batchable_scenarios() -> list[str]:
    """Return the names of the library scenarios the batch loop models."""
    out = []
    for f in sorted(list_scenarios(), key=lambda q: q.stem):
        try:
            check_batchable(load_scenario(f.stem))
            out.append(f.stem)
        except BatchUnsupported:
            continue  # an approach, a miss-panel, the fault scenario (module docstring)
    return out


def followed_gap_mm(sensor: Sensor, target_mm: float, coverage: float) -> float:
    """Return the true gap whose edge-model reading is ``target_mm`` (``target`` at c = 1)."""
    if coverage >= 1.0:
        return target_mm
    # the reading is monotonic in the gap and >= it (models/sensor.py), so the root is in
    # [0, target]
    return float(brentq(lambda g: sensor.apparent_gap_mm(g, coverage) - target_mm,
                        0.0, target_mm, xtol=1e-12))


def plate_schedule(sc: Scenario, n: int, h_s: float) -> tuple[list[float], list[bool],
                                                               list[float]]:
    """Per tick: timeline kick before the tick, gas on in the plate step, the plate's kick.

    The runner's rules (runner.run, Plate.step), which do not depend on the nozzle, so every
    row shares them: ``gas`` events switch the gas and end its automatic start at
    ``gas_on_s``; ``plate_kick`` events add to the plate's velocity at the start of their tick;
    the plate's own kick is added in its step at ``kick_t_s``.
    """
    kick_before, gas, kick_own = [0.0] * n, [False] * n, [0.0] * n
    plate = next((p for p in sc.sheet.profiles if type(p).__name__ == 'PlateParams'), None)
    if plate is None:
        return kick_before, gas, kick_own
    gas_events: dict[int, list] = {}
    for e in sc.timeline:
        if e.name in ('gas', 'plate_kick'):
            gas_events.setdefault(min(n - 1, int(round(e.t_s / h_s))), []).append(e)
    i_gas = _first_tick(plate.gas_on_s, h_s)
    i_kick = -1 if plate.kick_t_s is None else _first_tick(plate.kick_t_s, h_s)
    gas_on, gas_auto = i_gas == 0, True
    for i in range(n):
        for e in gas_events.get(i, ()):
            if e.name == 'plate_kick':
                kick_before[i] += e.args['velocity_mm_s']
            else:
                gas_on, gas_auto = e.args['on'], False
        if gas_auto and not gas_on and i >= i_gas:
            gas_on = True
        gas[i] = gas_on
        if i == i_kick:
            kick_own[i] = plate.kick_velocity_mm_s
    return kick_before, gas, kick_own


def run_batch(scenario: Scenario | str | Path, controller: Any, n_rows: int, *,
              h_s: float = H_S) -> BatchResult:
    """Run ``controller`` (N rows) through ``scenario``, every row starting followed."""
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    target = check_batchable(sc)
    n = int(round(sc.duration_s / h_s))
    targets = np.full(n, target)  # set_target takes effect at its tick, as in the runner
    for e in sorted((e for e in sc.timeline if e.name == 'set_target'), key=lambda e: e.t_s):
        targets[min(n - 1, int(round(e.t_s / h_s))):] = e.args['target_gap_mm']
    targets_l = targets.tolist()
    cov = schedule(n, h_s, sc.initial_coverage,
                   [(e.t_s, e.args['value'], e.args['ramp_s']) for e in sc.timeline
                    if e.name == 'coverage'])
    cov_l = cov.tolist()
    sheet, sensor = draw_world(sc, n, h_s)  # the runner's world
    base = sheet.base_mm
    s_gain, s_noise, s_alpha = sensor.gain.tolist(), sensor.noise_mm.tolist(), sensor.alpha
    s_q, s_rmax, s_rmin = sc.sensor.quant_mm, sc.sensor.range_max_mm, sc.sensor.range_min_mm
    # the edge model on rows: its tables as arrays (Sensor.measure indexes lists)
    edge = sensor.edge._replace(cum=np.asarray(sensor.edge.cum), eps=np.asarray(sensor.edge.eps))
    e_res = sc.encoder.resolution_mm
    axis = first_order(sc.axis, h_s)  # models/axis.py, exact ZOH of b0/(s(T1 s + 1))
    delay = [np.zeros(n_rows) for _ in range(sc.axis.dead_time_ticks)]
    k_delay = 0
    plate = sheet.plate
    if plate is not None:
        plate_c = plate.coefficients()
        p_k, p_g0 = plate.gas_k, plate.gas_g0
        kick_before, gas_l, kick_own = plate_schedule(sc, n, h_s)
    p_y = np.zeros(n_rows)  # the plate of each row (Plate.y_mm, v_mm_s)
    p_v = np.zeros(n_rows)

    gap0 = followed_gap_mm(sensor, target, cov_l[0])
    x = np.full(n_rows, float(base[0]) + gap0)  # followed: the nozzle reads the target
    v = np.zeros(n_rows)
    s_y: np.ndarray | None = None
    r_gap = np.empty((n, n_rows))
    r_cmd = np.empty((n, n_rows))
    enc0 = np.round(x / e_res) * e_res if e_res > 0.0 else x.copy()
    controller.reset(np.full(n_rows, target), np.zeros(n_rows), target, enc0)
    wall0 = time.perf_counter()
    for i in range(n):
        if plate is not None:
            if kick_before[i] != 0.0:
                p_v = p_v + kick_before[i]  # a timeline plate_kick (Plate.kick)
            gap = x - (base[i] + p_y)
        else:
            gap = x - base[i]
        # Sensor.measure (models/sensor.py), on arrays
        c = cov_l[i]
        if c >= 1.0:
            r = gap * s_gain[i]
        else:  # the edge model; c >= min_coverage (check_batchable)
            r = edge_gap_mm(ARRAY, gap, c, edge) * s_gain[i]
        if s_alpha != 0.0:
            r = r if s_y is None else s_alpha * s_y + (1.0 - s_alpha) * r
            s_y = r
        r = r + s_noise[i]
        if s_q > 0.0:
            r = np.round(r / s_q) * s_q
        reading = np.clip(r, s_rmin, s_rmax)  # out of range: saturated (and invalid)
        enc = np.round(x / e_res) * e_res if e_res > 0.0 else x
        u = controller.step(reading, enc, targets_l[i])
        r_gap[i] = gap
        r_cmd[i] = u
        if delay:  # Axis.step's dead time: the command of dead_time_ticks ago
            u, delay[k_delay] = delay[k_delay], u
            k_delay = k_delay + 1 if k_delay + 1 < len(delay) else 0
        x, v = first_order_step(ARRAY, axis, x, v, u)  # Axis.step (models/axis.py)
        if plate is not None:
            # Plate.step (models/sheet.py): gas push held at this tick's gap, per row
            if kick_own[i] != 0.0:
                p_v = p_v + kick_own[i]
            pa = gas_push_mm_s2(ARRAY, gap, p_k, p_g0) if gas_l[i] else 0.0
            p_y, p_v = plate_step(plate_c, p_y, p_v, pa)
    wall = time.perf_counter() - wall0
    return BatchResult(np.arange(n) * h_s, r_gap, r_cmd, targets, cov, wall)
