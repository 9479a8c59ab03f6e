"""Branch-free polynomial ``atan``, ``sin``, ``cos``, ``exp`` and a ``sqrt`` that LLVM can vectorise.

numba compiles ``math.atan`` and friends to scalar calls into the C library: the llvmlite
wheels on PyPI are built without Intel's SVML, so a loop that calls them is never
vectorised. The tyre model evaluates nine arctangents, two sines and two cosines per wheel
and RK4 stage, so the plant spent most of its time in those calls. These replacements are
plain arithmetic with selects (no calls, no data-dependent branches), so a loop over wheel
lanes compiles to AVX2/AVX-512 code (a tyre evaluation ~3.5x faster than with the library); in
scalar code they are slower than the library, so they belong in loops over lanes only
(docs/decisions/0005-plant-polynomial-math-in-simd-lanes.md). :mod:`envs.vehicle` pads its
lanes to a multiple of :data:`LANE_MULTIPLE`, so even one car's four wheels run as one vector.
Keep such loops free of calls (``math.sqrt`` is one: use :func:`sqrt`), inner loops, ``**`` and
``math.floor`` (an integer in numba): any of them stopped the vectoriser here.

Accuracy, checked against the C library by ``tests/test_vecmath.py`` over dense grids:

* ``atan``: <= 2 ulp everywhere (including +-inf). Reduction to ``|t| <= tan(pi/8)`` with
  ``atan(x) = pi/2 - atan(1/x)`` and ``atan(t) = pi/4 + atan((t - 1)/(t + 1))``, then
  ``t P(t^2)`` with ``P`` of degree 10: the polynomial through the 11 Chebyshev nodes of
  ``atan(sqrt(s))/sqrt(s)`` on ``s in [0, tan(pi/8)^2]``, computed in 40-digit arithmetic
  (mpmath); evaluated by Horner's rule in doubles its relative error there is 2.4e-16 (1 ulp)
  at most (measured on 400,001 points).
* ``sin``, ``cos``: <= 2 ulp absolute for ``|x| <= 1e5``. Cody-Waite reduction by ``pi/2``
  (the two-part constant of fdlibm's ``__ieee754_rem_pio2``), Taylor series to ``r^15`` and
  ``r^16`` on ``|r| <= pi/4`` (truncation below 7e-17), quadrant selected arithmetically.
* ``sqrt``: LLVM's ``llvm.sqrt`` intrinsic, correctly rounded like the C library's (so
  bit-identical to ``math.sqrt``, which it is when called from Python); numba compiles
  ``math.sqrt`` to a call of the C function, which the loop vectoriser refuses ("call
  instruction cannot be vectorized").
* ``exp``: <= 2e-14 relative for ``|z| <= 16``, degrading beyond (3e-8 at 64):
  Taylor series to ``w^12`` of ``exp(w)``, ``w = z / 64``, squared six times. The plant
  calls it for load-sensitivity factors ``exp(c dfz)`` with ``|c dfz| < 1``.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import types
from numba.extending import intrinsic, overload

from fourwis.core.kernels import JIT

LANE_MULTIPLE = 8  #: pad lane loops to this many doubles: one AVX-512 register, two AVX2 ones

_TAN_PI_8 = math.tan(math.pi / 8.0)
# atan(t) = t * P(t^2) on |t| <= tan(pi/8); coefficients of P from s^0 to s^10 (see module docstring)
_A0, _A1, _A2, _A3, _A4, _A5, _A6, _A7, _A8, _A9, _A10 = (
    1.0,
    -0.3333333333332844,
    0.1999999999885511,
    -0.14285714180976467,
    0.11111106180455946,
    -0.09090773074808414,
    0.07689953496306857,
    -0.06640233930429408,
    0.056883492268090106,
    -0.04348052215716462,
    0.021135373157693246,
)
_PIO2_HI = 1.5707963267341256  #: first 33 bits of pi/2 (fdlibm pio2_1): k * _PIO2_HI is exact for |k| < 2^20
_PIO2_LO = 6.0771005065061922e-11  #: pi/2 - _PIO2_HI (fdlibm pio2_1t)


@numba.njit(inline="always", **JIT)
def atan(x: float) -> float:
    """Arctangent [rad] of ``x``, in [-pi/2, pi/2]."""
    ax = abs(x)
    t = min(ax, 1.0 / ax)  # |x| > 1: atan(x) = pi/2 - atan(1/x); 1/0 = inf leaves t = 0
    upper = t > _TAN_PI_8
    t = (t - 1.0) / (t + 1.0) if upper else t
    s = t * t
    p = _A10
    p = p * s + _A9
    p = p * s + _A8
    p = p * s + _A7
    p = p * s + _A6
    p = p * s + _A5
    p = p * s + _A4
    p = p * s + _A3
    p = p * s + _A2
    p = p * s + _A1
    p = p * s + _A0
    result = t * p + (0.25 * math.pi if upper else 0.0)
    result = 0.5 * math.pi - result if ax > 1.0 else result
    return math.copysign(result, x)


@numba.njit(inline="always", **JIT)
def sin_cos(x: float) -> tuple[float, float]:
    """(sine, cosine) of ``x`` [rad], sharing one argument reduction."""
    k = np.floor(x * (2.0 / math.pi) + 0.5)  # np.floor stays a float; math.floor is an int in numba
    r = (x - k * _PIO2_HI) - k * _PIO2_LO  # x = r + k pi/2, |r| <= pi/4
    z = r * r
    # Taylor series in nested (Horner) form, to r^15 and r^16
    s = r - r * z * (
        1.0 / 6.0
        - z
        * (
            1.0 / 120.0
            - z
            * (
                1.0 / 5040.0
                - z * (1.0 / 362880.0 - z * (1.0 / 39916800.0 - z * (1.0 / 6227020800.0 - z * (1.0 / 1307674368000.0))))
            )
        )
    )
    c = 1.0 - z * (
        0.5
        - z
        * (
            1.0 / 24.0
            - z
            * (
                1.0 / 720.0
                - z
                * (
                    1.0 / 40320.0
                    - z
                    * (
                        1.0 / 3628800.0
                        - z * (1.0 / 479001600.0 - z * (1.0 / 87178291200.0 - z * (1.0 / 20922789888000.0)))
                    )
                )
            )
        )
    )
    quadrant = k - 4.0 * np.floor(0.25 * k)
    odd = quadrant == 1.0 or quadrant == 3.0
    sine = c if odd else s
    cosine = s if odd else c
    sine = -sine if quadrant >= 2.0 else sine
    cosine = -cosine if (quadrant == 1.0 or quadrant == 2.0) else cosine
    return sine, cosine


@numba.njit(inline="always", **JIT)
def sin(x: float) -> float:
    """Sine of ``x`` [rad]."""
    return sin_cos(x)[0]


@numba.njit(inline="always", **JIT)
def cos(x: float) -> float:
    """Cosine of ``x`` [rad]."""
    return sin_cos(x)[1]


@numba.njit(inline="always", **JIT)
def exp(z: float) -> float:
    """Exponential of ``z``; accurate for moderate ``|z|`` (see the module docstring)."""
    w = z * (1.0 / 64.0)
    p = 1.0 / 479001600.0
    p = p * w + 1.0 / 39916800.0
    p = p * w + 1.0 / 3628800.0
    p = p * w + 1.0 / 362880.0
    p = p * w + 1.0 / 40320.0
    p = p * w + 1.0 / 5040.0
    p = p * w + 1.0 / 720.0
    p = p * w + 1.0 / 120.0
    p = p * w + 1.0 / 24.0
    p = p * w + 1.0 / 6.0
    p = p * w + 0.5
    p = p * w + 1.0
    p = p * w + 1.0
    p = p * p  # six squarings, written out: a loop here would stop the enclosing loop's vectorisation
    p = p * p
    p = p * p
    p = p * p
    p = p * p
    return p * p


def sqrt(x: float) -> float:
    """Square root of a float: in compiled code the ``llvm.sqrt`` intrinsic (see the module
    docstring); from Python, and under NUMBA_DISABLE_JIT, ``math.sqrt`` (bit-identical)."""
    return math.sqrt(x)


@overload(sqrt, inline="always", jit_options=JIT)
def _sqrt_compiled(x):
    if isinstance(x, types.Float):
        return lambda x: _llvm_sqrt(x)
    return None


@intrinsic
def _llvm_sqrt(typingctx, x):
    """The ``llvm.sqrt`` intrinsic of a float."""
    if not isinstance(x, types.Float):
        return None

    def codegen(context, builder, signature, args):
        function = builder.module.declare_intrinsic("llvm.sqrt", [args[0].type])
        return builder.call(function, args)

    return x(x), codegen
