"""The parameter schema: every parameter declared once, as a dataclass field.

The controller's parameters and the simulator's models use it alike (the sim may not import
the controller, so it lives in the contract; pure Python, no rclpy). A controller parameter
is a field of one of the section dataclasses (``TDParams``, ``ESOParams``, …, gathered in
``ladrc_follow.control.params.ControllerParams``) declared with :func:`param`::

    w0_rad_s: float = param(60.0, 'rad/s', 'observer bandwidth ω0 (poles at −ω0)',
                            gt=0.0, le=5000.0, seed='notes §3.3')

The declaration holds the type (the annotation), the default, the unit, the valid range
(finite lower and upper bounds for every controller number; the simulator's models also
declare one-sided ranges and +inf for "never"), the description with the seed section it
comes from, and whether it may change while the node runs. Everything else derives from it:

* :func:`entries`: the flat list of dotted names (``eso.w0_rad_s``), what the node declares
  as ROS parameters (descriptors with range, unit and ``read_only``) and what the docs table
  (docs/parameters.md, :func:`markdown_table`) lists;
* :func:`field_problems`: the per-value checks (type, finiteness, range, choices) with one
  readable reason per bad value. Checks that involve several parameters (stability bounds,
  contradicting limits) are written next to the whole set (``ladrc_follow.control.params``);
* :func:`first_problem`: the simulator's models refuse a value at construction with the first
  reason (``ladrc_sim.models.axis.ParamError``);
* :func:`load`: the one mapping-to-dataclass loader (YAML of parameter files, job files,
  scenarios, device files): nested sections, type coercion, unknown keys, ranges, and
  :class:`LoadError` carrying each :class:`Problem` with its dotted path.
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, field, fields, is_dataclass, replace
import math
import numbers
import types
import typing
from typing import Any, Callable, Iterator

__all__ = ['Spec', 'Entry', 'param', 'entries', 'field_problems', 'value_problems',
           'first_problem', 'markdown_table', 'Section', 'load', 'coerce', 'as_mapping',
           'LoadError', 'Problem', 'type_name', 'UNKNOWN_KEY', 'MISSING_KEY', 'NOT_MAPPING',
           'WRONG_TYPE', 'OUT_OF_RANGE', 'INVALID']


@dataclass(frozen=True)
class Spec:
    """What :func:`param` declares besides the name, type and default."""

    unit: str
    description: str
    seed: str = ''
    gt: float | None = None      # value > gt
    ge: float | None = None      # value >= ge
    le: float | None = None      # value <= le
    lt: float | None = None      # value < lt
    choices: tuple = ()
    runtime: bool = True         # may change while the node runs (else read-only)
    inf_ok: bool = False         # +inf allowed, meaning "never" (an end time)

    @property
    def upper(self) -> float | None:
        """The upper bound (strict when ``lt`` is set)."""
        return self.lt if self.lt is not None else self.le

    @property
    def lower(self) -> float | None:
        """The lower bound (strict when ``gt`` is set)."""
        return self.gt if self.gt is not None else self.ge

    def range_text(self) -> str:
        """``(0, 5000]``-style text of the valid range, or the choices."""
        if self.choices:
            return ' | '.join(str(c) for c in self.choices)
        if self.lower is None and self.upper is None:
            return ''
        if self.upper is None:  # one-sided (simulator models): '> 0', '>= 0'
            return f"{'>' if self.gt is not None else '>='} {_num(self.lower)}"
        if self.lower is None:
            return f"{'<' if self.lt is not None else '<='} {_num(self.upper)}"
        left = '(' if self.gt is not None else '['
        right = ')' if self.lt is not None else ']'
        return f'{left}{_num(self.lower)}, {_num(self.upper)}{right}'


def _num(x: float | None) -> str:
    return '' if x is None else f'{x:g}'


def param(default: Any = MISSING, unit: str = '', description: str = '', *,
          gt: float | None = None, ge: float | None = None, le: float | None = None,
          lt: float | None = None, choices: tuple = (), seed: str = '', runtime: bool = True,
          inf_ok: bool = False) -> Any:
    """Declare one parameter (a dataclass field): default, unit, range, description, seed."""
    spec = Spec(unit=unit, description=description, seed=seed, gt=gt, ge=ge, le=le, lt=lt,
                choices=tuple(choices), runtime=runtime, inf_ok=inf_ok)
    return field(default=default, metadata={'spec': spec})


@dataclass(frozen=True)
class Entry:
    """One parameter of a parameter set: dotted name, Python type, value, declaration."""

    name: str
    type: Any
    value: Any
    spec: Spec


def entries(obj: Any, prefix: str = '') -> Iterator[Entry]:
    """Yield every declared parameter of a (nested) parameter dataclass instance, in order."""
    hints = typing.get_type_hints(type(obj))
    for f in fields(obj):
        value = getattr(obj, f.name)
        name = f'{prefix}{f.name}'
        if 'spec' in f.metadata:
            yield Entry(name, hints[f.name], value, f.metadata['spec'])
        elif is_dataclass(value):
            yield from entries(value, name + '.')


def value_problems(name: str, tp: Any, value: Any, spec: Spec) -> list[str]:
    """Reasons why one value does not fit its declaration (empty when it does)."""
    unit = f' {spec.unit}' if spec.unit and spec.unit != '1' else ''
    why = f' ({spec.description})' if spec.description else ''
    rng = f'outside its range {spec.range_text()}{unit}{why}'
    if spec.choices:
        if value not in spec.choices:
            return [f'{name} = {value!r}: must be one of {", ".join(map(repr, spec.choices))}']
        return []
    if tp is bool:
        return [] if isinstance(value, bool) else [f'{name} = {value!r}: must be true or false']
    if tp is str:
        return [] if isinstance(value, str) else [f'{name} = {value!r}: must be a string']
    if typing.get_origin(tp) is tuple:
        if not isinstance(value, tuple):
            return [f'{name} = {value!r}: must be a list of numbers']
        args = typing.get_args(tp)
        item = args[0] if args and (len(args) == 2 and args[1] is Ellipsis) else float
        out = []
        for i, v in enumerate(value):
            out += value_problems(f'{name}[{i}]', item, v, spec)
        return out
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return [f'{name} = {value!r}: must be a number']
    if tp is int and not isinstance(value, int):
        return [f'{name} = {value!r}: must be a whole number']
    try:
        x = float(value)
    except OverflowError:
        return [f'{name} = {value}: {rng}']
    if not math.isfinite(x) and not (spec.inf_ok and x == math.inf):
        return [f'{name} = {value!r}: must be a finite number']
    lo, hi = spec.lower, spec.upper
    if (lo is not None and (value <= lo if spec.gt is not None else value < lo)) or (
            hi is not None and (value >= hi if spec.lt is not None else value > hi)):
        return [f'{name} = {value:g}: {rng}']
    return []


def field_problems(obj: Any, prefix: str = '') -> list[str]:
    """Per-value reasons (type, finiteness, range, choices) for every parameter of ``obj``."""
    out: list[str] = []
    for e in entries(obj, prefix):
        out += value_problems(e.name, e.type, e.value, e.spec)
    return out


def first_problem(obj: Any) -> tuple[str, str] | None:
    """Return ``(field name, reason)`` of the first value of ``obj`` that does not fit, or None.

    Fields whose value is None are optional and not checked.
    """
    for e in entries(obj):
        if e.value is None:
            continue
        reasons = value_problems(e.name, e.type, e.value, e.spec)
        if reasons:
            return e.name, reasons[0][len(e.name) + 3:]  # without 'name = '
    return None


class Section:
    """Mixin for a section dataclass: :meth:`problems` from its declarations."""

    PREFIX = ''

    def problems(self) -> list[str]:
        """Readable reasons why these values cannot run (empty when valid)."""
        return field_problems(self, self.PREFIX)


def markdown_table(obj: Any) -> str:
    """Return the parameter table of docs/parameters.md, generated from the declarations."""
    rows = ['| parameter | type | default | unit | range | run time | description |',
            '| --- | --- | --- | --- | --- | --- | --- |']
    for e in entries(obj):
        tp = e.type
        tname = 'list of float' if typing.get_origin(tp) is tuple else tp.__name__
        value = list(e.value) if isinstance(e.value, tuple) else e.value
        value = "''" if value == '' else value  # an empty string shows as ''
        seed = f' ({e.spec.seed})' if e.spec.seed else ''
        cells = (f'`{e.name}`', tname, f'`{value}`', e.spec.unit, e.spec.range_text(),
                 'yes' if e.spec.runtime else 'start-up', e.spec.description + seed)
        rows.append('| ' + ' | '.join(c.replace('|', '\\|') for c in cells) + ' |')
    return '\n'.join(rows) + '\n'


# ---------------------------------------------------------------------------
# the loader: a mapping (parsed YAML) -> a (nested) dataclass

UNKNOWN_KEY = 'unknown_key'    # a key the dataclass does not declare
MISSING_KEY = 'missing_key'    # a required key (no default) is absent
NOT_MAPPING = 'not_mapping'    # a section (or the whole file) is not a mapping of string keys
WRONG_TYPE = 'wrong_type'      # a value of another type than declared
OUT_OF_RANGE = 'out_of_range'  # outside the declared range or choices, or not finite
INVALID = 'invalid'            # the dataclass refused the values (its own checks)


@dataclass(frozen=True)
class Problem:
    """One value that does not fit: its dotted path, the kind (``WRONG_TYPE``…) and why.

    ``reason`` is one line without the path; ``str(problem)`` is ``'path: reason'``.
    ``value`` is the value read, ``expected`` the type wanted (``'a number'``) for
    ``WRONG_TYPE``, ``allowed`` the declared keys for ``UNKNOWN_KEY``.
    """

    path: str
    kind: str
    reason: str
    value: Any = None
    expected: str = ''
    allowed: tuple = ()
    hint: str = ''

    def __str__(self) -> str:
        return f'{self.path or "(top level)"}: {self.reason}'


class LoadError(ValueError):
    """A mapping does not fit its dataclass: ``problems`` lists each one (at least one).

    ``str()`` is the first problem's one line; ``path``, ``kind`` and ``reason`` are its.
    """

    def __init__(self, problems: list[Problem] | Problem) -> None:
        self.problems = (problems,) if isinstance(problems, Problem) else tuple(problems)
        first = self.problems[0]
        self.path, self.kind, self.reason = first.path, first.kind, first.reason
        super().__init__(' '.join(str(first).split()))


def type_name(v: Any) -> str:
    """Return a YAML reader's name of the type of ``v`` ('a number', 'a list', 'null')."""
    if v is None:
        return 'null'
    return {bool: 'a boolean', int: 'an integer', float: 'a number', str: 'a string',
            list: 'a list', tuple: 'a list', dict: 'a mapping'}.get(type(v), type(v).__name__)


