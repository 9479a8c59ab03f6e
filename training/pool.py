"""Run independent simulations in worker processes with a progress bar."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import TypeVar

from tqdm import tqdm

from fourwis.core.checks import is_integer

T = TypeVar("T")
R = TypeVar("R")


def parallel_map(
    fn: Callable[[T], R], items: Sequence[T], jobs: int | None, desc: str, progress: bool = True
) -> Iterator[R]:
    """``fn`` over ``items`` in ``jobs`` processes (default: up to 2), in order, with a tqdm bar;
    a bad ``jobs`` raises ValueError at once, not at the first result (:func:`check_jobs`)."""
    check_jobs(jobs)
    return _map(fn, items, jobs or min(os.cpu_count() or 1, 2), desc, progress)


def check_jobs(jobs) -> None:
    """ValueError naming ``jobs`` unless it is None (up to 2 workers) or an integer >= 1."""
    if jobs is not None and not is_integer(jobs):
        raise ValueError(f"jobs must be an integer (None: up to 2), got {jobs!r}")
    if jobs is not None and jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs!r}")


def _map(fn: Callable[[T], R], items: Sequence[T], jobs: int, desc: str, progress: bool) -> Iterator[R]:
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        yield from tqdm(pool.map(fn, items), total=len(items), disable=not progress, desc=desc, unit="run")
