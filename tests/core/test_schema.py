"""The parameter schema: one declaration per parameter, everything else derived from it."""

from __future__ import annotations

import math
from pathlib import Path
import typing

from ladrc_contract.schema import entries, markdown_table, param, value_problems
from ladrc_follow.control.params import (
    ControllerParams,
    ParameterError,
    parameter_file,
    params_from_dict,
    validate,
)
import pytest

ROOT = Path(__file__).resolve().parents[2]
ENTRIES = list(entries(ControllerParams()))
NUMERIC = [e for e in ENTRIES if not e.spec.choices and e.type in (int, float)
           or typing.get_origin(e.type) is tuple]


def test_every_parameter_is_declared_with_unit_range_and_description():
    assert len(ENTRIES) == len({e.name for e in ENTRIES}) > 60
    for e in ENTRIES:
        assert e.spec.description, e.name
        if e.type in (bool, str):  # str: sensor.table_file (a path, '' = none)
            continue
        if e.spec.choices:
            assert e.value in e.spec.choices, e.name
            continue
        # finite lower and upper bounds for every number (the safety issue's rule)
        assert e.spec.lower is not None and math.isfinite(e.spec.lower), e.name
        assert e.spec.le is not None and math.isfinite(e.spec.le), e.name
        assert e.spec.unit, e.name


@pytest.mark.parametrize('entry', NUMERIC, ids=lambda e: e.name)
def test_bad_values_are_rejected_with_the_parameter_named(entry):
    """Non-finite, huge and out-of-range values: a ParameterError naming the key, no crash."""
    lo, hi = entry.spec.lower, entry.spec.le
    bad = [math.inf, -math.inf, math.nan, 1e300, -1e300, hi * 2.0 + 1.0, lo - 1.0, 10 ** 400]
    if entry.spec.gt is not None:
        bad.append(lo)
    for value in bad:
        if typing.get_origin(entry.type) is tuple:
            value = [value] * len(entry.value)
        with pytest.raises(ParameterError) as err:
            params_from_dict({entry.name: value})
        assert entry.name in str(err.value), (entry.name, value, str(err.value))


@pytest.mark.parametrize('entry', NUMERIC, ids=lambda e: e.name)
def test_values_inside_the_range_never_crash_validation(entry):
    """In-range values may still fail a cross check, but only with a reason, never raise."""
    lo, hi = entry.spec.lower, entry.spec.le
    for value in (lo if entry.spec.gt is None else lo + (hi - lo) * 1e-9, hi,
                  0.5 * (lo + hi)):
        if entry.type is int:
            value = int(value)
        if typing.get_origin(entry.type) is tuple:
            value = [value] * len(entry.value)
        try:
            params_from_dict({entry.name: value})
        except ParameterError as exc:
            assert exc.reasons and all(isinstance(r, str) for r in exc.reasons)


def test_wrong_types_are_reasons():
    for name, value in (('eso.order', 1.5), ('eso.order', 'one'), ('kalman.enabled', 1),
                        ('law.kp', 'fast'), ('eso.betas', 'x'), ('follow.controller', 3)):
        with pytest.raises(ParameterError, match=name.replace('.', r'\.')):
            params_from_dict({name: value})


def test_integer_given_for_a_float_is_accepted():
    p = params_from_dict({'law.kp': 12, 'eso.betas': [180, 10800]})
    assert p.law.kp == 12.0 and isinstance(p.law.kp, float)
    assert p.eso.betas == (180.0, 10800.0)


def test_value_problems_messages():
    spec = param(1.0, 'mm', 'a gap', gt=0.0, le=5.0).metadata['spec']
    assert value_problems('g', float, 0.0, spec) == [
        'g = 0: outside its range (0, 5] mm (a gap)']
    assert value_problems('g', float, 5.0, spec) == []
    assert 'finite' in value_problems('g', float, math.nan, spec)[0]


def test_validation_never_raises_on_garbage():
    p = ControllerParams()
    garbage = p.replace(eso=object())  # not even a section
    reasons = validate(garbage)
    assert reasons and isinstance(reasons[0], str)


def test_docs_table_is_generated_from_the_declarations():
    doc = (ROOT / 'docs' / 'parameters.md').read_text(encoding='utf-8')
    assert markdown_table(ControllerParams()) in doc, (
        'docs/parameters.md is stale: regenerate it with `scripts/in-env ladrc params '
        '--markdown`')


def test_shipped_parameter_file_is_generated_from_the_declarations():
    shipped = ROOT / 'ros2_ws' / 'src' / 'ladrc_bringup' / 'config' / 'follow.yaml'
    assert shipped.read_text(encoding='utf-8') == parameter_file(), (
        'config/follow.yaml is stale: regenerate it with `scripts/in-env ladrc params --yaml`')
