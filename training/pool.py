"""Run independent simulations on a backend: worker processes here, or Ray tasks on a cluster.

One driver for both (:func:`parallel_map`): every item is submitted as a future (a
``ProcessPoolExecutor``'s, or a Ray ``ObjectRef``'s ``future()``), the progress bar advances
as runs finish, in whatever order, and results are yielded in the items' order, so a sweep
writes the same tables on either backend. The backends:

* ``local`` (default): a process pool of ``jobs`` workers (default: up to 2).
* ``ray``: Ray tasks (:data:`MAX_RETRIES` retries of a task whose worker or node died; a task
  that raises is not retried and fails the sweep with its own exception). ``address`` None
  starts a local Ray instance (or uses the one this process already joined); ``"auto"``, a
  head's ``host:6379`` or ``ray://host:10001`` joins a running cluster. ``jobs`` caps the tasks
  in flight (default: all of them, scheduled by Ray over the cluster's CPUs).
"""

from __future__ import annotations

import importlib.util
import os
import signal
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, TypeVar

from fourwis.core.checks import is_integer
from fourwis.core.kernels import max_threads, share_cores
from fourwis.core.progress import progress as progress_bar

T = TypeVar("T")
R = TypeVar("R")

BACKENDS = ("local", "ray")
MAX_RETRIES = 3  #: Ray retries of a task whose worker process or node died (system failures only)
RAY_EXTRA_MISSING = "--backend ray needs Ray: pip install 'fourwis[ray]'"


class WorkerLostError(RuntimeError):
    """A worker process died (killed, out of memory) and the run could not be finished."""


@dataclass(frozen=True)
class Backend:
    """Where a sweep runs: ``name`` ``"local"`` (a process pool on this machine) or ``"ray"``
    (Ray tasks); ``address`` (Ray only) as ``ray.init`` takes it: None starts a local instance,
    ``"auto"``, ``host:port`` or ``ray://host:port`` joins a cluster. Bad values raise
    ValueError naming them; ``"ray"`` without Ray installed raises ModuleNotFoundError naming
    the extra (both at construction, before any run)."""

    name: str = "local"
    address: str | None = None

    def __post_init__(self) -> None:
        if self.name not in BACKENDS:
            raise ValueError(f"unknown backend {self.name!r}; known: {list(BACKENDS)}")
        if self.address is not None:
            if self.name != "ray":
                raise ValueError(f"an address ({self.address!r}) needs the ray backend (--backend ray), not local")
            if not (isinstance(self.address, str) and self.address.strip()):
                raise ValueError(
                    f"address must be a non-empty string (auto, host:port, ray://host:port), got {self.address!r}"
                )
        if self.name == "ray" and importlib.util.find_spec("ray") is None:
            raise ModuleNotFoundError(RAY_EXTRA_MISSING)


def as_backend(backend: Backend | str | None) -> Backend:
    """``backend`` as a :class:`Backend` (None: local; a name: that backend on its defaults)."""
    if backend is None:
        return Backend()
    if isinstance(backend, Backend):
        return backend
    if isinstance(backend, str):
        return Backend(backend)
    raise ValueError(f"backend must be a name {list(BACKENDS)} or a Backend, got {backend!r}")


def parallel_map(
    fn: Callable[[T], R],
    items: Sequence[T],
    jobs: int | None,
    desc: str,
    progress: bool = True,
    backend: Backend | str | None = None,
) -> Iterator[R]:
    """``fn`` over ``items`` on ``backend`` (default: ``jobs`` local processes, up to 2), results
    in the items' order, a tqdm bar advancing as runs finish. A bad ``jobs`` or ``backend``
    raises ValueError at once, not at the first result (:func:`check_jobs`). ``fn`` and the
    items must pickle (a module-level function; on Ray, importable on every node)."""
    check_jobs(jobs)
    backend = as_backend(backend)
    return _map(fn, list(items), jobs, desc, progress, backend)


def _map(fn, items: list, jobs: int | None, desc: str, progress: bool, backend: Backend) -> Iterator:
    with open_pool(backend, jobs) as pool:
        yield from pool.map(fn, items, desc, progress)


def check_jobs(jobs) -> None:
    """ValueError naming ``jobs`` unless it is None (up to 2 workers) or an integer >= 1."""
    if jobs is not None and not is_integer(jobs):
        raise ValueError(f"jobs must be an integer (None: up to 2), got {jobs!r}")
    if jobs is not None and jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs!r}")


@contextmanager
def open_pool(backend: Backend | str | None = None, jobs: int | None = None) -> Iterator[Pool]:
    """A :class:`Pool` on ``backend`` kept open for several maps (an optimiser's populations);
    a local pool's processes end with the block, a Ray instance stays up for the process."""
    check_jobs(jobs)
    backend = as_backend(backend)
    pool = RayPool(backend.address, jobs) if backend.name == "ray" else LocalPool(jobs)
    try:
        yield pool
    finally:
        pool.close()


