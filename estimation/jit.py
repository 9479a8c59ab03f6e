"""Compilation options shared by every numba kernel of fourwis, and an on-disk cache that
follows the code.

numba's cache (``cache=True``) is invalidated only when the source file of the cached
function itself changes, not when a function it calls from another module does (numba
documentation, "Notes on caching"). fourwis's kernels call across modules (the estimators in
``joint.py`` inline ``model.py`` and ``ckf.py``; the plant in ``vehicle.py`` inlines
``tyre.py``), so an edit to the tyre or estimation model would otherwise leave stale compiled
code in use, silently. Importing this module therefore points numba's cache at
``<checkout>/.numba_cache/<fingerprint>`` (an installed package, which has no pyproject.toml
beside it: ``$XDG_CACHE_HOME/fourwis/numba/<fingerprint>``, default ``~/.cache``, so that
site-packages stays as pip left it and a read-only one works), the fingerprint hashing the
source of every module with compiled kernels: after any edit to one of them everything
compiles afresh once (~45 s), and switching back to an earlier version finds its cache again.
A ``NUMBA_CACHE_DIR`` set by the user is left as it is (and with it numba's own invalidation
rule). Delete the cache directory to reclaim the disk space of old versions (~15 MB each).

Every kernel module imports :data:`JIT` from here, so the cache directory is set before its
first decorator runs. The setting is numba's process-wide ``config.CACHE_DIR``.

:func:`scratch` gives kernels small work arrays on the stack instead of the heap. A step of the
joint estimator used ~140 small arrays per vehicle (cubature points, gains, covariances);
numba allocates each with malloc plus an atomically reference-counted header, which cost
~30% of the step (B = 256, serial: 17.2 -> 12.2 us per vehicle-step without them). Stack
arrays also let the compiler prove that a loop's arrays do not overlap, which it needs
before it runs the loop in SIMD lanes (``estimation.model.body_forces``).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload
from numba.np import numpy_support
from numba.np.arrayobj import make_array, populate_array
from numba.np.unsafe.ndarray import to_fixed_tuple

#: options of every fourwis kernel: cached on disk, NumPy's floating-point error semantics
#: (division by zero gives inf/nan instead of raising, as in vectorised NumPy code)
JIT = dict(cache=True, error_model="numpy")

ROOT = Path(__file__).resolve().parent.parent  #: the checkout (or site-packages) holding the packages
PACKAGES = ("envs", "estimation", "control")  #: where compiled kernels live


def kernel_fingerprint(root: Path = ROOT, packages: tuple[str, ...] = PACKAGES) -> str:
    """16 hex digits hashing the path and source of every ``.py`` file under ``root/packages``
    that uses numba (a file mentioning ``numba``); other files do not affect it."""
    digest = hashlib.sha256()
    for package in packages:
        for path in sorted((root / package).glob("*.py")):
            source = path.read_bytes()
            if b"numba" in source:
                digest.update(path.relative_to(root).as_posix().encode() + b"\0" + source + b"\0")
    return digest.hexdigest()[:16]


def cache_dir(root: Path = ROOT) -> Path:
    """Where the compiled kernels of the sources under ``root`` are cached (module docstring)."""
    if (root / "pyproject.toml").is_file():  # a checkout
        return root / ".numba_cache" / kernel_fingerprint(root)
    user_cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return user_cache / "fourwis" / "numba" / kernel_fingerprint(root)


if not numba.config.CACHE_DIR:
    numba.config.CACHE_DIR = str(cache_dir())


#: bytes of stack reserved by each compiled :func:`scratch` call site (larger requests go to
#: the heap); the estimator's largest work array is 13 x 7 doubles (728 bytes)
SCRATCH_BYTES = 1024


def scratch(shape: tuple[int, ...], dtype=np.float64) -> np.ndarray:
    """Uninitialised work array of ``shape`` (a tuple) for compiled kernels: in compiled code
    it lives on the caller's stack (a heap array if it needs more than SCRATCH_BYTES); called
    from Python, or with NUMBA_DISABLE_JIT, it is a plain ``np.empty``.

    Only for arrays that do not outlive the compiled function that creates them: never return
    one, store it, or keep one across iterations of a loop (each call site owns one buffer)."""
    return np.empty(shape, dtype)


@overload(scratch, inline="always", jit_options=JIT)
def _scratch_compiled(shape, dtype=np.float64):
    """The compiled :func:`scratch`, inlined so that its stack bytes are the caller's."""
    # the element type as a compile-time constant (dtype left out: float64)
    element = numpy_support.as_dtype(dtype.dtype).type if isinstance(dtype, types.NumberClass) else np.float64

    def stack_or_heap(shape, dtype=np.float64):
        if _nbytes(shape, element) <= SCRATCH_BYTES:
            return _stack_array(shape, element)
        return np.empty(shape, element)

    return stack_or_heap


