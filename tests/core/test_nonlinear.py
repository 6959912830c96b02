"""Nonlinear functions (notes §6, paper eq. 6) and their lookup tables."""

import math

from ladrc_contract.ops import ARRAY, SCALAR
from ladrc_follow.control.nonlinear import (
    LookupTable,
    asinh_fn,
    atan_fn,
    fal,
    sat,
    sigmoid,
    sinh_fn,
    tanh_fn,
)
import numpy as np
import pytest
from reference_forms import default_tables

E = np.concatenate([np.linspace(-3.0, 3.0, 601), [0.05, -0.05, 1e-9, -1e-9, 0.0]])


def test_fal_matches_paper_eq6():
    alpha, delta = 0.5, 0.05
    for e in (-2.0, -0.3, 0.2, 1.5):
        assert fal(SCALAR, e, alpha, delta) == pytest.approx(math.copysign(abs(e) ** alpha, e))
    for e in (-0.04, 0.01, 0.05):
        assert fal(SCALAR, e, alpha, delta) == pytest.approx(e / delta ** (1 - alpha))
    # continuous at the edge of the linear zone: both sides give delta**alpha
    eps = 1e-12
    assert fal(SCALAR, delta + eps, alpha, delta) == pytest.approx(delta ** alpha, abs=1e-9)
    assert fal(SCALAR, delta - eps, alpha, delta) == pytest.approx(delta ** alpha, abs=1e-9)
    assert fal(SCALAR, 0.0, alpha, delta) == 0.0


@pytest.mark.parametrize('fn,args,exact', [
    (fal, (0.25, 0.1), None),
    (sat, (0.5,), lambda e: np.clip(e / 0.5, -1, 1)),
    (sigmoid, (2.0,), lambda e: 2.0 / (1.0 + np.exp(-2.0 * e)) - 1.0),
    (tanh_fn, (1.5,), lambda e: np.tanh(1.5 * e)),
    (atan_fn, (2.0,), lambda e: np.arctan(2.0 * e)),
    (asinh_fn, (3.0,), lambda e: np.arcsinh(3.0 * e)),
    (sinh_fn, (0.7,), lambda e: np.sinh(0.7 * e)),
])
def test_functions_odd_exact_and_batch_equals_scalar(fn, args, exact):
    arr = fn(ARRAY, E, *args)
    scal = np.array([fn(SCALAR, float(e), *args) for e in E])
    # One implementation on both backends. Only + - * / and sqrt are correctly rounded; numpy's
    # SIMD exp/pow/arctan may differ from libm's in the last bit on some processors, so
    # equality is to rounding, not bit for bit. The LADRC tick uses none of these functions,
    # so its batch N = 1 stays bit-exact (tests/core/test_ladrc.py).
    np.testing.assert_allclose(arr, scal, rtol=4e-16 * 4, atol=1e-15)
    np.testing.assert_array_equal(fn(ARRAY, -E, *args), -arr)   # odd
    if exact is not None:
        np.testing.assert_allclose(arr, exact(E), rtol=1e-13, atol=1e-15)


def test_fal_batch_rows_with_different_parameters():
    alphas = np.array([0.5, 0.25, 1.0])
    deltas = np.array([0.05, 0.2, 0.01])
    e = np.array([0.1, 0.1, -0.3])
    got = fal(ARRAY, e, alphas, deltas)
    want = [fal(SCALAR, float(a), float(b), float(c))
            for a, b, c in zip(e, alphas, deltas, strict=True)]
    np.testing.assert_allclose(got, want, rtol=1e-15, atol=0.0)  # pow: to rounding (see above)


def _second_derivative_bound(f, lo, hi):
    x = np.linspace(lo, hi, 200001)
    d2 = np.gradient(np.gradient(f(x), x), x)
    return float(np.max(np.abs(d2[5:-5])))


@pytest.mark.parametrize('name', ['sigmoid(1)', 'tanh(1)', 'atan(1)', 'asinh(1)', 'sinh(1)'])
def test_smooth_tables_within_interpolation_bound(name):
    tab = default_tables()[name]
    dx = tab.hi / (tab.size - 1)            # odd tables: grid on [0, hi]
    bound = dx * dx / 8.0 * _second_derivative_bound(tab.fn, tab.lo, tab.hi)
    err = tab.max_error()
    assert err <= bound * 1.01
    assert err > 0.0


@pytest.mark.parametrize('name', sorted(default_tables()))
def test_tables_scalar_equals_array_and_respect_max_error(name):
    tab = default_tables()[name]
    x = np.random.default_rng(1).uniform(tab.lo, tab.hi, 2000)
    arr = tab(x)
    np.testing.assert_allclose(arr, [tab(float(v)) for v in x], rtol=0, atol=1e-15)
    # the dense grid (64 points per cell) misses the true maximum by < 0.1 %
    assert np.max(np.abs(arr - tab.fn(x))) <= tab.max_error() * 1.001 + 1e-15
    np.testing.assert_array_equal(tab(-x), -arr)      # odd symmetry


def test_table_outside_range_rules():
    clamp = LookupTable(np.tanh, -2.0, 2.0, 65, odd=True, extrapolate='clamp')
    assert clamp(5.0) == pytest.approx(math.tanh(2.0))
    assert clamp(-5.0) == pytest.approx(-math.tanh(2.0))
    lin = LookupTable(lambda x: 3.0 * x + 1.0, 0.0, 1.0, 11, extrapolate='linear')
    assert lin(2.0) == pytest.approx(7.0)        # exact for a line, beyond the table
    assert lin(-1.0) == pytest.approx(-2.0)
    np.testing.assert_allclose(lin(np.array([2.0, -1.0])), [7.0, -2.0])


def test_table_bad_input():
    with pytest.raises(ValueError, match='size'):
        LookupTable(np.tanh, -1.0, 1.0, 1)
    with pytest.raises(ValueError, match='symmetric'):
        LookupTable(np.tanh, 0.0, 1.0, 9, odd=True)
    with pytest.raises(ValueError, match='extrapolate'):
        LookupTable(np.tanh, -1.0, 1.0, 9, extrapolate='wrap')
