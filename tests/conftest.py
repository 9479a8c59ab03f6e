"""Fixtures shared by the test modules, and the numba threads of pytest-xdist workers."""

import os

import numba
import pytest

if os.environ.get("PYTEST_XDIST_WORKER"):
    # `pytest -n 2` runs a worker process per core: one numba thread each. With numba's default
    # (a thread per core in every worker) the cores are oversubscribed, and the waiting OpenMP
    # threads spin: estimator steps of small batches ran 3-18x slower. tests/test_threads.py
    # raises the count again to exercise the parallel kernels on two threads.
    numba.set_num_threads(1)


@pytest.fixture
def heap_allocations():
    """``count(fn)``: numba heap allocations made while ``fn()`` runs (numba's runtime
    statistics, switched on for the test)."""
    from numba.core.runtime import _nrt_python, rtsys

    was_on = _nrt_python.memsys_stats_enabled()
    _nrt_python.memsys_enable_stats()

    def count(fn) -> int:
        before = rtsys.get_allocation_stats().alloc
        fn()
        return rtsys.get_allocation_stats().alloc - before

    yield count
    if not was_on:
        _nrt_python.memsys_disable_stats()
