"""The closed loop of N controllers at once: one scenario, one axis per parameter set (numpy).

For sweeps over parameter sets (issue 14): the state machine is not needed inside a sweep, so
each row starts followed (the nozzle at the target gap, the controller reset there) and holds
the scenario's first target. The world is the headless runner's (:mod:`.runner`), drawn
from the same seed in the same order, so one row sees what a scalar run sees: the sheet's
profiles, the sensor's gain schedule, noise, lag, quantization and range, the encoder's
resolution, the first-order axis with its limits and dead time. The axis, sensor and encoder
arithmetic is that of the models' scalar code written on arrays, operation for operation, so
a row equals the scalar models bit for bit (``tests/sim/test_batch.py``).

The controller is any object with ``reset(gap_mm, u_prev_mm_s, target_mm, encoder_mm)`` and
``step(gap_mm, encoder_mm, target_mm) -> u`` on arrays of N rows (``LADRC.batch``); the
simulator does not import the controller package.

Not in a batch (:class:`BatchUnsupported` says which): the thin-sheet plate (it couples to the
nozzle), coverage below 1 (the edge model), dropouts, freezes, encoder glitches, the
identified plant, and timeline commands other than ``set_target`` (which takes effect at its
tick in every row).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path
import time
from typing import Any

import numpy as np

from ..models.axis import H_S
from .runner import draw_world
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
    wall_s: float

    @property
    def realtime_x(self) -> float:
        """Simulated seconds per wall second, all rows together."""
        n_rows = self.true_gap_mm.shape[1]
        return self.t_s.size * H_S * n_rows / self.wall_s if self.wall_s > 0 else math.inf


_WORLD_EVENTS = ('sensor_gain', 'set_target')  # laid out as per-tick arrays


def check_batchable(sc: Scenario) -> float:
    """Return the scenario's follow target; :class:`BatchUnsupported` if it is not batchable."""
    why = []
    if sc.axis.model != 'first_order':
        why.append(f'axis model {sc.axis.model}')
    if any(type(p).__name__ == 'PlateParams' for p in sc.sheet.profiles):
        why.append('the thin-sheet plate')
    if sc.initial_coverage < 1.0:
        why.append('coverage below 1')
    starts = [e for e in sc.timeline if e.name == 'start_follow']
    others = sorted({e.name for e in sc.timeline
                     if e.name not in _WORLD_EVENTS + ('start_follow',)})
    if others:
        why.append('timeline events ' + ', '.join(others))
    if len(starts) != 1:
        why.append(f'{len(starts)} start_follow events (one is needed)')
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
            continue  # the plate, the edges, the fault scenario (module docstring)
    return out


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
    sheet, sensor = draw_world(sc, n, h_s)  # the runner's world
    base = sheet.base_mm
    s_gain, s_noise, s_alpha = sensor._gain, sensor._noise, sensor._alpha
    s_q, s_rmax, s_rmin = sc.sensor.quant_mm, sc.sensor.range_max_mm, sc.sensor.range_min_mm
    e_res = sc.encoder.resolution_mm
    ap = sc.axis
    a = math.exp(-h_s / ap.t1_s)  # models/axis.py, exact ZOH of b0/(s(T1 s + 1))
    kv, kxv = (1.0 - a) * ap.b0, ap.t1_s * (1.0 - a)
    kxu = ap.b0 * (h_s - ap.t1_s * (1.0 - a))
    u_max, dv_max, half_h = ap.v_max_mm_s / ap.b0, ap.a_max_mm_s2 * h_s, 0.5 * h_s
    delay = [np.zeros(n_rows) for _ in range(ap.dead_time_ticks)]
    k_delay = 0

    x = np.full(n_rows, float(base[0]) + target)  # followed: the nozzle at the target gap
    v = np.zeros(n_rows)
    s_y: np.ndarray | None = None
    r_gap = np.empty((n, n_rows))
    r_cmd = np.empty((n, n_rows))
    enc0 = np.round(x / e_res) * e_res if e_res > 0.0 else x.copy()
    controller.reset(np.full(n_rows, target), np.zeros(n_rows), target, enc0)
    wall0 = time.perf_counter()
    for i in range(n):
        gap = x - base[i]
        # Sensor.measure at full coverage (models/sensor.py), on arrays
        r = gap * s_gain[i]
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
        # Axis.step, first-order model (models/axis.py), on arrays
        u = np.where(u > u_max, u_max, np.where(u < -u_max, -u_max, np.where(u == u, u, 0.0)))
        v1 = a * v + kv * u
        dv = v1 - v
        inside = (-dv_max <= dv) & (dv <= dv_max)
        v_lim = v + np.where(dv > 0.0, dv_max, -dv_max)
        x = np.where(inside, x + kxv * v + kxu * u, x + half_h * (v + v_lim))
        v = np.where(inside, v1, v_lim)
    wall = time.perf_counter() - wall0
    return BatchResult(np.arange(n) * h_s, r_gap, r_cmd, targets, wall)
