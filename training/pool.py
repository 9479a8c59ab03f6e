"""Run independent simulations in worker processes with a progress bar."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import TypeVar

from tqdm import tqdm

T = TypeVar("T")
R = TypeVar("R")


def parallel_map(fn: Callable[[T], R], items: Sequence[T], jobs: int | None, desc: str,
                 progress: bool = True) -> Iterator[R]:
    """``fn`` over ``items`` in ``jobs`` processes (default: up to 2), in order, with a tqdm bar."""
    jobs = jobs or min(os.cpu_count() or 1, 2)
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        yield from tqdm(pool.map(fn, items), total=len(items), disable=not progress, desc=desc, unit="run")
