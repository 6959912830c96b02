"""Scenario files: YAML -> :class:`Scenario` dataclasses, with one-line errors.

A scenario is a run of the closed loop: the models' parameters, the sheet profiles, the
initial state and a timeline of events (follow commands for the controller and events for
the simulated world). The layout (every key but ``name`` and ``duration_s`` optional)::

    name: sine_1hz
    description: ...
    duration_s: 6.0
    seed: 1
    initial_gap_mm: 10.0        # nozzle above the sheet at t = 0
    initial_coverage: 1.0       # fraction of the nozzle over the sheet at t = 0
    expect_fault: false         # true: the run may end in FAULT (fault injection)
    axis:    {model: first_order, t1_s: 0.008, v_max_mm_s: 200, ...}   # AxisParams
    sensor:  {noise_std_mm: 0.005, ...}                                # SensorParams
    encoder: {resolution_mm: 0.001}                                    # EncoderParams
    sheet:
      profiles:
        - {kind: sine, amp_mm: 0.5, freq_hz: 1.0}
    timeline:
      - {t_s: 0.2, do: start_follow, target_gap_mm: 1.0}

Any mistake raises :class:`ScenarioError` whose message is one line: the file, the dotted
key (``sheet.profiles[1].freq_hz``) or the YAML line, and what is wrong.
"""

from __future__ import annotations

from dataclasses import MISSING, asdict, dataclass, field, make_dataclass
import importlib.resources
import math
from pathlib import Path
from typing import Any, Mapping

from ladrc_contract.schema import (
    INVALID,
    MISSING_KEY,
    OUT_OF_RANGE,
    UNKNOWN_KEY,
    WRONG_TYPE,
    LoadError,
    Problem,
    as_mapping,
    coerce,
    load,
    param,
    type_name,
)
import yaml

from ..models.axis import AxisParams, ParamError
from ..models.encoder import EncoderParams
from ..models.sensor import SensorParams
from ..models.sheet import PROFILE_KINDS, SheetParams

REQUIRED = object()

# Commands forwarded to the controller (``controller.command(name, **args)``), with their
# arguments: name -> (type, default or REQUIRED, lower bound, upper bound).
COMMANDS: dict[str, dict[str, tuple]] = {
    'start_follow': {'target_gap_mm': (float, REQUIRED, 0.0, 20.0)},
    'set_target': {'target_gap_mm': (float, REQUIRED, 0.0, 20.0)},
    'stop_follow': {},
    'reset_fault': {},  # the CNC clears a latched FAULT (an edge, a miss-panel)
    'machining': {'on': (bool, REQUIRED, None, None)},
    'height_compensation': {'offset_mm': (float, REQUIRED, -10.0, 10.0)},
    'gradient_follow': {'target_gap_mm': (float, REQUIRED, 0.0, 20.0),
                        'delay_s': (float, 0.0, 0.0, None)},
    # a test signal on the follow target once followed (the seed's SIN_GEN)
    'target_wave': {'kind': (str, 'sine', None, None), 'amp_mm': (float, REQUIRED, 0.0, 2.0),
                    'freq_hz': (float, REQUIRED, 0.0, 100.0),
                    'freq_end_hz': (float, 0.0, 0.0, 100.0),
                    'duration_s': (float, 0.0, 0.0, 600.0)},
    # the CNC interface (docs/interfaces.md, "CNC interface"); the controller checks the rest
    'pierce': {'heights_mm': (tuple[float, ...], REQUIRED, None, None),
               'dwell_s': (tuple[float, ...], REQUIRED, None, None),
               'cut_gap_mm': (float, REQUIRED, 0.0, 20.0), 'thc_delay_s': (float, 0.0, 0.0, 60.0),
               'locked': (bool, False, None, None)},
    'lift': {'mode': (int, 0, None, None), 'value_mm': (float, REQUIRED, 0.0, 500.0),
             'velocity_mm_s': (float, 0.0, 0.0, None)},
    'hold': {'hold': (bool, REQUIRED, None, None), 'at_next_segment': (bool, False, None, None),
             'reason': (str, '', None, None)},
    'leapfrog': {'lift_mm': (float, REQUIRED, 0.0, 500.0),
                 'rapid_length_mm': (float, REQUIRED, 0.0, None),
                 'rapid_feed_mm_s': (float, REQUIRED, 0.0, None),
                 'arrive_height_mm': (float, REQUIRED, 0.0, 20.0)},
}
WAVE_KINDS = ('sine', 'chirp', 'square')
# Events acting on the simulated world (handled by the runner).
SIM_EVENTS: dict[str, dict[str, tuple]] = {
    'coverage': {'value': (float, REQUIRED, 0.0, 1.0), 'ramp_s': (float, 0.0, 0.0, None)},
    'sensor_gain': {'value': (float, REQUIRED, 0.0, 10.0), 'ramp_s': (float, 0.0, 0.0, None)},
    # error_code: the fault's CiA 402 error code (0x603F, its EMCY) on a drive on a bus
    # (ladrc_sim/cia402/can_drive.py); 0 = 0x5000 device hardware
    'drive': {'enabled': (bool, True, None, None), 'fault': (bool, False, None, None),
              'error_code': (int, 0, 0, 0xFFFF)},
    'sensor_dropout': {'duration_s': (float, REQUIRED, 0.0, None)},
    'sensor_freeze': {'duration_s': (float, REQUIRED, 0.0, None)},
    'encoder_dropout': {'duration_s': (float, REQUIRED, 0.0, None)},
    'encoder_jump': {'size_mm': (float, REQUIRED, None, None),
                     'duration_s': (float, math.inf, 0.0, None)},
    'encoder_stuck': {'duration_s': (float, REQUIRED, 0.0, None)},
    'plate_kick': {'velocity_mm_s': (float, REQUIRED, None, None)},
    'gas': {'on': (bool, REQUIRED, None, None)},
}
EVENTS = {**COMMANDS, **SIM_EVENTS}


