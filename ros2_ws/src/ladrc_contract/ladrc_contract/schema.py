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
  reason (``ladrc_sim.models.axis.ParamError``).
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, field, fields, is_dataclass
import math
import numbers
import typing
from typing import Any, Iterator

__all__ = ['Spec', 'Entry', 'param', 'entries', 'field_problems', 'value_problems',
           'first_problem', 'markdown_table', 'Section']


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
        out = []
        for i, v in enumerate(value):
            out += value_problems(f'{name}[{i}]', float, v, spec)
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
