"""The contract's one mapping-to-dataclass loader (``ladrc_contract.schema.load``)."""

from __future__ import annotations

from dataclasses import MISSING, dataclass, field

from ladrc_contract.schema import (
    MISSING_KEY,
    NOT_MAPPING,
    OUT_OF_RANGE,
    UNKNOWN_KEY,
    WRONG_TYPE,
    LoadError,
    load,
    param,
)
import pytest


@dataclass(frozen=True)
class Cnc:
    small_contour_mm: float = param(8.0, 'mm', 'smallest contour cut unlocked', gt=0.0)
    passes: int = param(1, '1', 'passes', ge=1, le=9)
    mode: str = param('lock', '', 'how', choices=('lock', 'free'))
    dwell_s: tuple[float, ...] = param((0.1, 0.2), 's', 'pierce stages', ge=0.0, le=10.0)


@dataclass(frozen=True)
class Job:
    name: str = param(MISSING, '', 'the name')
    cnc: Cnc = field(default_factory=Cnc)
    contact: Cnc | None = None
    extra: dict = field(default_factory=dict)


def refusal(data, **kw) -> LoadError:
    with pytest.raises(LoadError) as err:
        load(Job, data, where='job', **kw)
    assert '\n' not in str(err.value)
    return err.value


def test_types_are_coerced_and_absent_keys_keep_their_defaults():
    job = load(Job, {'name': 'a', 'cnc': {'small_contour_mm': 3, 'passes': 2.0,
                                          'dwell_s': [1, 2, 3]}})
    assert job.cnc == Cnc(small_contour_mm=3.0, passes=2, dwell_s=(1.0, 2.0, 3.0))
    assert isinstance(job.cnc.small_contour_mm, float) and isinstance(job.cnc.passes, int)
    assert job.contact is None and job.extra == {}
    assert load(Job, {'name': 'b', 'contact': {'mode': 'free'}}).contact == Cnc(mode='free')
    base = Job(name='x', cnc=Cnc(passes=5))
    assert load(Job, {'cnc': {'mode': 'free'}}, base=base).cnc == Cnc(passes=5, mode='free')


def test_an_unknown_key_is_named_with_the_allowed_ones():
    e = refusal({'name': 'a', 'cnc': {'smal_contour_mm': 1.0}})
    assert (e.kind, e.path) == (UNKNOWN_KEY, 'job.cnc.smal_contour_mm')
    assert set(e.problems[0].allowed) == {'small_contour_mm', 'passes', 'mode', 'dwell_s'}


def test_a_wrong_type_names_the_nested_path():
    e = refusal({'name': 'a', 'cnc': {'passes': 'two'}})
    assert (e.kind, e.path, e.problems[0].expected) == (WRONG_TYPE, 'job.cnc.passes',
                                                        'an integer')
    assert refusal({'name': 'a', 'cnc': {'passes': 1.5}}).kind == WRONG_TYPE
    assert refusal({'name': 'a', 'cnc': {'small_contour_mm': True}}).kind == WRONG_TYPE
    e = refusal({'name': 'a', 'cnc': {'dwell_s': [0.1, 'x']}})
    assert (e.kind, e.path) == (WRONG_TYPE, 'job.cnc.dwell_s[1]')
    e = refusal({'name': 'a', 'cnc': [1, 2]})
    assert (e.kind, e.path) == (NOT_MAPPING, 'job.cnc')
    assert refusal({'name': 'a', 'extra': 3}).kind == WRONG_TYPE


def test_out_of_range_and_choices_are_refused_with_the_path():
    for cnc, path in (({'small_contour_mm': -1}, 'job.cnc.small_contour_mm'),
                      ({'small_contour_mm': 0.0}, 'job.cnc.small_contour_mm'),
                      ({'small_contour_mm': float('nan')}, 'job.cnc.small_contour_mm'),
                      ({'passes': 10}, 'job.cnc.passes'),
                      ({'mode': 'loose'}, 'job.cnc.mode'),
                      ({'dwell_s': [0.1, 11]}, 'job.cnc.dwell_s[1]')):
        e = refusal({'name': 'a', 'cnc': cnc})
        assert (e.kind, e.path) == (OUT_OF_RANGE, path), cnc
    assert load(Job, {'name': 'a', 'cnc': {'passes': 10}}, ranges=False).cnc.passes == 10


def test_a_required_key_and_every_problem_at_once():
    assert (refusal({}).kind, refusal({}).path) == (MISSING_KEY, 'job.name')
    e = refusal({'name': 'a', 'cnc': {'passes': 'x', 'mode': 'y', 'zz': 1}})
    assert {(p.kind, p.path) for p in e.problems} == {
        (UNKNOWN_KEY, 'job.cnc.zz'), (WRONG_TYPE, 'job.cnc.passes'),
        (OUT_OF_RANGE, 'job.cnc.mode')}
    assert str(e) == str(e.problems[0]) and str(e).startswith(e.path + ': ')
