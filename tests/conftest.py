"""Fixtures shared by the test modules, and the numba threads of pytest-xdist workers."""

import os

import pytest

from fourwis.core.kernels import set_threads

if os.environ.get("PYTEST_XDIST_WORKER"):
    # `pytest -n 2` runs a worker process per core: one kernel thread each, so the workers do
    # not oversubscribe the cores. tests/test_threads.py raises the count again to exercise the
    # parallel kernels on two threads.
    set_threads(1)


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


@pytest.fixture(scope="session")
def ray_instance():
    """ONE local Ray instance for the whole session (2 CPUs, no dashboard, a small object store),
    shut down at its end. Its tests carry ``xdist_group("ray")`` and the test command runs
    ``--dist loadgroup``, so under pytest-xdist they share one worker process, hence one
    instance. Skipped without the ray extra."""
    ray = pytest.importorskip("ray", reason="the ray extra is not installed")
    if not ray.is_initialized():
        # tests/ on the workers' path too (custom_models.py: the tests' own estimators and controllers);
        # a local instance's workers have the driver's working directory, not pytest's sys.path
        path = os.pathsep.join(p for p in (os.path.dirname(__file__), os.environ.get("PYTHONPATH")) if p)
        ray.init(
            num_cpus=2,
            include_dashboard=False,
            object_store_memory=256 * 2**20,
            logging_level="WARNING",
            runtime_env={"env_vars": {"PYTHONPATH": path}},
        )
    yield ray
    ray.shutdown()
