"""The vectorisable elementary functions of envs.vecmath against the C library."""

import math

import numba
import numpy as np

from fourwis.core import vecmath


@numba.njit
def _apply(function, x):
    out = np.empty_like(x)
    for i in range(x.size):
        out[i] = function(x[i])
    return out


def _ulps(value, reference):
    return np.abs(value - reference) / np.spacing(np.abs(reference))


def test_atan_within_two_ulp_everywhere_and_odd():
    x = np.concatenate([np.linspace(-20.0, 20.0, 400_001), np.logspace(-300, 300, 6_001), [np.inf]])
    x = np.concatenate([x, -x])
    value = _apply(vecmath.atan, x)
    nonzero = x != 0.0
    assert _ulps(value[nonzero], np.arctan(x[nonzero])).max() <= 2.0
    np.testing.assert_array_equal(_apply(vecmath.atan, -x), -value)
    assert _apply(vecmath.atan, np.array([np.inf]))[0] == math.pi / 2


def test_sin_cos_within_two_ulp_of_one_up_to_1e5_and_symmetric():
    x = np.concatenate([np.linspace(-1e5, 1e5, 1_000_001), np.linspace(-7.0, 7.0, 700_001)])
    for function, reference in ((vecmath.sin, np.sin), (vecmath.cos, np.cos)):
        error = np.abs(_apply(function, x) - reference(x))
        assert error.max() <= 2.0 * np.finfo(float).eps, function
    small = np.linspace(1e-3, 0.7, 10_001)  # near zero the sine is accurate relative to itself
    assert _ulps(_apply(vecmath.sin, small), np.sin(small)).max() <= 2.0
    np.testing.assert_array_equal(_apply(vecmath.sin, -x), -_apply(vecmath.sin, x))
    np.testing.assert_array_equal(_apply(vecmath.cos, -x), _apply(vecmath.cos, x))


def test_exp_relative_error_below_2e_14_for_moderate_arguments():
    z = np.linspace(-16.0, 16.0, 1_000_001)
    assert np.abs(_apply(vecmath.exp, z) / np.exp(z) - 1.0).max() < 2e-14
    assert _apply(vecmath.exp, np.array([0.0]))[0] == 1.0


@numba.njit
def _sqrt(x):  # an overloaded function is not a first-class function, so no _apply
    out = np.empty_like(x)
    for i in range(x.size):
        out[i] = vecmath.sqrt(x[i])
    return out


def test_sqrt_is_bit_identical_to_the_c_library():
    x = np.concatenate([np.logspace(-300, 300, 100_001), np.linspace(0.0, 10.0, 100_001)])
    np.testing.assert_array_equal(_sqrt(x), np.sqrt(x))
    # compiled, it is LLVM's intrinsic (vectorisable), not a call of the C library's sqrt
    llvm = next(iter(_sqrt.inspect_llvm().values()))
    assert "llvm.sqrt.f64" in llvm and "@sqrt(" not in llvm