def _join(where: str, key: Any) -> str:
    return f'{where}.{key}' if where else str(key)


def _wrong(path: str, value: Any, expected: str, hint: str = '') -> Problem:
    return Problem(path, WRONG_TYPE, f'expected {expected}, got {type_name(value)} '
                   f'({value!r:.60}){hint}', value, expected, hint=hint)


def _number(value: Any, path: str, out: list[Problem]) -> float | None:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        hint = ''
        if isinstance(value, str):
            try:
                float(value)
                hint = ' (YAML reads 1e-3 as text: write 1.0e-3)'
            except ValueError:
                pass
        out.append(_wrong(path, value, 'a number', hint))
        return None
    try:
        return float(value)
    except OverflowError:
        out.append(Problem(path, OUT_OF_RANGE, f'{value}: too large for a float', value))
        return None


def _mapping(data: Any, path: str, out: list[Problem]) -> bool:
    """Whether ``data`` is a mapping of string keys (else a problem is added)."""
    if not isinstance(data, dict):
        out.append(Problem(path, NOT_MAPPING, f'must be a mapping of keys, got '
                           f'{type_name(data)}', data, 'a mapping'))
        return False
    for k in data:
        if isinstance(k, bool):
            out.append(Problem(path, NOT_MAPPING, f'key {k!r} is not a string (YAML reads a '
                               "bare on/off/yes/no as a boolean: quote it, e.g. 'on': true)", k))
            return False
        if not isinstance(k, str):
            out.append(Problem(path, NOT_MAPPING, f'key {k!r} is not a string', k))
            return False
    return True