def _args_class(event: str, schema: dict[str, tuple]) -> type:
    """Return the frozen dataclass of one event's arguments, declared from its table row."""
    return make_dataclass(f'{event}_args', [
        (k, typ, param(MISSING if default is REQUIRED else default, '', f'{event} {k}',
                       ge=lo, le=hi, inf_ok=hi is None))
        for k, (typ, default, lo, hi) in schema.items()], frozen=True, kw_only=True)


_ARGS = {name: _args_class(name, schema) for name, schema in EVENTS.items()}
"""Each event's arguments as a dataclass: the contract's loader reads them."""
# AxisFeedback.fault_reason while a 'drive' event holds the drive faulted (sim node, bags)
DRIVE_FAULT_REASON = 'drive fault (scenario event)'


class ScenarioError(ValueError):
    """A scenario file is malformed; the message is one line naming file and key."""


@dataclass(frozen=True)
class Event:
    """One timeline entry: at ``t_s`` do ``name`` with ``args`` (defaults filled in)."""

    t_s: float
    name: str
    args: Mapping[str, Any] = field(default_factory=dict)

    @property
    def is_command(self) -> bool:
        """Whether the runner forwards this event to the controller."""
        return self.name in COMMANDS


@dataclass(frozen=True)
class Scenario:
    """A closed-loop run: models, sheet, initial state and the event timeline."""

    name: str
    duration_s: float
    description: str = ''
    seed: int = 0
    initial_gap_mm: float = 10.0
    initial_coverage: float = 1.0
    axis: AxisParams = field(default_factory=AxisParams)
    sensor: SensorParams = field(default_factory=SensorParams)
    encoder: EncoderParams = field(default_factory=EncoderParams)
    sheet: SheetParams = field(default_factory=SheetParams)
    timeline: tuple[Event, ...] = ()
    source: str = ''
    expect_fault: bool = False  # the run may end in FAULT (a fault-injection scenario)


_TOP_KEYS = ('name', 'description', 'duration_s', 'seed', 'initial_gap_mm',
             'initial_coverage', 'axis', 'sensor', 'encoder', 'sheet', 'timeline',
             'expect_fault')


