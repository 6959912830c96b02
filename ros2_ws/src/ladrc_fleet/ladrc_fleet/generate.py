"""A fleet to test the fleet tools on: bags of M simulated machines over D days.

Every bag is a headless run (``ladrc_sim.headless.runner.run``, the follow controller) of a
short production-like scenario: an approach from 10 mm, following at 1 mm over a wavy sheet
with the beam on, and one crossing of a sheet edge (half the nozzle off the sheet for a
moment). Each bag says where it comes from (bags/provenance.py): its machine id, its
wall-clock start on its day (shifts from 06:00, real dates) and the hash of its parameter set;
it carries no ``sim/truth`` (a real fleet has none) and no timing but the tick period (the
headless runner knows no other).

Machines differ a little (axis time constant, sensor gain and noise, drawn per machine); a few
degrade on purpose, each in one way (:data:`DEGRADATIONS`), and on ``change_day`` every
machine gets a new parameter set (``law.kp`` raised). What was done to which machine is
written apart (``fleet_truth.json``) and never read by the fleet tool.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
import datetime as dt
import json
from pathlib import Path
from typing import Any

from ladrc_contract.schema import field_problems, param
import numpy as np

DEGRADATIONS = {
    'gain_drift': 'the sensor gain drifts from 1 to 1 - gain_drift over the days',
    'slow_axis': 'from the middle day on, the axis velocity loop is slow_axis_factor x slower',
    'noisy_sensor': 'from the middle day on, the sensor noise is noisy_factor x larger',
}
"""How a degraded machine degrades (one way per machine)."""


@dataclass(frozen=True)
class FleetSpec:
    """What to generate (``ladrc fleet-gen``'s options are these fields)."""

    machines: int = param(8, '1', 'machines in the fleet', ge=1, le=999)
    days: int = param(5, 'day', 'days recorded', ge=1, le=366)
    bags_per_day: int = param(4, '1', 'bags per machine and day', ge=1, le=24)
    bag_s: float = param(8.0, 's', 'length of a bag', ge=4.0, le=3600.0)
    seed: int = param(1, '', 'seed of the fleet (machines, degradations, sheets)', ge=0)
    first_day: str = param('2026-11-02', '', 'the first day, YYYY-MM-DD (UTC)')
    change_day: int = param(3, 'day', 'index of the day the new parameter set arrives '
                            '(>= days: none)', ge=0, le=10000)
    degraded: tuple[str, ...] = tuple(DEGRADATIONS)
    gain_drift: float = param(0.15, '1', 'gain_drift: the gain lost by the last day', ge=0.0,
                              lt=0.9)
    slow_axis_factor: float = param(4.0, '1', 'slow_axis: T1 multiplied by this', ge=1.0,
                                    le=100.0)
    noisy_factor: float = param(4.0, '1', 'noisy_sensor: noise multiplied by this', ge=1.0,
                                le=100.0)
    kp_before: float = param(10.0, '1/s', 'law.kp before the change day', gt=0.0, le=1000.0)
    kp_after: float = param(14.0, '1/s', 'law.kp from the change day on', gt=0.0, le=1000.0)
    storage: str = param('mcap', '', 'bag storage', choices=('mcap', 'sqlite3'))

    def __post_init__(self) -> None:
        problems = field_problems(self)
        if len(self.degraded) > self.machines:
            problems.append(f'{len(self.degraded)} degradations need as many machines')
        unknown = set(self.degraded) - set(DEGRADATIONS)
        if unknown:
            problems.append(f'unknown degradation(s): {", ".join(sorted(unknown))}')
        try:
            dt.date.fromisoformat(self.first_day)
        except (TypeError, ValueError):
            problems.append(f'first_day must be YYYY-MM-DD, got {self.first_day!r}')
        if problems:
            raise ValueError('; '.join(problems))


CLI_FIELDS = ('machines', 'days', 'bags_per_day', 'bag_s', 'seed', 'first_day', 'change_day')
"""The :class:`FleetSpec` fields ``ladrc fleet-gen`` offers as options."""


@dataclass(frozen=True)
class BagPlan:
    """One bag to write: its file name, provenance, scenario and controller gain."""

    name: str
    machine_id: str
    start_utc: str
    day: int
    scenario: dict[str, Any]
    kp: float
    storage: str = 'mcap'


@dataclass
class FleetPlan:
    """Every bag of the fleet and the truth about its machines (written apart)."""

    bags: list[BagPlan] = field(default_factory=list)
    truth: dict[str, Any] = field(default_factory=dict)


def machine_id(k: int) -> str:
    """Return the id of machine ``k`` (0-based): ``cutter-01`` ..."""
    return f'cutter-{k + 1:02d}'


def plan(spec: FleetSpec) -> FleetPlan:
    """Return every bag of ``spec``'s fleet: deterministic for its seed."""
    rng = np.random.default_rng(spec.seed)
    day0 = dt.datetime.fromisoformat(spec.first_day).replace(tzinfo=dt.timezone.utc)
    ids = [machine_id(k) for k in range(spec.machines)]
    victims = rng.choice(spec.machines, size=len(spec.degraded), replace=False)
    degraded = {ids[int(k)]: how for k, how in zip(victims, spec.degraded, strict=True)}
    base = {m: {'t1_s': 0.008 * rng.uniform(0.9, 1.1), 'gain': rng.uniform(0.99, 1.01),
                'noise_mm': 0.005 * rng.uniform(0.8, 1.2)} for m in ids}
    mid = spec.days // 2
    out = FleetPlan(truth={'spec': asdict(spec), 'degraded': degraded, 'machines': base,
                           'change_day': (day0 + dt.timedelta(days=spec.change_day)).date()
                           .isoformat() if spec.change_day < spec.days else None})
    for m in ids:
        how = degraded.get(m)
        for d in range(spec.days):
            b = dict(base[m])
            if how == 'gain_drift':
                b['gain'] *= 1.0 - spec.gain_drift * d / max(spec.days - 1, 1)
            elif how == 'slow_axis' and d >= mid:
                b['t1_s'] *= spec.slow_axis_factor
            elif how == 'noisy_sensor' and d >= mid:
                b['noise_mm'] *= spec.noisy_factor
            kp = spec.kp_after if d >= spec.change_day else spec.kp_before
            for j in range(spec.bags_per_day):
                start = day0 + dt.timedelta(days=d, hours=6 + 2 * j,
                                            minutes=float(rng.uniform(0, 60)))
                seed = int(rng.integers(1, 2**31 - 1))
                name = f'{m}_{start:%Y%m%d_%H%M%S}'
                out.bags.append(BagPlan(name, m, start.strftime('%Y-%m-%dT%H:%M:%SZ'), d,
                                        _scenario(name, spec.bag_s, seed, b, rng), kp,
                                        spec.storage))
    return out


def _scenario(name: str, bag_s: float, seed: int, machine: dict[str, float],
              rng: np.random.Generator) -> dict[str, Any]:
    """Return one bag's scenario: approach, follow a wavy sheet, cross an edge."""
    edge_t = float(rng.uniform(0.45, 0.6) * bag_s)
    return {
        'name': name, 'duration_s': bag_s, 'seed': seed, 'initial_gap_mm': 10.0,
        'axis': {'t1_s': machine['t1_s']},
        'sensor': {'noise_std_mm': machine['noise_mm'], 'quant_mm': 0.001,
                   'gain': machine['gain']},
        'sheet': {'profiles': [{'kind': 'waviness', 'rms_mm': float(rng.uniform(0.1, 0.2)),
                                'cutoff_hz': 1.5}]},
        'timeline': [
            {'t_s': 0.2, 'do': 'start_follow', 'target_gap_mm': 1.0},
            {'t_s': 1.5, 'do': 'machining', 'on': True},
            {'t_s': edge_t, 'do': 'coverage', 'value': 0.5, 'ramp_s': 0.2},
            {'t_s': edge_t + 0.8, 'do': 'coverage', 'value': 1.0, 'ramp_s': 0.2},
            {'t_s': bag_s - 0.5, 'do': 'machining', 'on': False}],
    }


def write_bag(item: BagPlan, out_dir: str | Path) -> str:
    """Run one planned bag headless and write it under ``out_dir/<machine>/``; return its path.

    A bag already there is kept (a re-run completes a fleet; the writer renames a bag into
    place only when complete).
    """
    from ladrc_bags import write_run_bag
    from ladrc_bags.provenance import MACHINE_KEY, START_KEY
    from ladrc_follow import FollowController, dump_params, params_from_dict
    from ladrc_sim import run, scenario_from_dict
    import yaml

    path = Path(out_dir) / item.machine_id / item.name
    if path.exists():
        return str(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    params = params_from_dict({'law': {'kp': item.kp}})
    result = run(scenario_from_dict(item.scenario), FollowController(params),
                 record_internals=True)
    write_run_bag(result, path, dump_params(params), yaml.safe_dump(item.scenario,
                                                                   sort_keys=False),
                  storage=item.storage, controller='ladrc', truth=False,
                  provenance={MACHINE_KEY: item.machine_id, START_KEY: item.start_utc})
    return str(path)


def write_truth(fleet: FleetPlan, out_dir: str | Path) -> Path:
    """Write what was done to which machine (``fleet_truth.json``), apart from the bags."""
    p = Path(out_dir) / 'fleet_truth.json'
    p.write_text(json.dumps(fleet.truth, indent=1, sort_keys=True) + '\n', encoding='utf-8')
    return p