def _coerce(value: Any, tp: Any, path: str, out: list[Problem], ranges: bool,
            convert: Callable[[Any, Any], Any] | None) -> Any:
    """``value`` converted to annotation ``tp``; None (and a problem added) if it cannot be."""
    if convert is not None:
        value = convert(tp, value)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        tp = next(a for a in args if a is not type(None))
        origin, args = typing.get_origin(tp), typing.get_args(tp)
    if is_dataclass(tp):
        return _load(tp, value, path, None, out, ranges, (), convert)
    if tp is float:
        return _number(value, path, out)
    if tp is int:
        if isinstance(value, float) and value.is_integer():
            return int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            out.append(_wrong(path, value, 'an integer'))
            return None
        return value
    if tp is bool or tp is str:
        if not isinstance(value, tp):
            out.append(_wrong(path, value, 'true or false' if tp is bool else 'a string'))
            return None
        return value
    if tp is tuple or origin is tuple:
        if not isinstance(value, (list, tuple)):
            what = 'a list' if not args or args[0] is not float else 'a list of numbers'
            out.append(_wrong(path, value, what))
            return None
        if not args:
            return tuple(value)
        if len(args) == 2 and args[1] is Ellipsis:
            kinds = [args[0]] * len(value)
        elif len(args) != len(value):
            out.append(_wrong(path, value, f'a list of {len(args)}'))
            return None
        else:
            kinds = list(args)
        n = len(out)
        items = [_coerce(v, k, f'{path}[{i}]', out, ranges, convert)
                 for i, (v, k) in enumerate(zip(value, kinds, strict=True))]
        return None if len(out) > n else tuple(items)
    if tp is dict or origin is dict:
        if not isinstance(value, dict):
            out.append(_wrong(path, value, 'a mapping'))
            return None
        return dict(value)
    return value