def _fail(path: str, reason: str, kind: str = INVALID) -> LoadError:
    """Return the loader's error for one problem the scenario's own checks found at ``path``."""
    return LoadError(Problem(path, kind, reason))


def _join(prefix: str, key: str) -> str:
    return f'{prefix}.{key}' if prefix else key


def _profile(data: Any, key: str) -> Any:
    data = as_mapping(data, key)
    if 'kind' not in data:
        raise _fail(_join(key, 'kind'),
                    f'missing required key (one of: {", ".join(PROFILE_KINDS)})', MISSING_KEY)
    kind = data['kind']
    if kind not in PROFILE_KINDS:
        raise _fail(_join(key, 'kind'),
                    f'unknown profile kind {kind!r} (one of: {", ".join(PROFILE_KINDS)})',
                    OUT_OF_RANGE)
    rest = {k: v for k, v in data.items() if k != 'kind'}
    return load(PROFILE_KINDS[kind], rest, where=key)


def _sheet(data: Any, key: str) -> SheetParams:
    data = as_mapping(data, key)
    for k in data:
        if k != 'profiles':
            raise _fail(_join(key, k), 'unknown key (allowed: profiles)', UNKNOWN_KEY)
    profs = data.get('profiles', [])
    if not isinstance(profs, list):
        raise _fail(_join(key, 'profiles'), f'expected a list, got {type_name(profs)}',
                    WRONG_TYPE)
    built = tuple(_profile(p, f'{key}.profiles[{i}]') for i, p in enumerate(profs))
    try:
        return SheetParams(profiles=built)
    except ParamError as e:
        raise _fail(_join(key, e.key), e.reason) from None


def _event(data: Any, key: str, duration_s: float) -> Event:
    data = as_mapping(data, key)
    for req in ('t_s', 'do'):
        if req not in data:
            raise _fail(_join(key, req), 'missing required key', MISSING_KEY)
    t_s = coerce(data['t_s'], float, _join(key, 't_s'))
    if not 0.0 <= t_s <= duration_s:
        raise _fail(_join(key, 't_s'),
                    f'{t_s} is outside the run (0 .. duration_s = {duration_s})', OUT_OF_RANGE)
    name = data['do']
    if name not in EVENTS:
        raise _fail(_join(key, 'do'), f'unknown event {name!r} (one of: {", ".join(EVENTS)})',
                    OUT_OF_RANGE)
    rest = {k: v for k, v in data.items() if k not in ('t_s', 'do')}
    args = asdict(load(_ARGS[name], rest, where=key))
    if name == 'target_wave' and args['kind'] not in WAVE_KINDS:
        raise _fail(_join(key, 'kind'), f'{args["kind"]!r} is not one of '
                    f'{", ".join(WAVE_KINDS)}', OUT_OF_RANGE)
    if name in ('start_follow', 'set_target', 'gradient_follow') and args['target_gap_mm'] <= 0:
        raise _fail(_join(key, 'target_gap_mm'), 'must be > 0 (a gap of 0 is contact)',
                    OUT_OF_RANGE)
    return Event(t_s=t_s, name=name, args=args)


def scenario_from_dict(data: Any, source: str = '') -> Scenario:
    """Build a :class:`Scenario` from parsed YAML; raise ScenarioError naming the key."""
    label = source or '<dict>'
    try:
        return _scenario(data, source)
    except LoadError as e:
        raise ScenarioError(' '.join(f'{label}: {e}'.split())) from None


