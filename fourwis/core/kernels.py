"""The compiled-kernel plumbing every layer shares: numba options, an on-disk cache that follows
the code, stack scratch arrays and the small vector helpers.

numba's cache (``cache=True``) is invalidated only when the source file of the cached function
itself changes, not when a function it calls from another module does (numba documentation,
"Notes on caching"). fourwis's kernels call across modules and packages (the estimators inline
the estimation model, the compiled loop inlines every stage), so importing this module points
numba's cache at ``<checkout>/.numba_cache/<fingerprint>`` (an installed package:
``$XDG_CACHE_HOME/fourwis/numba/<fingerprint>``, default ``~/.cache``, so that site-packages
stays as pip left it), the fingerprint hashing the source of every fourwis module that uses
numba: after an edit to any of them everything compiles afresh once, and switching back to an
earlier version finds its cache again. A ``NUMBA_CACHE_DIR`` set by the user is left as it is
(and with it numba's own invalidation rule) (docs/decisions/0007-numba-cache-fingerprint.md).

Every kernel module imports :data:`JIT` from here, so the cache directory is set before its
first decorator runs (numba's process-wide ``config.CACHE_DIR``).

:func:`scratch` gives kernels small work arrays on the stack instead of the heap: numba
allocates each heap array with malloc and an atomically reference-counted header, which costs
a sizeable share of a filter step made of ~140 small arrays; stack arrays also let the compiler
prove that a loop's arrays do not overlap, which it needs before it runs the loop in SIMD lanes
(docs/decisions/0006-estimator-kernel-scratch-and-simd.md).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import inspect
import os
from concurrent.futures import ThreadPoolExecutor
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

from fourwis.core.checks import is_integer

#: options of every fourwis kernel: cached on disk, NumPy's floating-point error semantics
#: (division by zero gives inf/nan instead of raising, as in vectorised NumPy code)
JIT = dict(cache=True, error_model="numpy")

#: the packages whose modules hold compiled kernels
KERNEL_PACKAGES = ("fourwis.core", "fourwis.envs", "fourwis.estimation", "fourwis.control")


def package_dirs(packages: tuple[str, ...] = KERNEL_PACKAGES) -> list[Path]:
    """The folders of ``packages`` (found without importing them: the layers map to folders of
    their own in a checkout, pyproject.toml's package-dir)."""
    return [Path(importlib.util.find_spec(name).submodule_search_locations[0]) for name in packages]


def kernel_fingerprint(folders: list[Path] | None = None) -> str:
    """16 hex digits hashing the package-relative path and source of every ``.py`` file in
    ``folders`` (default: :func:`package_dirs`) that uses numba (a file mentioning ``numba``)."""
    digest = hashlib.sha256()
    for folder in package_dirs() if folders is None else folders:
        for path in sorted(folder.glob("*.py")):
            source = path.read_bytes()
            if b"numba" in source:
                digest.update(f"{folder.name}/{path.name}".encode() + b"\0" + source + b"\0")
    return digest.hexdigest()[:16]


def cache_dir(folders: list[Path] | None = None) -> Path:
    """Where the compiled kernels of the sources in ``folders`` are cached (module docstring):
    beside pyproject.toml in a checkout, else in the user's cache."""
    folders = package_dirs() if folders is None else folders
    checkout = folders[-1].parent
    if (checkout / "pyproject.toml").is_file():
        return checkout / ".numba_cache" / kernel_fingerprint(folders)
    user_cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return user_cache / "fourwis" / "numba" / kernel_fingerprint(folders)


if not numba.config.CACHE_DIR:
    numba.config.CACHE_DIR = str(cache_dir())


#: bytes of stack reserved by each compiled :func:`scratch` call site (larger requests go to
#: the heap); the estimator's largest work array is 13 x 7 doubles (728 bytes)
#: (docs/decisions/0006-estimator-kernel-scratch-and-simd.md)
SCRATCH_BYTES = 1024
#: bytes a :func:`scratch` array whose shape is all compile-time constants may take on the stack
#: (exactly its size; larger ones go to the heap): the lane kernels' blocks of cars, e.g. 12
#: cubature points x 7 measurements x 64 cars (43 KB) (docs/decisions/0046-lane-estimator.md)
STACK_LIMIT = 128 * 1024


def scratch(shape: tuple[int, ...], dtype=np.float64) -> np.ndarray:
    """Uninitialised work array of ``shape`` (a tuple) for compiled kernels: in compiled code
    it lives on the caller's stack (a heap array if it needs more than SCRATCH_BYTES; a shape of
    compile-time constants, e.g. literal arguments or module constants, takes exactly its bytes,
    up to STACK_LIMIT); called from Python, or with NUMBA_DISABLE_JIT, it is a plain ``np.empty``.

    Only for arrays that do not outlive the compiled function that creates them: never return
    one, store it, or keep one across iterations of a loop (each call site owns one buffer)."""
    return np.empty(shape, dtype)


@overload(scratch, inline="always", prefer_literal=True, jit_options=JIT)
def _scratch_compiled(shape, dtype=np.float64):
    """The compiled :func:`scratch`, inlined so that its stack bytes are the caller's."""
    # the element type as a compile-time constant (dtype left out: float64)
    element = numpy_support.as_dtype(dtype.dtype).type if isinstance(dtype, types.NumberClass) else np.float64
    size = _literal_bytes(shape, element)
    if size is not None:  # a shape of compile-time constants: exactly its bytes, up to STACK_LIMIT
        if size <= STACK_LIMIT:
            return lambda shape, dtype=np.float64: _stack_array(shape, element)
        return lambda shape, dtype=np.float64: np.empty(_intp_shape(shape), element)

    def stack_or_heap(shape, dtype=np.float64):
        if _nbytes(shape, element) <= SCRATCH_BYTES:
            return _stack_array(shape, element)
        return np.empty(_intp_shape(shape), element)

    return stack_or_heap


def _literal_bytes(shape, element) -> int | None:
    """The bytes of a scratch array of ``shape`` (a numba type) if all its extents are compile-time
    constants (IntegerLiteral), else None."""
    if not (isinstance(shape, types.BaseTuple) and all(isinstance(t, types.IntegerLiteral) for t in shape)):
        return None
    return int(np.prod([t.literal_value for t in shape], dtype=np.int64)) * np.dtype(element).itemsize


def _integer_shape(shape) -> bool:
    """Whether the numba type ``shape`` is a tuple of integers (constants or not)."""
    return isinstance(shape, types.BaseTuple) and all(isinstance(t, types.Integer) for t in shape)


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


@intrinsic(prefer_literal=True)
def _stack_array(typingctx, shape, dtype):
    """Uninitialised C-contiguous array of ``shape`` (a tuple of ints) and ``dtype`` in the
    calling function's stack frame, reserved once in its entry block (so a call in a loop reuses
    the same bytes): exactly its size, 64-byte aligned, for a shape of compile-time constants,
    else SCRATCH_BYTES; no meminfo (so no reference counting and no free)."""
    if not (_integer_shape(shape) and isinstance(dtype, types.NumberClass)):
        return None
    array_type = types.Array(dtype.dtype, len(shape), "C")
    exact = _literal_bytes(shape, numpy_support.as_dtype(dtype.dtype))

    def codegen(context, builder, signature, args):
        intp = context.get_value_type(types.intp)
        element = context.get_data_type(dtype.dtype)
        itemsize = context.get_abi_sizeof(element)
        doubles = SCRATCH_BYTES // 8 if exact is None else max(1, -(-exact // 8))
        buffer = cgutils.alloca_once(builder, ir.DoubleType(), size=ir.Constant(intp, doubles))
        if exact is not None:
            buffer.align = 64  # (a cache line: whole vectors of lanes)
            sizes = [ir.Constant(intp, t.literal_value) for t in shape]
        else:
            sizes = [
                context.cast(builder, size, t, types.intp)
                for size, t in zip(cgutils.unpack_tuple(builder, args[0], len(shape)), shape)
            ]
        strides, stride = [], ir.Constant(intp, itemsize)
        for size in reversed(sizes):
            strides.insert(0, stride)
            stride = builder.mul(stride, size)
        array = make_array(array_type)(context, builder)
        populate_array(
            array,
            data=builder.bitcast(buffer, element.as_pointer()),
            shape=sizes,
            strides=strides,
            itemsize=ir.Constant(intp, itemsize),
            meminfo=None,
        )
        return array._getvalue()

    return array_type(shape, dtype), codegen


@intrinsic
def _nbytes(typingctx, shape, dtype):
    """Bytes of an array of ``shape`` (a tuple of ints) and NumPy scalar type ``dtype``."""
    if not (_integer_shape(shape) and isinstance(dtype, types.NumberClass)):
        return None

    def codegen(context, builder, signature, args):
        size = context.get_constant(types.intp, context.get_abi_sizeof(context.get_data_type(dtype.dtype)))
        for extent, t in zip(cgutils.unpack_tuple(builder, args[0], len(shape)), shape):
            size = builder.mul(size, context.cast(builder, extent, t, types.intp))
        return size

    return types.intp(shape, dtype), codegen


@intrinsic
def _intp_shape(typingctx, shape):
    """A tuple of ints (constants or not) as a tuple of intp, as ``np.empty`` takes a shape."""
    if not _integer_shape(shape):
        return None
    result = types.UniTuple(types.intp, len(shape))

    def codegen(context, builder, signature, args):
        values = [
            context.cast(builder, v, t, types.intp) for v, t in zip(cgutils.unpack_tuple(builder, args[0]), shape)
        ]
        return context.make_tuple(builder, result, values)

    return result(shape), codegen


def borrowed(bundle):
    """``bundle`` (an array, or a tuple / NamedTuple nesting arrays and other values) with every
    array in it a borrowed view: the same data, shape and strides, without an owner whose count
    of references the compiled code keeps. A kernel entry point calls it once on each bundle it is
    handed, so that the functions it calls with them count nothing: numba increfs every array of a
    bundle at the entry of a function that branches and decrefs them at its exits, and LLVM merges
    those exits (a phi) before numba's pruning pass looks, so each such call costs two atomic
    operations per array (docs/decisions/0049-borrowed-bundles.md). Only for bundles the caller
    keeps alive for the whole call, never returned or stored. From Python, and with
    NUMBA_DISABLE_JIT, ``bundle`` itself."""
    return bundle


@overload(borrowed, jit_options=JIT)
def _borrowed_compiled(bundle):
    # (a call, not inlined: numba 0.68's IR inlining of this overload into a function that
    # rebinds the bundle's name drops that function's own writes through it; the test has one)
    return lambda bundle: _borrow(bundle)


def _borrowed_value(context, builder, value_type, value):
    """:func:`borrowed`'s code for one value of numba type ``value_type``: an array's meminfo and
    parent set to NULL, a tuple's items in turn, any other value as it is (with the reference the
    result owns, where its type counts them)."""
    if isinstance(value_type, types.Array):
        array = make_array(value_type)(context, builder, value=value)
        array.meminfo = cgutils.get_null_value(array.meminfo.type)
        array.parent = cgutils.get_null_value(array.parent.type)
        return array._getvalue()
    if isinstance(value_type, types.BaseTuple):
        for i, item_type in enumerate(value_type.types):
            item = builder.extract_value(value, i)
            value = builder.insert_value(value, _borrowed_value(context, builder, item_type, item), i)
        return value
    context.nrt.incref(builder, value_type, value)
    return value


@intrinsic
def _borrow(typingctx, bundle):
    """The compiled :func:`borrowed`."""

    def codegen(context, builder, signature, args):
        return _borrowed_value(context, builder, signature.args[0], args[0])

    return bundle(bundle), codegen


@numba.njit(inline="always", **JIT)
def dot(a: np.ndarray, b: np.ndarray) -> float:
    """sum_i a_i b_i, summed in index order (as numba's ``(a * b).sum()``, without the
    temporary array)."""
    t = 0.0
    for i in range(a.shape[0]):
        t += a[i] * b[i]
    return t


@numba.njit(**JIT)
def matmul(A: np.ndarray, B: np.ndarray, out: np.ndarray) -> None:
    """out = A @ B for small matrices (plain loops: numba's BLAS call cannot be cached); out
    must not overlap A or B."""
    out[:, :] = 0.0
    for i in range(A.shape[0]):
        for k in range(A.shape[1]):
            a = A[i, k]
            for j in range(B.shape[1]):
                out[i, j] += a * B[k, j]


def bundle_dispatch(name: str, parameters: str):
    """A function ``name(parameters)`` (e.g. ``"controller, b, sample"``) that runs the
    implementation registered for the NamedTuple class of its first argument
    (``@function.register(BundleClass)``, an implementation with the same parameters): how a
    compiled stage dispatches on the kind of component it is handed. In compiled code the choice is
    made when the caller compiles and the implementation is inlined into it (one specialisation
    per bundle type, no branch and no bundle copied at run time); from Python, and with
    NUMBA_DISABLE_JIT, by the argument's type."""
    implementations: dict[type, object] = {}
    first = parameters.split(",")[0].strip()
    namespace = {"_implementations": implementations}
    exec(  # (numba matches an overload's parameters by name: the stub is written with the stage's own)
        f"def {name}({parameters}):\n    return _implementations[type({first})]({parameters})\n"
        f"def _typing({parameters}):\n    return _implementations.get(getattr({first}, 'instance_class', None))\n",
        namespace,
    )
    dispatcher = namespace[name]

    def register(bundle_class: type):
        def add(implementation):
            if list(inspect.signature(implementation).parameters) != [p.strip() for p in parameters.split(",")]:
                raise TypeError(f"{implementation.__name__} must take ({parameters}), as {name} does")
            implementations[bundle_class] = implementation
            return implementation

        return add

    dispatcher.register = register
    dispatcher.__doc__ = f"{name}({parameters}): dispatched on the type of {first} (:func:`bundle_dispatch`)."
    overload(dispatcher, jit_options=JIT, inline="always")(namespace["_typing"])
    return dispatcher


@functools.cache
def _thread_pool(threads: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(threads, thread_name_prefix="fourwis-kernel")


os.register_at_fork(after_in_child=_thread_pool.cache_clear)  # (a forked child has none of the parent's threads)


#: the environment variable that sets the batched kernels' thread count (as ``--threads`` does)
THREADS_VARIABLE = "FOURWIS_THREADS"
_threads: int | None = None


#: the machine's cores, counted once: ``os.cpu_count()`` reads /sys on every call (~15 us on
#: Linux), which every batched kernel entry would pay (docs/decisions/0041-per-call-cost.md)
CORES = os.cpu_count() or 1


def max_threads() -> int:
    """The most threads the kernels take: the machine's cores (as many as numba's
    NUMBA_NUM_THREADS, if that is set lower)."""
    return max(1, min(CORES, numba.config.NUMBA_NUM_THREADS))


def set_threads(threads: int | None) -> None:
    """Run the batched kernels (:func:`run_parallel`) on ``threads`` threads, 1 to
    :func:`max_threads`; ``None``: back to the default (FOURWIS_THREADS, else every core)."""
    global _threads
    if threads is not None and (not is_integer(threads) or not 1 <= threads <= max_threads()):
        raise ValueError(f"threads must be an integer from 1 to {max_threads()} (the cores here), got {threads!r}")
    _threads = None if threads is None else int(threads)


def share_cores(workers: int) -> None:
    """In one of ``workers`` processes that run at once on this machine: its share of the cores
    (at least 1) unless a count was set (:func:`set_threads`, FOURWIS_THREADS), so that the
    workers' kernel threads do not outnumber the cores (docs/decisions/0032-kernel-threads.md)."""
    if _threads is None and THREADS_VARIABLE not in os.environ:
        set_threads(max(1, max_threads() // max(1, workers)))


def kernel_threads() -> int:
    """The batched kernels' thread count: :func:`set_threads`'s, else FOURWIS_THREADS, else every
    core (the faster default for one process on 2 cores: docs/decisions/0032-kernel-threads.md)."""
    if _threads is not None:
        return _threads
    value = os.environ.get(THREADS_VARIABLE)
    if value is None:
        return max_threads()
    try:
        threads = int(value)
    except ValueError:
        threads = None
    if threads is None or not 1 <= threads <= max_threads():
        raise ValueError(f"{THREADS_VARIABLE} must be an integer from 1 to {max_threads()}, got {value!r}")
    return threads


def run_parallel(kernel, items: np.ndarray, *args, min_items: int = 2) -> None:
    """``kernel(part, *args)`` over the parts of ``items`` (int64 (N,)), one part per thread of
    :func:`kernel_threads` when there are at least ``min_items``, else ``kernel(items, *args)``
    on this thread. ``kernel`` must be compiled with ``nogil=True`` and write only to its own
    items' rows. Python threads rather than numba's ``prange``: a parallel loop cannot take the
    NamedTuple bundles the kernels are given."""
    # (the batch size first: one car's step skips the thread count's look-ups)
    if len(items) < min_items or (threads := min(kernel_threads(), len(items))) < 2:
        kernel(items, *args)
        return
    list(_thread_pool(threads).map(lambda part: kernel(part, *args), np.array_split(items, threads)))
