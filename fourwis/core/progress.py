"""Progress bars that keep their clock running, and the first run's compile notice.

A tqdm bar redraws only when it advances, so while the first step of a first run compiles the
numba kernels (minutes on 2 cores) it shows neither progress nor elapsed time. :func:`progress`
is a tqdm bar redrawn every second by a daemon thread until it closes, and says in its
description when the kernels are being compiled for the first time (:func:`cache_is_cold`).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numba
from tqdm import tqdm

#: what a bar adds to its description while the kernels compile (measured: 3-4 min for one
#: closed loop on 2 cores, docs/decisions/0032-kernel-threads.md)
COMPILING = "compiling numba kernels: first run on this machine, a few minutes; cached for later runs"


def cache_is_cold() -> bool:
    """True when numba's cache folder (:func:`fourwis.core.kernels.cache_dir`) holds no compiled
    closed loop (fourwis.envs.loop.run_cars, the kernel that takes minutes): this version of the
    kernels has not run a closed loop on this machine. (Small kernels compile at import, so any
    cached file is no sign.)"""
    folder = Path(numba.config.CACHE_DIR or ".")
    return not (folder.is_dir() and any(folder.rglob("loop.run_cars-*.nbi")))


@contextmanager
def progress(total: int | None, desc: str, unit: str, disable: bool = False, **options) -> Iterator[tqdm]:
    """A tqdm bar (``total`` items of ``unit``, ``options`` as tqdm's) redrawn every second, its
    description naming the compilation when the cache is cold until the first item is done."""
    cold = not disable and cache_is_cold()
    with tqdm(total=total, desc=f"{desc} [{COMPILING}]" if cold else desc, unit=unit, disable=disable,
              **options) as bar:  # fmt: skip
        stop = threading.Event()

        def tick() -> None:
            compiling = cold
            while not stop.wait(1.0):
                if compiling and bar.n > 0:
                    bar.set_description_str(desc, refresh=False)
                    compiling = False
                bar.refresh()

        ticker = threading.Thread(target=tick, name="fourwis-progress", daemon=True)
        if not disable:
            ticker.start()
        try:
            yield bar
        finally:
            stop.set()
            if ticker.is_alive():
                ticker.join()
            if cold:
                bar.set_description_str(desc, refresh=False)