def fixed_tuple(array: np.ndarray, n: int) -> tuple:
    """The first ``n`` elements of the 1-D ``array`` as a tuple. In compiled code ``n`` must be
    a compile-time constant and the tuple is a value (numba's ``to_fixed_tuple``): unlike an
    array, it can be handed to inlined functions inside a loop that the compiler should run in
    SIMD lanes. From Python, and under NUMBA_DISABLE_JIT, a plain tuple."""
    return tuple(array[:n])


@overload(fixed_tuple, inline="always", prefer_literal=True, jit_options=JIT)
def _fixed_tuple_compiled(array, n):
    if not isinstance(n, types.IntegerLiteral):
        return None
    size = n.literal_value
    return lambda array, n: to_fixed_tuple(array, size)


@intrinsic
def _stack_array(typingctx, shape, dtype):
    """Uninitialised C-contiguous array of ``shape`` (a tuple of ints) and ``dtype`` in the
    calling function's stack frame: SCRATCH_BYTES reserved once in its entry block (so a call
    in a loop reuses the same bytes), no meminfo (so no reference counting and no free)."""
    if not (isinstance(shape, types.UniTuple) and isinstance(shape.dtype, types.Integer)
            and isinstance(dtype, types.NumberClass)):
        return None
    array_type = types.Array(dtype.dtype, shape.count, "C")

    def codegen(context, builder, signature, args):
        intp = context.get_value_type(types.intp)
        element = context.get_data_type(dtype.dtype)
        itemsize = context.get_abi_sizeof(element)
        buffer = cgutils.alloca_once(builder, ir.DoubleType(), size=ir.Constant(intp, SCRATCH_BYTES // 8))
        sizes = [context.cast(builder, size, shape.dtype, types.intp)
                 for size in cgutils.unpack_tuple(builder, args[0], shape.count)]
        strides, stride = [], ir.Constant(intp, itemsize)
        for size in reversed(sizes):
            strides.insert(0, stride)
            stride = builder.mul(stride, size)
        array = make_array(array_type)(context, builder)
        populate_array(array, data=builder.bitcast(buffer, element.as_pointer()), shape=sizes, strides=strides,
                       itemsize=ir.Constant(intp, itemsize), meminfo=None)
        return array._getvalue()

    return array_type(shape, dtype), codegen


@intrinsic
def _nbytes(typingctx, shape, dtype):
    """Bytes of an array of ``shape`` (a tuple of ints) and NumPy scalar type ``dtype``."""
    if not (isinstance(shape, types.UniTuple) and isinstance(shape.dtype, types.Integer)
            and isinstance(dtype, types.NumberClass)):
        return None

    def codegen(context, builder, signature, args):
        size = context.get_constant(types.intp, context.get_abi_sizeof(context.get_data_type(dtype.dtype)))
        for extent in cgutils.unpack_tuple(builder, args[0], shape.count):
            size = builder.mul(size, context.cast(builder, extent, shape.dtype, types.intp))
        return size

    return types.intp(shape, dtype), codegen
