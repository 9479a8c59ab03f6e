"""Fixtures shared by the test modules."""

import pytest


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
