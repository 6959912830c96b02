"""Identification bags from the headless sim: an excitation played on a scenario.

``ladrc excite`` (and the tests) use this: a scenario (the built-in :data:`IDENTIFY_SCENARIO`,
a scenario file or a shipped name) as a dict, with ``--set key=value`` overrides
(:func:`apply_overrides`, e.g. ``axis.b0=1.3``, ``axis.t1_s=0.004``,
``axis.dead_time_ticks=6``, ``sensor.lag_s=0.001``), validated by the scenario loader itself
(``scenario_from_dict``: one-line errors naming the key); the :class:`.ExcitationPlayer` as the
controller of ``ladrc_sim.headless.runner.run``; and the bag written by the one bag writer of
headless runs (``bags.bag.write_run_bag``, as ``ladrc simulate -o``), so an identification bag
has the layout of any other (``axis/velocity_command``, ``axis/feedback``,
``axis/capacitive_height``, ``sim/truth``; the overridden scenario as ``run/scenario``).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

import yaml

from .excitation import H_S, Excitation
from .player import ExcitationPlayer, PlayerLimits

IDENTIFY_SCENARIO: dict[str, Any] = {
    'name': 'identify_axis',
    'description': 'Axis identification: an excitation played 5 mm above a flat sheet, no '
                   'follow controller (ladrc excite).',
    'seed': 1,
    'initial_gap_mm': 5.0,
    'sensor': {'noise_std_mm': 0.005, 'quant_mm': 0.001},
}
"""The built-in identification scenario: the sim's default axis and encoder, the shipped
scenarios' sensor noise (5 µm) and quantization (1 µm), a flat sheet, 5 mm below the nozzle.
Its ``duration_s`` is set to the settle time + the excitation + ``TAIL_S``."""

TAIL_S = 0.1
"""Rest after the excitation, so the bag shows the axis stopped at its start."""


class SimRunError(ValueError):
    """A bad scenario, override or excitation; the message is one line."""


def _one_line(text: str) -> str:
    return ' '.join(str(text).split())


def scenario_dict(source: str | Path | None) -> dict[str, Any]:
    """Return the scenario ``source`` (file, shipped name, None: built-in) as a dict."""
    if source is None:
        return copy.deepcopy(IDENTIFY_SCENARIO)
    from ladrc_sim import list_scenarios

    p = Path(source)
    if not p.exists() and p.suffix == '' and p.name == str(source):
        shipped = {q.stem: q for q in list_scenarios()}
        if p.name in shipped:
            p = shipped[p.name]
    try:
        data = yaml.safe_load(p.read_text(encoding='utf-8'))
    except OSError as exc:
        raise SimRunError(f'{source}: cannot read the scenario: {exc.strerror or exc}') from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise SimRunError(_one_line(f'{source}: not a scenario YAML file: {exc}')) from None
    if not isinstance(data, dict):
        raise SimRunError(f'{source}: a scenario file is a mapping of keys')
    return data


def apply_overrides(data: dict[str, Any], sets: Iterable[str]) -> dict[str, Any]:
    """Return a copy of the scenario dict with ``key.sub=value`` overrides (YAML values).

    ``axis.b0=1.3`` sets ``data['axis']['b0'] = 1.3``; the value is read as YAML
    (``true``, ``0.004``, ``6``). Keys and values are checked by the scenario loader.
    """
    out = copy.deepcopy(data)
    for item in sets:
        key, sep, text = str(item).partition('=')
        key = key.strip()
        if not sep or not key or any(not part for part in key.split('.')):
            raise SimRunError(f'--set {item!r}: expected KEY=VALUE, e.g. axis.b0=1.3')
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError:
            raise SimRunError(f'--set {item!r}: the value is not valid YAML') from None
        node = out
        *head, last = key.split('.')
        for part in head:
            nxt = node.get(part)
            if nxt is None:
                nxt = node[part] = {}
            if not isinstance(nxt, dict):
                raise SimRunError(f'--set {item!r}: {part} is not a section')
            node = nxt
        node[last] = value
    return out


@dataclass
class ExcitationRun:
    """A played excitation: the run result (``RunResult``), the player, the scenario text."""

    result: Any
    player: ExcitationPlayer
    scenario_yaml: str


def run_excitation(data: dict[str, Any], excitation: Excitation,
                   limits: PlayerLimits | None = None, source: str = '') -> ExcitationRun:
    """Play ``excitation`` on the scenario dict ``data`` headless; return the run."""
    from ladrc_sim import ScenarioError, run, scenario_from_dict

    limits = limits or PlayerLimits()
    reasons = excitation.problems(H_S) + limits.problems()
    if reasons:
        raise SimRunError('excitation: ' + '; '.join(reasons))
    data = copy.deepcopy(data)
    needed = limits.settle_s + excitation.duration_s + TAIL_S
    if 'duration_s' not in data:
        data['duration_s'] = round(needed, 6)
    try:
        scenario = scenario_from_dict(data, source or str(data.get('name', 'scenario')))
    except ScenarioError as exc:
        raise SimRunError(_one_line(str(exc))) from None
    if scenario.duration_s + 1e-9 < needed:
        raise SimRunError(f'{scenario.name}: duration_s {scenario.duration_s:g} s is shorter '
                          f'than the settle time + excitation + rest ({needed:g} s)')
    if excitation.amplitude_mm_s * scenario.axis.b0 > scenario.axis.v_max_mm_s:
        raise SimRunError('excitation: the amplitude exceeds the axis velocity limit')
    player = ExcitationPlayer(excitation, limits, H_S)
    result = run(scenario, player, record_internals=True, h_s=H_S)
    text = yaml.safe_dump(data, sort_keys=False, allow_unicode=True)
    return ExcitationRun(result, player, text)


def write_bag(run_: ExcitationRun, path: str | Path, storage: str = 'mcap') -> Path:
    """Write the run as a bag with the headless bag writer (never overwrites)."""
    from ladrc_bags import write_run_bag

    return write_run_bag(run_.result, path, '', run_.scenario_yaml, storage=storage,
                         controller='excitation')
