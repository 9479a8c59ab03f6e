"""Kernel thread counts side by side (issue 36): the single env, the native vector env of 16, 64
and 256 cars and a small ``fourwis compare`` (2 worker processes), each with FOURWIS_THREADS=1
and with every core, alternating, each measurement in a fresh process, and compare with the
default threads (every core in one process, a share of them in each worker process:
:func:`fourwis.core.kernels.share_cores`).

Run: ``.venv/bin/python benchmarks/bench_threads.py`` (or ``fourwis bench --only threads``).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import report

from fourwis.core.kernels import max_threads

HERE = Path(__file__).resolve().parent
ROUNDS = 2  #: alternating rounds per thread count (the best is reported)
COMPARE = ["compare", "--scenarios", "paper_dlc", "mu_jump", "--estimators", "ckf", "joint", "--seeds", "2"]


def _env_rate(threads: int, n: int) -> float:
    """Env steps per second of bench_env's single env (``n`` 0) or vector env of ``n`` cars, joint."""
    code = (
        f"import sys; sys.path.insert(0, {str(HERE)!r}); import bench_env; "
        f"print(bench_env.fourwis_single('joint') if {n} == 0 else bench_env.fourwis_vector('joint', {n}))"
    )
    env = dict(os.environ, FOURWIS_THREADS=str(threads))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return float(out.stdout.split()[-1])


def _compare_seconds(threads: int | None) -> float:
    """Wall time of the small comparison with ``--threads`` (``None``: the default, each worker
    process its share of the cores)."""
    fourwis = Path(sys.executable).with_name("fourwis")
    flag = [] if threads is None else ["--threads", str(threads)]
    env = {k: v for k, v in os.environ.items() if k != "FOURWIS_THREADS"}
    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        subprocess.run([str(fourwis), *COMPARE, *flag, "--out", out], env=env, check=True,
                       capture_output=True)  # fmt: skip
        return time.perf_counter() - start


def main() -> dict:
    counts = sorted({1, max_threads()})
    cases = {"single env, joint [env-steps/s]": 0}
    cases.update({f"vector env x{n}, joint [env-steps/s]": n for n in (16, 64, 256)})
    _env_rate(counts[-1], 16)  # untimed: compile or load the kernels
    _compare_seconds(counts[-1])
    seen: dict[str, list[float]] = {}
    for _ in range(ROUNDS):
        for threads in counts:
            for label, n in cases.items():
                seen.setdefault(f"{label}, threads={threads}", []).append(_env_rate(threads, n))
            seen.setdefault(f"compare (small matrix) wall [s], threads={threads}", []).append(_compare_seconds(threads))
        seen.setdefault("compare (small matrix) wall [s], default", []).append(_compare_seconds(None))
    results = {label: (min(v) if "[s]" in label else max(v)) for label, v in seen.items()}
    if len(counts) == 2:
        for label in (*cases, "compare (small matrix) wall [s]"):
            one, many = results[f"{label}, threads=1"], results[f"{label}, threads={counts[1]}"]
            speed_up = (one / many) if "[s]" in label else (many / one)
            results[f"{label.split(' [')[0]}: speed-up of {counts[1]} threads over 1"] = speed_up
    return report(results, decimals=2)


if __name__ == "__main__":
    main()