def coerce(value: Any, tp: Any, path: str) -> Any:
    """Return ``value`` converted to annotation ``tp`` (int for float, list for tuple, ...).

    Raises :class:`LoadError` naming ``path`` if it cannot be.
    """
    out: list[Problem] = []
    v = _coerce(value, tp, path, out, True, None)
    if out:
        raise LoadError(out)
    return v


def as_mapping(data: Any, path: str) -> dict:
    """Return ``data`` if it is a mapping of string keys, else raise :class:`LoadError`."""
    out: list[Problem] = []
    if not _mapping(data, path, out):
        raise LoadError(out)
    return data


def _load(cls: type, data: Any, where: str, base: Any, out: list[Problem], ranges: bool,
          skip: tuple[str, ...], convert: Callable[[Any, Any], Any] | None) -> Any:
    if data is None:
        data = {}
    if not _mapping(data, where, out):
        return None
    hints = typing.get_type_hints(cls)
    decl = {f.name: f for f in fields(cls) if f.name not in skip}
    n = len(out)
    for k in data:
        if k not in decl:
            out.append(Problem(_join(where, k), UNKNOWN_KEY,
                               f'unknown key {k!r} (allowed: {", ".join(decl)})', k,
                               allowed=tuple(decl)))
    if base is None:
        for name, f in decl.items():
            if (name not in data and f.default is MISSING
                    and f.default_factory is MISSING and f.init):
                out.append(Problem(_join(where, name), MISSING_KEY, 'missing required key'))
    values = {}
    for k, v in data.items():
        if k not in decl:
            continue
        path, tp = _join(where, k), hints[k]
        if is_dataclass(tp) and base is not None:
            values[k] = _load(tp, v, path, getattr(base, k), out, ranges, (), convert)
            continue
        m = len(out)
        value = _coerce(v, tp, path, out, ranges, convert)
        spec = decl[k].metadata.get('spec')
        if len(out) == m and ranges and spec is not None and value is not None:
            inner = [a for a in typing.get_args(tp) if a is not type(None)]
            if typing.get_origin(tp) in (typing.Union, types.UnionType) and len(inner) == 1:
                tp = inner[0]
            for line in value_problems(path, tp, value, spec):
                name, _, rest = line.partition(' = ')
                out.append(Problem(name, OUT_OF_RANGE, rest, value))
        values[k] = value
    if len(out) > n:
        return None
    try:
        if base is not None:
            return replace(base, **values)
        return cls(**values)
    except (TypeError, ValueError) as exc:
        key = getattr(exc, 'key', None)  # a model's ParamError names its field
        reason = getattr(exc, 'reason', None) or ' '.join(str(exc).split())
        out.append(Problem(_join(where, key) if key else where, INVALID, reason))
        return None


def load(cls: type, data: Any, *, where: str = '', base: Any = None, ranges: bool = True,
         skip: tuple[str, ...] = (),
         convert: Callable[[Any, Any], Any] | None = None) -> Any:
    """Build dataclass ``cls`` from ``data`` (parsed YAML), nested sections included.

    Coerces each value to its annotation (an int for a float, an integral float for an int,
    a list for a tuple, ``X | None``, a nested dataclass from a mapping), refuses keys the
    dataclass does not declare (naming the allowed ones) and required keys that are absent,
    and, with ``ranges``, checks each :func:`param` declaration (range, choices, finiteness).
    ``base``: an instance whose values stand for the absent keys (else the defaults);
    ``where``: the path of ``data`` (``'cnc'``: problems read ``cnc.feed_mm_s: ...``);
    ``skip``: fields that are not keys of the mapping; ``convert(annotation, value)``:
    a caller's rewrite of each raw value before coercion. Raises :class:`LoadError` with
    every problem found; the dataclass's own refusals (``__post_init__``) are ``INVALID``.
    """
    out: list[Problem] = []
    obj = _load(cls, data, where, base, out, ranges, skip, convert)
    if out:
        raise LoadError(out)
    return obj