def _scenario(data: Any, source: str) -> Scenario:
    data = as_mapping(data, '')
    for k in data:
        if k not in _TOP_KEYS:
            raise _fail(k, f'unknown key (allowed: {", ".join(_TOP_KEYS)})', UNKNOWN_KEY)
    for req in ('name', 'duration_s'):
        if req not in data:
            raise _fail(req, 'missing required key', MISSING_KEY)
    name = coerce(data['name'], str, 'name')
    duration_s = coerce(data['duration_s'], float, 'duration_s')
    if not 0.0 < duration_s <= 3600.0:
        raise _fail('duration_s', f'{duration_s} out of range, must be in (0, 3600] s',
                    OUT_OF_RANGE)
    seed = coerce(data.get('seed', 0), int, 'seed')
    if seed < 0:
        raise _fail('seed', f'{seed} must be >= 0 (numpy seeds are non-negative)',
                    OUT_OF_RANGE)
    gap0 = coerce(data.get('initial_gap_mm', 10.0), float, 'initial_gap_mm')
    if not 0.0 < gap0 <= 100.0:
        raise _fail('initial_gap_mm', f'{gap0} out of range, must be in (0, 100] mm',
                    OUT_OF_RANGE)
    cov0 = coerce(data.get('initial_coverage', 1.0), float, 'initial_coverage')
    if not 0.0 <= cov0 <= 1.0:
        raise _fail('initial_coverage', f'{cov0} out of range, must be in [0, 1]',
                    OUT_OF_RANGE)
    tl = data.get('timeline', [])
    if not isinstance(tl, list):
        raise _fail('timeline', f'expected a list of events, got {type_name(tl)}',
                    WRONG_TYPE)
    events = [_event(ev, f'timeline[{i}]', duration_s) for i, ev in enumerate(tl)]
    events.sort(key=lambda ev: ev.t_s)  # stable: same-time events keep file order
    return Scenario(
        name=name, duration_s=duration_s,
        description=coerce(data.get('description', ''), str, 'description'),
        seed=seed, initial_gap_mm=gap0, initial_coverage=cov0,
        axis=load(AxisParams, data.get('axis', {}), where='axis'),
        sensor=load(SensorParams, data.get('sensor', {}), where='sensor'),
        encoder=load(EncoderParams, data.get('encoder', {}), where='encoder'),
        sheet=_sheet(data.get('sheet', {}), 'sheet'),
        timeline=tuple(events), source=source,
        expect_fault=coerce(data.get('expect_fault', False), bool, 'expect_fault'))


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate keys (PyYAML silently keeps the last one)."""


def _construct_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False):
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f'duplicate key {key!r}', key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG,
                                 _construct_mapping)


def load_scenario(path: str | Path) -> Scenario:
    """Load a scenario file, or a shipped scenario by name (``'showcase'``)."""
    p = Path(path)
    if not p.exists() and p.suffix == '' and p.name == str(path):
        shipped = {q.stem: q for q in list_scenarios()}
        if p.name in shipped:
            p = shipped[p.name]
    label = str(path)
    try:
        text = p.read_text(encoding='utf-8')
    except OSError as e:
        raise ScenarioError(f'{label}: cannot read the file: {e.strerror or e}') from None
    except UnicodeDecodeError:
        raise ScenarioError(f'{label}: not a text (UTF-8) file') from None
    try:
        data = yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as e:
        mark = getattr(e, 'problem_mark', None)
        line = f'line {mark.line + 1}' if mark is not None else 'line ?'
        problem = getattr(e, 'problem', None) or str(e)
        ctx, ctx_mark = getattr(e, 'context', None), getattr(e, 'context_mark', None)
        if ctx and ctx_mark is not None:
            problem += f' ({ctx} at line {ctx_mark.line + 1})'
        raise ScenarioError(' '.join(f'{label}: {line}: bad YAML: {problem}'.split())) from None
    except RecursionError:
        raise ScenarioError(f'{label}: YAML nested too deeply') from None
    if data is None:
        raise ScenarioError(f'{label}: (top level): the file is empty')
    return scenario_from_dict(data, label)


def list_scenarios() -> list[Path]:
    """Paths of the shipped scenario files (package data of ``ladrc_sim.headless.scenarios``)."""
    root = importlib.resources.files('ladrc_sim.headless.scenarios')
    return sorted((Path(str(e)) for e in root.iterdir() if e.name.endswith('.yaml')),
                  key=lambda q: q.name)