class Pool:
    """An open backend: :meth:`map` submits, :meth:`share` places a large read-only object once
    (an optimiser's calibration run) for every task to :func:`shared` it, :attr:`slots` is how
    many tasks run at once."""

    slots: int

    def submit(self, fn: Callable, item) -> Future:
        raise NotImplementedError

    def share(self, value) -> Any:
        return value

    def close(self) -> None:
        pass

    def map(self, fn: Callable[[T], R], items: Sequence[T], desc: str, progress: bool = True) -> Iterator[R]:
        """``fn`` over ``items``, yielded in order as soon as each and those before it finished."""
        items = list(items)
        limit = self.in_flight(len(items))
        pending: dict[Future, int] = {}
        done: dict[int, Any] = {}
        submitted = yielded = 0
        with progress_bar(len(items), desc, "run", disable=not progress) as bar:
            try:
                while yielded < len(items):
                    while submitted < len(items) and len(pending) < limit:
                        pending[self.submit(fn, items[submitted])] = submitted
                        submitted += 1
                    finished, _ = wait(list(pending), return_when=FIRST_COMPLETED)
                    for future in finished:
                        done[pending.pop(future)] = self.result(future)
                        bar.update()
                    while yielded in done:
                        yield done.pop(yielded)
                        yielded += 1
            finally:
                self.cancel(list(pending))

    def in_flight(self, n: int) -> int:
        return max(1, n)

    def result(self, future: Future):
        return future.result()

    def cancel(self, futures: list[Future]) -> None:
        for future in futures:
            future.cancel()


class LocalPool(Pool):
    """``jobs`` worker processes on this machine (default: up to 2); a dead worker breaks the
    pool (no retry): :class:`WorkerLostError`."""

    def __init__(self, jobs: int | None = None):
        self.slots = jobs or min(os.cpu_count() or 1, 2)
        self._executor: ProcessPoolExecutor | None = None

    def submit(self, fn: Callable, item) -> Future:
        if self._executor is None:  # (lazily: a pool opened for in-process work starts no process)
            self._executor = ProcessPoolExecutor(self.slots, initializer=_start_worker, initargs=(self.slots,))
        return self._executor.submit(fn, item)

    def result(self, future: Future):
        try:
            return future.result()
        except BrokenProcessPool as err:
            raise WorkerLostError(f"a worker process died ({err}); the local pool does not retry") from err

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(cancel_futures=True)


def _start_worker(slots: int) -> None:
    """A local worker's start: it leaves Ctrl-C to the parent, which cancels what has not started
    and waits for the runs in progress (a terminal sends the signal to every process of the group;
    a worker interrupted inside the pool's queues can leave the parent's shutdown waiting on it for
    ever), and takes its share of the cores (share_cores)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    share_cores(slots)


class RayPool(Pool):
    """Ray tasks on the instance at ``address`` (see :class:`Backend`); ``jobs`` caps the tasks
    in flight (default: all; Ray schedules them on the cluster's CPUs)."""

    def __init__(self, address: str | None = None, jobs: int | None = None):
        ray = _ray()
        if not ray.is_initialized():
            ray.init(address=address, include_dashboard=False, logging_level="WARNING")
        self._ray, self._jobs = ray, jobs
        self.slots = jobs or max(1, int(ray.cluster_resources().get("CPU", 1)))
        self._apply = ray.remote(max_retries=MAX_RETRIES, retry_exceptions=False)(_apply)

    def in_flight(self, n: int) -> int:
        return max(1, min(n, self._jobs or n))

    def submit(self, fn: Callable, item) -> Future:
        ref = self._apply.remote(fn, item)
        future = ref.future()
        future.ref = ref  # (for cancel)
        return future

    def share(self, value):
        return _Shared(self._ray.put(value))

    def result(self, future: Future):
        from ray.exceptions import NodeDiedError, OutOfMemoryError, RayTaskError, WorkerCrashedError

        try:
            return future.result()
        except RayTaskError as err:  # the task's own exception, without Ray's traceback around it
            cause = err.cause
            if isinstance(cause, BaseException):
                raise cause from None
            raise
        except (WorkerCrashedError, NodeDiedError, OutOfMemoryError) as err:
            raise WorkerLostError(f"a Ray worker died {MAX_RETRIES + 1} times on one run: {err}") from None

    def cancel(self, futures: list[Future]) -> None:
        for future in futures:
            self._ray.cancel(future.ref)


def _apply(fn: Callable, item):
    """The Ray task: ``fn(item)`` (one remote function for every sweep, so that any picklable
    callable, a functools.partial too, runs as a task). A task holds one of Ray's CPUs: its
    kernels run on one thread unless a count was set."""
    share_cores(max_threads())
    return fn(item)


class _Shared:
    """A value placed in Ray's object store once, fetched (and cached) by each worker."""

    def __init__(self, ref):
        self.ref = ref


def shared(value):
    """What :meth:`Pool.share` placed: the value itself (fetched from Ray's object store on Ray)."""
    if isinstance(value, _Shared):
        return _ray().get(value.ref)
    return value


def _ray():
    try:
        import ray
    except ModuleNotFoundError as err:  # optional dependency (a broken install raises its own error)
        raise ModuleNotFoundError(RAY_EXTRA_MISSING) from err
    return ray
